"""The composite, the per-pixel float maps and the rows' mean as compiled passes (the
numba sides of the ``composite``, ``float_image`` and ``row_mean`` twins,
:mod:`core.result`, :meth:`core.geometry.Geometry.to_image` and
:func:`core.geometry.row_mean`).
"""

from __future__ import annotations

import numba
import numpy as np


def composite(combined, lighting, albedo, index, shaded, weight) -> tuple:
    """:func:`core.result.composite` in two parallel passes (float64 ``shaded``).

    The same float64 operations as NumPy's, so the same float32 images. NumPy's
    version is a dozen passes over the image and fancy-indexed rows.

    Parameters
    ----------
    combined, lighting, albedo : (H, W, 3) float32, the frame's passes (linear)
    index : (P,) int, flat SSS pixels; shaded : (P, 3) float64, L there
    weight : (P,) float or None, Subsurface Weight

    Returns
    -------
    composite, sss : (H, W, 3) float32
    """
    h, w = lighting.shape[:2]
    out = np.empty((h, w, 3), np.float32)
    sss = np.empty((h, w, 3), np.float32)
    use_weight = weight is not None and not np.all(weight == 1.0)
    _composite_pass(
        _rows(combined),
        _rows(lighting),
        _rows(albedo),
        np.asarray(index, np.int64),
        np.ascontiguousarray(shaded, np.float64),
        np.ascontiguousarray(weight if use_weight else np.ones(0), np.float64),
        use_weight,
        float(np.finfo(np.float32).max),
        out.reshape(-1, 3),
        sss.reshape(-1, 3),
    )
    return out, sss


def _rows(image: np.ndarray) -> np.ndarray:
    """An (H, W, 3) float32 image as contiguous (H·W, 3) rows (no copy when it is)."""
    return np.ascontiguousarray(image, np.float32).reshape(-1, 3)


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _composite_pass(combined, lighting, albedo, index, shaded, weight, use_weight, big, out, sss):
    zero = np.float32(0.0)
    for i in numba.prange(combined.shape[0]):
        for c in range(3):
            x = combined[i, c]
            out[i, c] = x if (x >= zero or np.isnan(x)) else zero  # np.maximum(x, 0)
            sss[i, c] = lighting[i, c]
    for k in numba.prange(index.shape[0]):
        i = index[k]
        for c in range(3):
            # np.clip(np.nan_to_num(s, nan=0, posinf=big), 0, big)
            s = shaded[k, c]
            s = 0.0 if np.isnan(s) else min(max(s, 0.0), big)
            change = s - np.float64(lighting[i, c])
            if use_weight:
                change *= weight[k]
            v = np.float64(combined[i, c]) + np.float64(albedo[i, c]) * change
            out[i, c] = np.float32(min(max(v, 0.0), big))
            sss[i, c] = np.float32(s)


def float_image(values: np.ndarray, index: np.ndarray, size: int, fill: float) -> np.ndarray:
    """:meth:`core.geometry.Geometry.to_image` of float values into float32, in one
    parallel pass: (size, C) or (size,), ``fill`` off ``index``, values clipped to
    ±float32 max (NaN kept), as NumPy's clip and cast give them."""
    values = np.asarray(values)
    channels = int(np.prod(values.shape[1:]))  # 1 for (P,); also when P = 0
    rows = np.ascontiguousarray(values, np.float64).reshape(values.shape[0], channels)
    out = np.empty((size, rows.shape[1]), np.float32)
    _float_image_pass(
        rows, np.asarray(index, np.int64), float(fill), float(np.finfo(np.float32).max), out
    )
    return out.reshape(size, *values.shape[1:])


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _float_image_pass(rows, index, fill, big, out):
    f = np.float32(fill)
    # The fill over the flat array: written as a loop over (pixel, channel) inside
    # prange it compiled in 6.3 s against 2.0 s (the same run time, 3.3 ms per
    # 1920×1080 (P, 3) map).
    n = out.shape[0] * out.shape[1]
    flat = out.reshape(n)
    for i in numba.prange(n):
        flat[i] = f
    channels = out.shape[1]
    for k in numba.prange(index.shape[0]):
        i = index[k]
        for c in range(channels):
            x = rows[k, c]
            out[i, c] = np.float32(x if np.isnan(x) else min(max(x, -big), big))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def row_sums(rows):
    """(3,) float64: the sums of the (P, 3) float64 ``rows`` over P, row after row (the
    order NumPy's sum along the first axis of a C-contiguous array takes; serial)."""
    s0 = s1 = s2 = 0.0
    for k in range(rows.shape[0]):
        s0 += rows[k, 0]
        s1 += rows[k, 1]
        s2 += rows[k, 2]
    out = np.empty(3)
    out[0] = s0
    out[1] = s1
    out[2] = s2
    return out

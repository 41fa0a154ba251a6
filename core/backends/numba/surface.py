"""The depth-buffer surface in one compiled pass (the numba side of the ``surface``
twin, :func:`core.geometry.surface`).
"""

from __future__ import annotations

import math

import numba
import numpy as np


@numba.njit(cache=True, inline="always", error_model="numpy")
def _position(depth, i, j, ox, oy, wu, hu, cx, cy, ortho):
    """Camera-space point of pixel (i, j), as core.geometry.positions computes it."""
    z = np.float64(depth[i, j])
    s = 1.0 if ortho else z
    return ((j + ox) - cx) * wu * s, ((i + oy) - cy) * hu * s, z


@numba.njit(cache=True, inline="always", error_model="numpy")
def _step(prev, cur, nxt, has_prev, has_next, z):
    """core.geometry.surface's tangent along one axis at one pixel (same operations)."""
    nan = np.nan
    fx = fy = fz = nan
    bx = by = bz = nan
    if has_next:
        fx, fy, fz = nxt[0] - cur[0], nxt[1] - cur[1], nxt[2] - cur[2]
        if not (np.isfinite(fx) and np.isfinite(fy) and np.isfinite(fz)):
            fx = fy = fz = nan
    if has_prev:
        bx, by, bz = cur[0] - prev[0], cur[1] - prev[1], cur[2] - prev[2]
        if not (np.isfinite(bx) and np.isfinite(by) and np.isfinite(bz)):
            bx = by = bz = nan
    af, ab = abs(fz), abs(bz)
    if np.isfinite(af + ab) and max(af, ab) <= 2.0 * min(af, ab) + 1e-6 * z:
        return 0.5 * (fx + bx), 0.5 * (fy + by), 0.5 * (fz + bz)
    if np.isnan(af) or ab < af:
        return bx, by, bz
    return fx, fy, fz


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def surface_arrays(depth, objects, use_obj, ox, oy, wu, hu, cx, cy, ortho, max_tilt):
    """Area and normal of every pixel of the depth buffer: core.geometry.surface's
    arithmetic in one pass (float64, the same operations in the same order, so the
    results are bit-identical; tests/core/test_backend.py checks it).

    Parameters
    ----------
    depth : (H, W) float32, planar depth (scene units, inf = background)
    objects : (H, W) int32, the Object Index pass (read when ``use_obj``): a step never
        goes to a neighbour of another object
    use_obj : bool
    ox, oy : int, image position of depth[0, 0]
    wu, hu : float, pixel footprint at unit depth (ortho: the footprint)
    cx, cy : float, principal point (pixels)
    ortho : bool
    max_tilt : float, core.geometry.MAX_TILT

    Returns
    -------
    area : (H·W,) float32 (scene units²), normal : (H·W, 3) float32
    """
    h, w = depth.shape
    area = np.empty(h * w, np.float32)
    normal = np.empty((h * w, 3), np.float32)
    for i in numba.prange(h):
        for j in range(w):
            c = _position(depth, i, j, ox, oy, wu, hu, cx, cy, ortho)
            z = c[2]
            left = _position(depth, i, max(j - 1, 0), ox, oy, wu, hu, cx, cy, ortho)
            right = _position(depth, i, min(j + 1, w - 1), ox, oy, wu, hu, cx, cy, ortho)
            up = _position(depth, max(i - 1, 0), j, ox, oy, wu, hu, cx, cy, ortho)
            down = _position(depth, min(i + 1, h - 1), j, ox, oy, wu, hu, cx, cy, ortho)
            has_left, has_right, has_up, has_down = j > 0, j < w - 1, i > 0, i < h - 1
            if use_obj:
                o = objects[i, j]
                has_left = has_left and objects[i, j - 1] == o
                has_right = has_right and objects[i, j + 1] == o
                has_up = has_up and objects[i - 1, j] == o
                has_down = has_down and objects[i + 1, j] == o
            a0, a1, a2 = _step(left, c, right, has_left, has_right, z)
            b0, b1, b2 = _step(up, c, down, has_up, has_down, z)
            c0 = a1 * b2 - a2 * b1
            c1 = a2 * b0 - a0 * b2
            c2 = a0 * b1 - a1 * b0
            norm = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
            flat = (wu * hu) * (1.0 if ortho else z * z)
            known = np.isfinite(norm) and norm > 0
            a = min(norm, max_tilt * flat) if known else flat
            k = i * w + j
            area[k] = np.float32(a if np.isfinite(z) else 0.0)
            d = norm if known else 1.0
            n0, n1, n2 = c0 / d, c1 / d, c2 / d
            if ortho:
                v0, v1, v2 = 0.0, 0.0, 1.0
            else:
                v0 = ((j + ox) - cx) * wu
                v1 = ((i + oy) - cy) * hu
                vn = np.sqrt(v0 * v0 + v1 * v1 + 1.0)
                v0, v1, v2 = v0 / vn, v1 / vn, 1.0 / vn
            if known:
                if n0 * v0 + n1 * v1 + n2 * v2 > 0:
                    n0, n1, n2 = -n0, -n1, -n2
            else:
                n0, n1, n2 = -v0, -v1, -v2
            x32, y32 = np.float32(n0), np.float32(n1)
            rest = np.float32(1.0) - (x32 * x32 + y32 * y32)
            r = np.sqrt(max(rest, np.float32(0.0)))
            normal[k, 0] = x32
            normal[k, 1] = y32
            normal[k, 2] = math.copysign(r, np.float32(n2))
    return area, normal

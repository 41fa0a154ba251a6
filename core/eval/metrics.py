"""Per-frame metrics: mean sample count, PSNR, and a median filter over frames."""

from __future__ import annotations

import numpy as np

from .color import display_luma

#: PSNR reported when the images are identical on the mask (avoids inf in CSV/JSON).
PSNR_CAP_DB = 100.0


def psnr(test: np.ndarray, reference: np.ndarray, mask: np.ndarray, exposure: float = 1.0) -> float:
    """Luminance PSNR over ``mask``, display-referred (exposure, sRGB, clip, peak 1).

    Parameters
    ----------
    test, reference : (H, W, 3) float, linear scene-referred
    mask : (H, W) bool, pixels to compare (SSS pixels)
    exposure : float

    Returns
    -------
    float, dB; ``nan`` when the mask is empty; capped at 100 dB.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return float("nan")
    a = display_luma(np.asarray(test)[mask], exposure)
    b = display_luma(np.asarray(reference)[mask], exposure)
    mse = float(np.mean((a - b) ** 2))
    if mse <= 10.0 ** (-PSNR_CAP_DB / 10.0):
        return PSNR_CAP_DB
    return float(10.0 * np.log10(1.0 / mse))


def median3(values: np.ndarray) -> np.ndarray:
    """Third-order median filter over a 1D series (edges keep their window of 2).

    >>> median3(np.array([1.0, 9.0, 2.0, 3.0])).tolist()
    [5.0, 2.0, 3.0, 2.5]
    """
    v = np.asarray(values, dtype=np.float64)
    if v.size < 3:
        return v.copy()
    out = np.empty_like(v)
    out[1:-1] = np.median(np.stack([v[:-2], v[1:-1], v[2:]]), axis=0)
    out[0] = np.median(v[:2])
    out[-1] = np.median(v[-2:])
    return out

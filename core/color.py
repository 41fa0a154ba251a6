"""Colour helpers: luminance and the display transform used for metrics.

All inputs are linear, scene-referred RGB in Blender's working space
(Rec. 709 primaries, ``lin_rec709_scene`` in the EXR header).
"""

from __future__ import annotations

import numpy as np

#: Rec. 709 / sRGB luminance weights.
REC709 = np.array([0.2126, 0.7152, 0.0722])


def luminance(rgb: np.ndarray) -> np.ndarray:
    """Rec. 709 luminance.

    Parameters
    ----------
    rgb : (..., 3) float array, linear

    Returns
    -------
    (...) float array, same dtype as ``rgb`` for floating inputs.

    >>> float(luminance(np.array([1.0, 1.0, 1.0])))
    1.0
    """
    rgb = np.asarray(rgb)
    return rgb @ REC709.astype(rgb.dtype if rgb.dtype.kind == "f" else np.float64)


def srgb_encode(linear: np.ndarray) -> np.ndarray:
    """sRGB transfer function (IEC 61966-2-1), input clipped to [0, 1].

    >>> round(float(srgb_encode(np.array(0.5))), 4)
    0.7354
    """
    x = np.clip(np.nan_to_num(np.asarray(linear, dtype=np.float64), nan=0.0), 0.0, 1.0)
    return np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1.0 / 2.4) - 0.055)


def display_luma(rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    """Display-referred luma used for PSNR: exposure, sRGB encode, clip, Rec. 709.

    Parameters
    ----------
    rgb : (..., 3) float array, linear scene-referred
    exposure : float
        Linear multiplier applied before the transfer function.

    Returns
    -------
    (...) float64 array in [0, 1].
    """
    return srgb_encode(np.asarray(rgb, dtype=np.float64) * exposure) @ REC709

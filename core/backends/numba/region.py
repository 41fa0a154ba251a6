"""The Burley distant region in one compiled pass (the numba side of the
``burley_region`` twin, :meth:`core.profiles.burley.BurleyProfile.region`).
"""

from __future__ import annotations

import math

import numba
import numpy as np


def burley_region(r0, mat, d, truncate, tail_max):
    """γ, weight scale and sampling bounds of P pixels in one parallel pass.

    :meth:`core.profiles.burley.BurleyProfile.region`'s float64 operations in the same
    order (``tail`` at ``min(r0, d·truncate)``, the mass above the truncation tail, γ
    and its weight scale). The exponentials are libm's ``exp``, which NumPy also calls
    for float64 on CPUs without AVX-512; where NumPy has its own AVX-512 ``exp`` the two
    may differ in the last bit.

    Parameters
    ----------
    r0 : (P,) float64, inner radius per pixel (scene units); mat : (P,) int, compact slot
    d : (K, 3) float64, Burley shape per slot and channel (scene units)
    truncate : float, truncation radius in units of d; tail_max : float, the tail there

    Returns
    -------
    gamma, weight_scale, lo, hi : (P, 3) float64
    """
    out = np.empty((4, r0.shape[0], 3))
    _region(
        np.ascontiguousarray(r0, dtype=np.float64),
        np.ascontiguousarray(mat, dtype=np.int64),
        np.ascontiguousarray(d, dtype=np.float64),
        float(truncate),
        float(tail_max),
        out,
    )
    return out[0], out[1], out[2], out[3]


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _region(r0, mat, d, truncate, tail_max, out):
    total = 1.0 - tail_max
    for i in numba.prange(r0.shape[0]):
        k = mat[i]
        for c in range(3):
            dc = d[k, c]
            rmax = dc * truncate
            r = r0[i] if r0[i] < rmax else rmax  # np.minimum (both finite)
            if dc > 0:  # burley.tail at r, and the mass above the truncation tail
                t = 0.25 * math.exp(-r / dc) + 0.75 * math.exp(-r / (3.0 * dc))
                lo = tail_max
                mass = t - lo
                mass = mass if mass > 0.0 else 0.0
            else:  # no scattering in this channel
                t = 0.0 if r > 0 else 1.0
                lo = 0.0
                mass = 0.0
            gamma = mass / total
            out[0, i, c] = gamma
            out[1, i, c] = gamma / mass if mass > 0 else 0.0
            out[2, i, c] = lo
            out[3, i, c] = t

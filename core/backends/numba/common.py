"""Helpers the compiled kernels of several domains share: integer hashing, NumPy's
``nan_to_num`` and the float32 store rule of one value, Rec. 709 weights.

Every helper is inlined into the pass that calls it (``inline="always"``).
"""

from __future__ import annotations

import numba
import numpy as np

from ...color import REC709

#: uint32 arithmetic is done in uint64 and masked (numba's integers are 64-bit).
_M32 = np.uint64(0xFFFFFFFF)
_LCG_A = np.uint64(1664525)
_LCG_C = np.uint64(1013904223)
_S16 = np.uint64(16)
_M16 = np.uint64(0xFFFF)
_ONE, _TWO, _THREE, _FOUR = np.uint64(1), np.uint64(2), np.uint64(3), np.uint64(4)
_FIVE, _SIX, _SEVEN, _EIGHT = np.uint64(5), np.uint64(6), np.uint64(7), np.uint64(8)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _pcg3d_xy(x, y, z):
    """The first two words of :func:`core.sampling.qmc.pcg3d` (uint32 arithmetic
    done in uint64 and masked)."""
    vx = (x * _LCG_A + _LCG_C) & _M32
    vy = (y * _LCG_A + _LCG_C) & _M32
    vz = (z * _LCG_A + _LCG_C) & _M32
    vx = (vx + vy * vz) & _M32
    vy = (vy + vz * vx) & _M32
    vz = (vz + vx * vy) & _M32
    vx ^= vx >> _S16
    vy ^= vy >> _S16
    vz ^= vz >> _S16
    vx = (vx + vy * vz) & _M32
    vy = (vy + vz * vx) & _M32
    return vx, vy


_F64_MAX = np.finfo(np.float64).max


@numba.njit(inline="always", error_model="numpy")
def _finite(x, nan, posinf, neginf):
    """np.nan_to_num of one float64."""
    if np.isnan(x):
        return nan
    if x == np.inf:
        return posinf
    if x == -np.inf:
        return neginf
    return x


def _flat(x, shape, dtype) -> np.ndarray:
    """``x`` broadcast to ``shape``, as a contiguous 1-D array of ``dtype``."""
    return np.ascontiguousarray(np.broadcast_to(np.asarray(x, dtype=dtype), shape)).reshape(-1)


#: Largest finite float32, as a float64.
_F32_MAX = float(np.finfo(np.float32).max)
_R0, _R1, _R2 = (float(v) for v in REC709)


@numba.njit(inline="always", error_model="numpy")
def _bounded(x, limit):
    """core.mc.update._bounded of one float64: clipped to ±limit, NaN → 0."""
    if np.isnan(x):
        return 0.0
    return min(max(x, -limit), limit)


@numba.njit(inline="always", error_model="numpy")
def _stored(x):
    """History.write of one float64 into float32 storage: ±inf → ±max, NaN → 0."""
    if np.isnan(x):
        return np.float32(0.0)
    return np.float32(min(max(x, -_F32_MAX), _F32_MAX))

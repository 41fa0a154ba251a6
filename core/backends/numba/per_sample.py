"""The per-sample helpers the sampling pass inlines (:mod:`core.backends.numba.sampling`).

Each mirrors one NumPy operation of :mod:`core.mc.samples` in float32, operation by
operation: a texel's normal, the Burley pdf from its table, a camera-space offset,
a sample's mirror image, and the share of light the contact rule keeps.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from ...params import CONTACT_FOOT, CONTACT_LOSS
from .common import _EIGHT, _FIVE, _ONE, _THREE, _TWO

#: The contact rule's loss where a surface ends on another object (core.params).
_LOSS = np.float32(CONTACT_LOSS)
_FOOT = np.float32(CONTACT_FOOT)
#: Above the other object's plane beyond this share of the sample's radius (as
#: core.mc.samples).
_ABOVE = np.float32(1e-4)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _normal_z(mx, my, signed):
    """z of the unit normal (mx, my, z), float32: the texel keeps x and y, and its
    area carries z's sign (:func:`core.backends.numba.sampling.texels`)."""
    z2 = max(np.float32(1.0) - (mx * mx + my * my), np.float32(0.0))
    return np.float32(math.copysign(np.sqrt(z2), signed))


@numba.njit(cache=True, inline="always", error_model="numpy")
def _offset(sx, sy, z, px, py, zp, ortho, cx, cy, unit_x, unit_y):
    """Camera-space x, y offset (float32, scene units) from the centre pixel (px, py) at
    depth zp to the screen point (sx, sy) at depth z (as :func:`core.mc.samples._offset`)."""
    if ortho:
        return (sx - px) * unit_x, (sy - py) * unit_y
    return ((sx - cx) * z - (px - cx) * zp) * unit_x, ((sy - cy) * z - (py - cy) * zp) * unit_y


@numba.njit(cache=True, inline="always", error_model="numpy")
def _opposite(px, py, fx, fy, ox, oy, w, h, texel, key, zp, tol):
    """The crop pixel opposite the landing pixel (fx, fy) through the centre (px, py),
    where it is on the centre's surface (its key, within ``tol`` of the centre's depth
    zp; no plane test); -1 elsewhere (as :func:`core.mc.samples._mirrored`)."""
    mix = np.int64(np.int32(np.float32(2.0) * px - fx)) - ox
    miy = np.int64(np.int32(np.float32(2.0) * py - fy)) - oy
    if (mix >= 0) & (mix < w) & (miy >= 0) & (miy < h):
        qm = miy * w + mix
        m8 = np.uint64(qm) * _EIGHT
        if texel[m8 + _FIVE] == key and abs(texel[m8 + _THREE] - zp) <= tol:
            return qm
    return np.int64(-1)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _kept(height, reach):
    """The share of its light a sample keeps where the centre's surface ends on another
    object at ``height`` of it, for ``height < reach`` (float32; as
    :func:`core.mc.samples._kept`)."""
    lost = (reach - height) / (reach - _FOOT * reach)
    lost = min(lost, np.float32(1.0)) * _LOSS
    return np.float32(1.0) - lost


@numba.njit(cache=True, inline="always", error_model="numpy")
def _pdf(x, k, inv_d, ptab, size):
    """Burley pdf at x of one channel from the flat unit table (as
    :func:`core.profiles.burley.pdf_from_table`): k = size/(truncate·d), inv_d = 1/d."""
    s = x * k
    if s > size:
        s = size
    # 0 <= s <= size: the signed 32-bit conversion is exact and one instruction (a
    # float to unsigned 64-bit conversion is a compare-and-select sequence on AVX2);
    # the index is then widened unsigned, so numba emits no negative-index test.
    si = np.int32(s)
    i = np.uint64(np.uint32(si)) * _TWO
    s = (s - np.float32(si)) * ptab[i + _ONE] + ptab[i]
    return s * inv_d

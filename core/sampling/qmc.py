"""R2 sequence with per-pixel, per-frame hashed offsets.

The defense slides (D, slide 42) pair Roberts' R2 sequence, which keeps the
samples of one pixel well stratified, with the pcg3d hash of Jarzynski & Olano
(2020) on (x, y, frame), which decorrelates pixels and frames. Everything is
integer arithmetic on uint32, so a fixed seed gives bit-identical samples.
"""

from __future__ import annotations

import numpy as np

#: Plastic number φ₂, the real root of x³ = x + 1.
PHI2 = 1.32471795724474602596
R2_STEP = np.array([1.0 / PHI2, 1.0 / PHI2**2])

_U32 = np.uint32
_INV_2_32 = 1.0 / 4294967296.0
#: R2 step in 0.32 fixed point: frac(k·a) = (k·A mod 2**32) / 2**32 exactly.
R2_STEP_U32 = (np.uint32(round(2**32 / PHI2)), np.uint32(round(2**32 / PHI2**2)))
#: Sample directions are the centres of 2**DIRECTION_BITS equal angular bins.
DIRECTION_BITS = 12


def direction_table(bits: int = DIRECTION_BITS) -> np.ndarray:
    """(2**bits, 2) float32 ``(cos θ_i, sin θ_i)`` with ``θ_i = 2π(i + ½)/2**bits``.

    The angle coordinate v of a sample (0.32 fixed point) selects bin
    ``v >> (32 − bits)``, so each of the equally likely bins holds the
    directions of its width and the sample takes the bin's centre: the
    angular distribution stays uniform over a symmetric set, moving a sample
    at radius ρ pixels by at most πρ/2**bits pixels (0.08 px at 100 px), and
    the sampler reads a table instead of calling cos and sin.

    >>> t = direction_table(2); [round(float(v), 4) for v in t[:, 0]]
    [0.7071, -0.7071, -0.7071, 0.7071]
    """
    theta = 2.0 * np.pi * (np.arange(1 << bits) + 0.5) / (1 << bits)
    return np.stack([np.cos(theta), np.sin(theta)], axis=1).astype(np.float32)


#: The table of :func:`direction_table` the estimators use.
DIRECTIONS = direction_table()


def pcg3d(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, ...]:
    """pcg3d hash (Jarzynski & Olano 2020) on uint32 triples.

    Parameters
    ----------
    x, y, z : (...) integer arrays, broadcastable; taken modulo 2**32.

    Returns
    -------
    (hx, hy, hz) : three (...) uint32 arrays.

    >>> [int(v) for v in pcg3d(np.uint32(0), np.uint32(0), np.uint32(0))]
    [2611992518, 2833812075, 1058359340]
    """
    shape = np.broadcast_shapes(np.shape(x), np.shape(y), np.shape(z))
    vx, vy, vz = (
        np.broadcast_to(np.asarray(a).astype(np.int64) & 0xFFFFFFFF, shape).astype(_U32)
        for a in (x, y, z)
    )
    with np.errstate(over="ignore"):
        vx = vx * _U32(1664525) + _U32(1013904223)
        vy = vy * _U32(1664525) + _U32(1013904223)
        vz = vz * _U32(1664525) + _U32(1013904223)
        vx = vx + vy * vz
        vy = vy + vz * vx
        vz = vz + vx * vy
        vx ^= vx >> _U32(16)
        vy ^= vy >> _U32(16)
        vz ^= vz >> _U32(16)
        vx = vx + vy * vz
        vy = vy + vz * vx
        vz = vz + vx * vy
    return vx, vy, vz


def pixel_hashes(
    px: np.ndarray, py: np.ndarray, frame: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel, per-frame offsets as uint32 (0.32 fixed point).

    Parameters are as in :func:`pixel_offsets`; returns two (N,) uint32 arrays.
    """
    hx, hy, _ = pcg3d(px, py, np.int64(frame) ^ np.int64(seed))
    return hx, hy


def r2_points_fixed(
    hx: np.ndarray, hy: np.ndarray, k: np.ndarray, dtype=np.float64
) -> tuple[np.ndarray, np.ndarray]:
    """Shifted R2 points in 0.32 fixed point, returned as floats in [0, 1).

    ``u = ((hx + k·A) mod 2**32) / 2**32`` with ``A = round(2**32/φ₂)``: the
    wrap-around of uint32 arithmetic is the ``frac`` of the sequence, exact
    and cheaper than floating-point floor. Agrees with :func:`r2_points` to
    ~1e-9.

    Parameters
    ----------
    hx, hy : (N,) uint32, per-sample offsets (from :func:`pixel_hashes`)
    k : (N,) integer, sample index within its pixel (1, 2, …)
    dtype : float dtype of the result; float32 keeps 24 bits and is clipped
        below 1 so rounding never yields 1.0.
    """
    k = np.asarray(k).astype(_U32, copy=False)
    with np.errstate(over="ignore"):
        u = hx + k * R2_STEP_U32[0]
        v = hy + k * R2_STEP_U32[1]
    if np.dtype(dtype) == np.float64:
        return u * _INV_2_32, v * _INV_2_32
    top = np.nextafter(np.float32(1.0), np.float32(0.0))
    uf = u.astype(np.float32)
    uf *= np.float32(_INV_2_32)
    vf = v.astype(np.float32)
    vf *= np.float32(_INV_2_32)
    return np.minimum(uf, top, out=uf), np.minimum(vf, top, out=vf)


def r2_fixed(hx: np.ndarray, hy: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Shifted R2 points as 0.32 fixed-point uint32 (see :func:`r2_points_fixed`).

    Returns ``(hx + k·A, hy + k·B) mod 2**32``: the radial coordinate is turned
    into a float by the caller, the angular one selects a :data:`DIRECTIONS` bin
    by its top bits.
    """
    k = np.asarray(k).astype(_U32, copy=False)
    with np.errstate(over="ignore"):
        u = k * R2_STEP_U32[0]
        u += hx
        v = k * R2_STEP_U32[1]
        v += hy
    return u, v


def pixel_offsets(
    px: np.ndarray, py: np.ndarray, frame: int, seed: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel, per-frame Cranley–Patterson offsets in [0, 1)².

    Parameters
    ----------
    px, py : (N,) integer arrays, pixel column and row.
    frame : int
        Frame number.
    seed : int
        Stream seed in [0, 2**32); combined with the frame by XOR.

    Returns
    -------
    sx, sy : (N,) float64 arrays in [0, 1).
    """
    hx, hy = pixel_hashes(px, py, frame, seed)
    return hx * _INV_2_32, hy * _INV_2_32


def r2_points(sx: np.ndarray, sy: np.ndarray, k: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Points ``frac(s + k·(1/φ₂, 1/φ₂²))`` of the shifted R2 sequence.

    Parameters
    ----------
    sx, sy : (N,) float arrays, per-sample offsets in [0, 1).
    k : (N,) integer array, sample index within its pixel (1, 2, …).

    Returns
    -------
    u, v : (N,) float64 arrays in [0, 1).
    """
    k = np.asarray(k, dtype=np.float64)
    u = sx + k * R2_STEP[0]
    v = sy + k * R2_STEP[1]
    u -= np.floor(u)
    v -= np.floor(v)
    return u, v

"""The separable passes, compiled (the numba side of the ``separable_passes`` twin,
:mod:`core.separable.apply`).
"""

from __future__ import annotations

import types

import numba
import numpy as np

from .common import _M32, _ONE, _TWO, _pcg3d_xy

#: Pixels per parallel task of the separable passes.
_ROW_TASK = 1024
_INV_2_32_F32 = np.float32(2.0**-32)
#: Pixels that go through each tap of a separable pass together (see _separable_pass).
_SEP_BLOCK = 16
#: Rows of a block's float32 buffer: the centre's value, the sums of the first RGB
#: group, scale, depth and the tap's value (each row _SEP_BLOCK long).
_SB0, _SB1, _SB2, _SA0, _SA1, _SA2, _SSK, _SZK, _SV0, _SV1, _SV2 = (
    r * _SEP_BLOCK for r in range(11)
)
#: Rows of its int64 buffer: slot, coordinate along the pass, offset across it, core
#: flag, zero-weight reads, image x and y.
_SS, _SCI, _SBK, _SCORE, _SBAD, _SPX, _SPY = (r * _SEP_BLOCK for r in range(7))
#: The follow rule a build of the pass is compiled for (see separable_pass).
_EXP_FOLLOW = False


def _separable_pass(
    src,
    c0,
    reps,
    index,
    px,
    py,
    mat,
    z,
    coord_i,
    base,
    scale,
    core,
    depth_flat,
    mat_flat,
    offsets,
    width,
    jittered,
    weights,
    stride,
    size,
    first,
    span,
    key,
    slope,
    neg_inv2tau,
    linear,
    out,
):
    """One 1D separable pass of one RGB group, per pixel:
    :func:`core.separable.apply._one_pass`'s float32 arithmetic operation by
    operation, each pixel's taps in order.

    Reads the channels ``c0 … c0 + 2`` of ``src`` and adds to the columns
    ``c0 + 3·r + c`` of ``out``, r < ``reps`` (the horizontal pass's one RGB read feeds
    its J terms: c0 = 0, reps = J; the vertical pass reads and writes term t's
    group: c0 = 3t, reps = 1).

    Parameters
    ----------
    src : (H·W, C) float32, pixel-major source image (a read's channels share a line)
    c0 : int, first channel read and first column written; reps : int, groups written
    index, px, py : (P,) int64, flat index into the frame's arrays and image coords
    mat : (P,) int32 slot; z : (P,) float32 depth; coord_i : (P,) int64, the pixel's
        image coordinate along the pass; base : (P,) int64, the read's flat offset
        across it; scale : (P,) float32, pixels per scene unit along it
    core : (P,) bool, pixels whose zero-weight reads are counted
    depth_flat : (H·W,) float32; mat_flat : (H·W,) int32
    offsets, width : (K, n) float64 tap offsets (scene units) and jitter cells
    jittered : (n,) bool, the tap is jittered on some pixel's slot (NumPy's test)
    weights : (K, n, 3·R') float32 tap weights
    stride, size, first, span : int, as in _one_pass; key : int64 jitter key (< 0: none)
    slope : float64 depth slope (the slope follow; the exponential build ignores it)
    neg_inv2tau : (K,) float32, −1/(2τ) per slot (the exponential follow)
    linear : bool, read between the two nearest pixels
    out : (P, 3·R') float32, zeroed; gains Σ_i w_i·sample_i

    Returns
    -------
    fallback : (T,) int64, zero-weight reads of core pixels per task
    """
    n_pix = index.shape[0]
    n = offsets.shape[1]
    half = n // 2
    n_tasks = (n_pix + _ROW_TASK - 1) // _ROW_TASK
    fallback = np.zeros(n_tasks, np.int64)
    f32slope = np.float64(np.float32(slope))
    one = np.float32(1.0)
    zero = np.float32(0.0)
    inf = np.float32(np.inf)
    # Unsigned indices: numba emits no negative-index wrap-around per read.
    u0 = np.uint64(c0)
    u1 = np.uint64(c0 + 1)
    u2 = np.uint64(c0 + 2)
    un = np.uint64(n)
    wc = np.uint64(weights.shape[2])
    # Flat tables (NumPy converts the offsets and cells to float32 per read, the same).
    off32 = offsets.astype(np.float32).ravel()
    wid32 = width.astype(np.float32).ravel()
    w32 = weights.ravel()
    for t in numba.prange(n_tasks):
        # The pixels go through the taps in blocks of _SEP_BLOCK: for each tap, every
        # pixel of the block, whose reads are independent and overlap. Their values sit
        # in two small buffers (one base each, so the compiler sees that the block's
        # stores do not alias its loads). A 1920×1080 frame's passes took 11-33 % less
        # time than with each pixel's taps in turn (docs/checks/separable_pass.py; blocks
        # of 16-64 alike, 8 slower). Each pixel's arithmetic and the order of its sums are
        # those of the plain loop.
        fb = np.zeros(11 * _SEP_BLOCK, np.float32)
        ib = np.zeros(7 * _SEP_BLOCK, np.int64)
        end = min(n_pix, (t + 1) * _ROW_TASK)
        nfb = 0
        for k0 in range(t * _ROW_TASK, end, _SEP_BLOCK):
            nb = min(_SEP_BLOCK, end - k0)
            for j in range(nb):
                k = k0 + j
                ck = np.uint64(index[k])
                fb[_SB0 + j] = src[ck, u0]
                fb[_SB1 + j] = src[ck, u1]
                fb[_SB2 + j] = src[ck, u2]
                fb[_SA0 + j] = zero
                fb[_SA1 + j] = zero
                fb[_SA2 + j] = zero
                fb[_SSK + j] = scale[k]
                fb[_SZK + j] = z[k]
                ib[_SS + j] = np.int64(mat[k])
                ib[_SCI + j] = coord_i[k]
                ib[_SBK + j] = base[k]
                ib[_SCORE + j] = np.int64(core[k])
                ib[_SBAD + j] = 0
                ib[_SPX + j] = px[k]
                ib[_SPY + j] = py[k]
            for i in range(n):
                ui = np.uint64(i)
                if i == half:
                    # The centre tap reads the centre.
                    for j in range(nb):
                        wrow = (np.uint64(ib[_SS + j]) * un + ui) * wc + u0
                        fb[_SA0 + j] = fb[_SA0 + j] + w32[wrow] * fb[_SB0 + j]
                        fb[_SA1 + j] = fb[_SA1 + j] + w32[wrow + _ONE] * fb[_SB1 + j]
                        fb[_SA2 + j] = fb[_SA2 + j] + w32[wrow + _TWO] * fb[_SB2 + j]
                        fb[_SV0 + j] = fb[_SB0 + j]
                        fb[_SV1 + j] = fb[_SB1 + j]
                        fb[_SV2 + j] = fb[_SB2 + j]
                else:
                    jit_tap = jittered[i] and key >= 0
                    hz = np.uint64(key * 67 + i) & _M32
                    for j in range(nb):
                        sl = ib[_SS + j]
                        s = np.uint64(sl) * un + ui
                        sk = fb[_SSK + j]
                        zk = fb[_SZK + j]
                        ci = ib[_SCI + j]
                        bk = ib[_SBK + j]
                        pos = off32[s]
                        if jit_tap:
                            hx, _ = _pcg3d_xy(
                                np.uint64(ib[_SPX + j]) & _M32, np.uint64(ib[_SPY + j]) & _M32, hz
                            )
                            jit = np.float32(np.float64(hx) * np.float64(_INV_2_32_F32))
                            jit = jit - np.float32(0.5)
                            jit = jit * wid32[s]
                            pos = pos + jit
                        pos = pos * sk
                        pos = pos + np.float32(ci)
                        if linear:
                            p0f = np.floor(pos)
                            fr = pos - p0f
                        else:
                            p0f = np.rint(pos)
                            fr = zero
                        p0 = np.int64(p0f)
                        b0 = fb[_SB0 + j]
                        b1 = fb[_SB1 + j]
                        b2 = fb[_SB2 + j]
                        v0 = v1 = v2 = zero
                        bad = 0
                        for r in range(2 if linear else 1):
                            p = p0 + r
                            pc = min(max(p, 0), size - 1)
                            local = pc - first
                            inside = (p == pc) & (local >= 0) & (local < span)
                            local = min(max(local, 0), span - 1)
                            q = np.uint64(local * stride + bk)
                            # Loaded whatever the slot (selects, not branches).
                            d = depth_flat[q]
                            d = d if mat_flat[q] == sl else inf
                            wz = d - zk
                            if _EXP_FOLLOW:
                                wz = wz * wz
                                wz = wz * neg_inv2tau[np.uint64(sl)]
                                wz = np.exp(wz)
                            else:
                                dist = np.float64(abs(p - ci))
                                wz = one if np.float64(abs(wz) * sk) <= f32slope * dist else zero
                            wz = wz if inside else zero
                            bad += np.int64(wz == zero)
                            if linear:
                                wz = wz * ((one - fr) if r == 0 else fr)
                            v0 = v0 + (src[q, u0] - b0) * wz
                            v1 = v1 + (src[q, u1] - b1) * wz
                            v2 = v2 + (src[q, u2] - b2) * wz
                        ib[_SBAD + j] += bad
                        v0 = v0 + b0
                        v1 = v1 + b1
                        v2 = v2 + b2
                        wrow = s * wc + u0
                        fb[_SA0 + j] = fb[_SA0 + j] + w32[wrow] * v0
                        fb[_SA1 + j] = fb[_SA1 + j] + w32[wrow + _ONE] * v1
                        fb[_SA2 + j] = fb[_SA2 + j] + w32[wrow + _TWO] * v2
                        fb[_SV0 + j] = v0
                        fb[_SV1 + j] = v1
                        fb[_SV2 + j] = v2
                # The other terms' groups of the horizontal pass (J > 1), in their own
                # loop: inside the one above, it ran 10 % slower with J = 1 too.
                if reps > 1:
                    for j in range(nb):
                        row = (np.uint64(ib[_SS + j]) * un + ui) * wc
                        for rep in range(1, reps):
                            o = c0 + 3 * rep
                            wo = row + np.uint64(o)
                            out[k0 + j, o] += w32[wo] * fb[_SV0 + j]
                            out[k0 + j, o + 1] += w32[wo + _ONE] * fb[_SV1 + j]
                            out[k0 + j, o + 2] += w32[wo + _TWO] * fb[_SV2 + j]
            for j in range(nb):
                nfb += ib[_SBAD + j] * ib[_SCORE + j]
                out[k0 + j, c0] = fb[_SA0 + j]
                out[k0 + j, c0 + 1] = fb[_SA1 + j]
                out[k0 + j, c0 + 2] = fb[_SA2 + j]
        fallback[t] = nfb
    return fallback


def _build(name: str, **constants):
    """:func:`_separable_pass` compiled with ``constants`` for its module globals (its
    own name keeps numba's disk-cache entries of the builds apart)."""
    fn = types.FunctionType(
        _separable_pass.__code__, {**_separable_pass.__globals__, **constants}, name
    )
    fn.__qualname__ = name
    fn.__doc__ = _separable_pass.__doc__
    return numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")(fn)


# One build per follow rule, the rule a constant: the exponential follow's call of exp
# in the loop of the slope rule, even where it is never taken, cost that loop 9 %.
separable_pass_slope = _build("separable_pass_slope", _EXP_FOLLOW=False)
separable_pass_exp = _build("separable_pass_exp", _EXP_FOLLOW=True)


def separable_pass(exponential: bool):
    """The build of the separable pass for a follow rule (the slope rule, or the
    exponential one): a compiled function of :func:`_separable_pass`'s arguments."""
    return separable_pass_exp if exponential else separable_pass_slope

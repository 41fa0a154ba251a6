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
#: Pixels that go through each tap of a separable pass together (see _separable_pass):
#: 32 rather than 16, the same bits in 5-11 % less time per frame's passes
#: (docs/checks/separable_pass.py, docs/performance.md); 8 took three times as long
#: (stage 2 then runs scalar), 64 longer than 16.
_SEP_BLOCK = 32
#: Rows of a block's float32 buffer (each _SEP_BLOCK long): the centre's value, the sums
#: of the first RGB group, scale, depth, coordinate along the pass, −1/(2τ); and per tap
#: the offset (scene units), the linear read's fraction, the depth read at each of the
#: two reads (+inf on another slot), their values, the tap's value and its weights.
(
    _SB0, _SB1, _SB2, _SA0, _SA1, _SA2, _SSK, _SZK, _SCF, _SNT, _SPOS, _SFR, _SD0, _SD1,
    _SR00, _SR01, _SR02, _SR10, _SR11, _SR12, _SV0, _SV1, _SV2, _SW0, _SW1, _SW2,
) = (r * _SEP_BLOCK for r in range(26))  # fmt: skip
_SEP_FLOATS = 26
#: Rows of its int64 buffer: slot, coordinate along the pass, offset across it, core
#: flag, zero-weight reads, image x and y; and per tap, for each of the two reads, the
#: flat pixel read, whether it is inside, and its distance from the pixel (pixels).
(
    _SS, _SCI, _SBK, _SCORE, _SBAD, _SPX, _SPY, _SQ0, _SQ1, _SIN0, _SIN1, _SDI0, _SDI1,
) = (r * _SEP_BLOCK for r in range(13))  # fmt: skip
_SEP_INTS = 13
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
    rows,
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
    rows : (P,) int64, the row of ``out`` each pixel's sums go to
    out : (N, 3·R') float32, zeroed; row ``rows[k]`` gains pixel k's Σ_i w_i·sample_i

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
    last = size - 1
    last_local = span - 1
    # Flat tables (NumPy converts the offsets and cells to float32 per read, the same).
    off32 = offsets.astype(np.float32).ravel()
    wid32 = width.astype(np.float32).ravel()
    w32 = weights.ravel()
    for t in numba.prange(n_tasks):
        # The pixels go through the taps in blocks of _SEP_BLOCK, and each tap through
        # stages over the whole block: (1) the offset and weights of the tap, (2) where
        # its two reads land, (3) the reads, (4) their weights and the sums. Stages 2
        # and 4 are straight-line code over the block's buffers, which the compiler
        # vectorises; the reads of stage 3 (scalar loads: gathers measured slower) then
        # overlap. The block's values sit in two buffers (one base each, so the compiler
        # sees that the block's stores do not alias its loads). Each pixel's arithmetic
        # and the order of its sums are those of the plain loop; lanes past a partial
        # block's end hold stale values that are never read back.
        fb = np.zeros(_SEP_FLOATS * _SEP_BLOCK, np.float32)
        ib = np.zeros(_SEP_INTS * _SEP_BLOCK, np.int64)
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
                fb[_SCF + j] = np.float32(coord_i[k])
                fb[_SNT + j] = neg_inv2tau[np.uint64(mat[k])]
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
                    # Stage 1: the tap's offset (jittered per pixel) and weights.
                    if jittered[i] and key >= 0:
                        hz = np.uint64(key * 67 + i) & _M32
                        for j in range(nb):
                            s = np.uint64(ib[_SS + j]) * un + ui
                            hx, _ = _pcg3d_xy(
                                np.uint64(ib[_SPX + j]) & _M32, np.uint64(ib[_SPY + j]) & _M32, hz
                            )
                            jit = np.float32(np.float64(hx) * np.float64(_INV_2_32_F32))
                            jit = jit - np.float32(0.5)
                            jit = jit * wid32[s]
                            fb[_SPOS + j] = off32[s] + jit
                    else:
                        for j in range(nb):
                            fb[_SPOS + j] = off32[np.uint64(ib[_SS + j]) * un + ui]
                    for j in range(nb):
                        wrow = (np.uint64(ib[_SS + j]) * un + ui) * wc + u0
                        fb[_SW0 + j] = w32[wrow]
                        fb[_SW1 + j] = w32[wrow + _ONE]
                        fb[_SW2 + j] = w32[wrow + _TWO]
                    # Stage 2: where the reads land (the second one, linear reads only).
                    for j in range(_SEP_BLOCK):
                        pos = fb[_SPOS + j] * fb[_SSK + j]
                        pos = pos + fb[_SCF + j]
                        if linear:
                            p0f = np.floor(pos)
                            fb[_SFR + j] = pos - p0f
                        else:
                            p0f = np.rint(pos)
                            fb[_SFR + j] = zero
                        p0 = np.int64(p0f)
                        ci = ib[_SCI + j]
                        bk = ib[_SBK + j]
                        pc = min(max(p0, 0), last)
                        local = pc - first
                        ib[_SIN0 + j] = np.int64((p0 == pc) & (local >= 0) & (local < span))
                        ib[_SQ0 + j] = min(max(local, 0), last_local) * stride + bk
                        ib[_SDI0 + j] = abs(p0 - ci)
                        p1 = p0 + 1
                        pc = min(max(p1, 0), last)
                        local = pc - first
                        ib[_SIN1 + j] = np.int64((p1 == pc) & (local >= 0) & (local < span))
                        ib[_SQ1 + j] = min(max(local, 0), last_local) * stride + bk
                        ib[_SDI1 + j] = abs(p1 - ci)
                    # Stage 3: the reads (depth loaded whatever the slot: a select).
                    for j in range(nb):
                        q = np.uint64(ib[_SQ0 + j])
                        d = depth_flat[q]
                        fb[_SD0 + j] = d if mat_flat[q] == ib[_SS + j] else inf
                        fb[_SR00 + j] = src[q, u0]
                        fb[_SR01 + j] = src[q, u1]
                        fb[_SR02 + j] = src[q, u2]
                    if linear:
                        for j in range(nb):
                            q = np.uint64(ib[_SQ1 + j])
                            d = depth_flat[q]
                            fb[_SD1 + j] = d if mat_flat[q] == ib[_SS + j] else inf
                            fb[_SR10 + j] = src[q, u0]
                            fb[_SR11 + j] = src[q, u1]
                            fb[_SR12 + j] = src[q, u2]
                    # Stage 4: each read's weight, then the tap's value and the sums.
                    for j in range(_SEP_BLOCK):
                        wz = fb[_SD0 + j] - fb[_SZK + j]
                        if _EXP_FOLLOW:
                            wz = wz * wz
                            wz = wz * fb[_SNT + j]
                            wz = np.exp(wz)
                        else:
                            dist = np.float64(ib[_SDI0 + j])
                            near = np.float64(abs(wz) * fb[_SSK + j]) <= f32slope * dist
                            wz = one if near else zero
                        wz = wz if ib[_SIN0 + j] != 0 else zero
                        ib[_SBAD + j] += np.int64(wz == zero)
                        if linear:
                            wz = wz * (one - fb[_SFR + j])
                        fb[_SV0 + j] = zero + (fb[_SR00 + j] - fb[_SB0 + j]) * wz
                        fb[_SV1 + j] = zero + (fb[_SR01 + j] - fb[_SB1 + j]) * wz
                        fb[_SV2 + j] = zero + (fb[_SR02 + j] - fb[_SB2 + j]) * wz
                    if linear:
                        for j in range(_SEP_BLOCK):
                            wz = fb[_SD1 + j] - fb[_SZK + j]
                            if _EXP_FOLLOW:
                                wz = wz * wz
                                wz = wz * fb[_SNT + j]
                                wz = np.exp(wz)
                            else:
                                dist = np.float64(ib[_SDI1 + j])
                                near = np.float64(abs(wz) * fb[_SSK + j]) <= f32slope * dist
                                wz = one if near else zero
                            wz = wz if ib[_SIN1 + j] != 0 else zero
                            ib[_SBAD + j] += np.int64(wz == zero)
                            wz = wz * fb[_SFR + j]
                            fb[_SV0 + j] = fb[_SV0 + j] + (fb[_SR10 + j] - fb[_SB0 + j]) * wz
                            fb[_SV1 + j] = fb[_SV1 + j] + (fb[_SR11 + j] - fb[_SB1 + j]) * wz
                            fb[_SV2 + j] = fb[_SV2 + j] + (fb[_SR12 + j] - fb[_SB2 + j]) * wz
                    for j in range(_SEP_BLOCK):
                        v0 = fb[_SV0 + j] + fb[_SB0 + j]
                        v1 = fb[_SV1 + j] + fb[_SB1 + j]
                        v2 = fb[_SV2 + j] + fb[_SB2 + j]
                        fb[_SA0 + j] = fb[_SA0 + j] + fb[_SW0 + j] * v0
                        fb[_SA1 + j] = fb[_SA1 + j] + fb[_SW1 + j] * v1
                        fb[_SA2 + j] = fb[_SA2 + j] + fb[_SW2 + j] * v2
                        fb[_SV0 + j] = v0
                        fb[_SV1 + j] = v1
                        fb[_SV2 + j] = v2
                # The other terms' groups of the horizontal pass (J > 1), in their own
                # loop: inside the one above, it ran 10 % slower with J = 1 too.
                if reps > 1:
                    for j in range(nb):
                        row = (np.uint64(ib[_SS + j]) * un + ui) * wc
                        r = rows[k0 + j]
                        for rep in range(1, reps):
                            o = c0 + 3 * rep
                            wo = row + np.uint64(o)
                            out[r, o] += w32[wo] * fb[_SV0 + j]
                            out[r, o + 1] += w32[wo + _ONE] * fb[_SV1 + j]
                            out[r, o + 2] += w32[wo + _TWO] * fb[_SV2 + j]
            for j in range(nb):
                nfb += ib[_SBAD + j] * ib[_SCORE + j]
                r = rows[k0 + j]
                out[r, c0] = fb[_SA0 + j]
                out[r, c0 + 1] = fb[_SA1 + j]
                out[r, c0 + 2] = fb[_SA2 + j]
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


_F32_BIG = np.float64(np.finfo(np.float32).max)


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def finish_single(terms):
    """core.separable.apply._finish of a single term: (P, 3) float32 -> float64, NaN as 0,
    clipped to [0, float32 max] (np.clip's rule: −0 becomes +0).

    Parameters
    ----------
    terms : (P, 3) float32, the vertical pass's sums

    Returns
    -------
    (P, 3) float64
    """
    out = np.empty((terms.shape[0], 3))
    for k in numba.prange(terms.shape[0]):
        for c in range(3):
            v = np.float64(terms[k, c])
            if np.isnan(v):
                v = 0.0
            v = v if v > 0.0 else 0.0
            out[k, c] = v if v < _F32_BIG else _F32_BIG
    return out

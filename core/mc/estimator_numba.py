"""The sampling step as one compiled loop per pixel (numba backend of core.mc.estimator).

:func:`pixel_sums` does, for every active pixel and each of its samples, what
the NumPy path of :func:`core.mc.estimator.estimate_distant` does with whole
arrays: R2 point from the pixel's hashed offset, channel choice, Burley
radius (exact or fast inverse), screen offset, follow-surface tests, gather,
per-channel weight (planar, chromatic or surface distance with the area
Jacobian) and the running sums. Nothing per sample is stored, so memory is
O(pixels) and the cost is proportional to Σm.

It mirrors the NumPy arithmetic operation by operation in float32 (sums in
float64, in sample order), so both backends draw the same samples and agree
to float32 rounding. Only the transcendental functions (log, exp, sin, cos)
come from different libraries: a sample whose position lies within an ulp of
a pixel boundary may round to the neighbouring pixel in one backend
(tests/core/test_backend.py bounds how often).

Pixels are independent and each writes its own output row, so the result does
not depend on the thread count or schedule (tiles stay bit-identical to a
whole-frame run on the same backend).

This module imports numba at import time; import it through
:mod:`core.mc.backend`, which does so lazily and falls back to NumPy.
"""

from __future__ import annotations

import types

import numba
import numpy as np

from ..sampling.sequence import R2_STEP_U32

#: Geometry modes of the kernel.
PLANAR, PERSPECTIVE, ORTHO = 0, 1, 2
#: Samples that go through each stage together (see pixel_sums).
BATCH = 16
#: Pixels per parallel task (one set of batch buffers each).
PIXELS_PER_TASK = 64

_A = np.uint64(R2_STEP_U32[0])
_B = np.uint64(R2_STEP_U32[1])
_MASK = np.uint64(0xFFFFFFFF)


@numba.njit(cache=True, inline="always")
def _burley_pdf(r, inv3d, inv4d, rmax, c, mat):
    """Burley pdf of channel c at r (float32), as BurleyProfile.pdf_channels."""
    a = np.exp(inv3d[c, mat] * (-r))
    a = a * (a * a + np.float32(1.0))
    a = a * inv4d[c, mat]
    if r > rmax[c, mat]:
        a = np.float32(0.0)
    return a


def _pixel_sums(
    hx,
    hy,
    counts,
    edges,
    lo,
    hi,
    mat_a,
    x_a,
    y_a,
    inv_fw,
    inv_fh,
    idx_a,
    z_a,
    core_a,
    gam,
    g_s,
    chrom,
    fwfh,
    texel,
    mat_flat,
    area,
    d32,
    inv3d,
    inv4d,
    rmax,
    trunc,
    fast,
    w,
    h,
    full_w,
    full_h,
    ox,
    oy,
    slope,
    mode,
    unit_x,
    unit_y,
    unit_xy,
    cx,
    cy,
    want_var,
):
    """Per-pixel sums of the weighted differences of P active pixels.

    Arrays are per active pixel unless said otherwise, with the dtypes the
    NumPy path builds in :func:`core.mc.estimator.estimate_distant`.

    Parameters
    ----------
    hx, hy : (P,) uint32, hashed R2 offsets
    counts : (P,) int64, samples m ≥ 1
    edges : (P, 4) float32, cumulative channel probabilities
    lo, hi : (P, 3) float32, Burley tail bounds of the distant region
    mat_a : (P,) int, compact material slot; x_a, y_a : (P,) float32 image coords
    inv_fw, inv_fh : (P,) float32, 1/footprint (pixels per scene unit)
    idx_a : (P,) int64, flat index into the frame's arrays; z_a : (P,) float32 depth
    core_a : (P,) bool, counts towards the fallback tally
    gam : (P, 3) float32, γ_c; g_s : (P,) float32, Σγ; chrom : (P,) bool
    fwfh : (P,) float32, footprint area (ortho plane element)
    texel : (N, 4) float32, lighting B (3 channels) and depth per pixel, interleaved
        so that one sample's reads share a cache line
    mat_flat : (N,) int, slots; area : (N,) float32, surface area per pixel
    d32 : (3K,) float32; inv3d, inv4d, rmax : (3, K) float32, Burley tables
    trunc : float32, truncation in d; fast : bool, fast inverse
    w, h : int, frame (crop) size; full_w, full_h : float32, image size
    ox, oy : float32, crop origin; slope : float32, depth slope
    mode : int, PLANAR / PERSPECTIVE / ORTHO; unit_* , cx, cy : float32 camera
    want_var : bool, accumulate luminance sums for the variance

    Returns
    -------
    sums : (P, 3) float64, Σ_k w_c·(B_c(q_k) − B_c(p))
    var : (P, 2) float64, Σ y and Σ y² of the luminance of those terms
    fallback : (P,) int64, samples that fell back (core pixels only)
    """
    n = counts.shape[0]
    sums = np.zeros((n, 3))
    var = np.zeros((n, 2))
    fallback = np.zeros(n, np.int64)
    inv32 = np.float32(1.0 / 4294967296.0)
    top = np.nextafter(np.float32(1.0), np.float32(0.0))
    tiny = np.float32(np.finfo(np.float32).tiny)
    two_pi = np.float32(2.0 * np.pi)
    one = np.float32(1.0)
    zero = np.float32(0.0)
    n_chunks = (n + PIXELS_PER_TASK - 1) // PIXELS_PER_TASK
    for task in numba.prange(n_chunks):
        # Samples go through the stages in batches of BATCH: each stage's samples are
        # independent, so their long latencies (libm calls, divisions, gathers) overlap
        # instead of forming one dependent chain per sample. Per-sample arithmetic and the
        # order of the sums are those of the plain loop.
        b_ch = np.empty(BATCH, np.int64)
        b_t = np.empty(BATCH, np.float32)
        b_d = np.empty(BATCH, np.float32)
        b_v = np.empty(BATCH, np.float32)
        b_r = np.empty(BATCH, np.float32)
        b_q = np.empty(BATCH, np.int64)
        b_zq = np.empty(BATCH, np.float32)
        b_sx = np.empty(BATCH, np.float32)
        b_sy = np.empty(BATCH, np.float32)
        b_ok = np.empty(BATCH, np.bool_)
        b_w = np.empty((BATCH, 3), np.float32)
        for i in range(task * PIXELS_PER_TASK, min(n, (task + 1) * PIXELS_PER_TASK)):
            m = counts[i]
            mat = mat_a[i]
            centre = idx_a[i]
            zp = z_a[i]
            px = x_a[i]
            py = y_a[i]
            b0 = texel[centre, 0]
            b1 = texel[centre, 1]
            b2 = texel[centre, 2]
            e1 = edges[i, 1]
            e2 = edges[i, 2]
            hxi = np.uint64(hx[i])
            hyi = np.uint64(hy[i])
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            v0 = 0.0
            v1 = 0.0
            nfb = 0
            for k0 in range(1, m + 1, BATCH):
                nb = min(BATCH, m + 1 - k0)
                # Stage 1: R2 point, channel, tail value.
                for j in range(nb):
                    kk = np.uint64(k0 + j)
                    u = np.float32((hxi + kk * _A) & _MASK) * inv32
                    v = np.float32((hyi + kk * _B) & _MASK) * inv32
                    if u > top:
                        u = top
                    if v > top:
                        v = top
                    ch = 0
                    if u >= e1:
                        ch += 1
                    if u >= e2:
                        ch += 1
                    lo_sel = edges[i, ch]
                    uu = (u - lo_sel) / (edges[i, ch + 1] - lo_sel)
                    if uu < zero:
                        uu = zero
                    if uu > top:
                        uu = top
                    b_ch[j] = ch
                    b_t[j] = hi[i, ch] - uu * (hi[i, ch] - lo[i, ch])
                    b_d[j] = d32[mat * 3 + ch]
                    b_v[j] = v
                # Stage 2: Burley radius from the tail t (BurleyProfile.sample).
                for j in range(nb):
                    t = b_t[j]
                    d = b_d[j]
                    if fast:
                        t64 = min(max(np.float64(t), 1e-300), 1.0)
                        r64 = np.float64(d) * ((2.0 - 2.5715) * (1.0 - t64) - 2.0) * np.log(t64)
                        r = np.float32(max(r64, 0.0))
                    else:
                        tu = min(max(t, tiny), one)
                        g = tu * tu * np.float32(4.0) + one
                        g = np.sqrt(g)
                        g = g + np.float32(2.0) * tu
                        g = g * (np.float32(4.0) * tu)
                        g = g + one
                        g13 = np.exp(np.log(g) * np.float32(1.0 / 3.0))
                        inner = one / g13
                        inner = inner + g13
                        inner = inner + one
                        inner = inner / (np.float32(4.0) * tu)
                        r = np.log(inner) * (np.float32(3.0) * d)
                        if r < zero:
                            r = zero
                    rcap = d * trunc
                    if r > rcap:
                        r = rcap
                    b_r[j] = r
                # Stage 3: screen position and the follow-surface tests.
                for j in range(nb):
                    r = b_r[j]
                    theta = b_v[j] * two_pi
                    qx = np.cos(theta) * r * inv_fw[i] + px
                    qy = np.sin(theta) * r * inv_fh[i] + py
                    if qx < np.float32(-1.0):
                        qx = np.float32(-1.0)
                    if qx > full_w:
                        qx = full_w
                    if qy < np.float32(-1.0):
                        qy = np.float32(-1.0)
                    if qy > full_h:
                        qy = full_h
                    b_sx[j] = qx
                    b_sy[j] = qy
                    qx = np.rint(qx) - ox
                    qy = np.rint(qy) - oy
                    ok = (qx >= 0) and (qx < w) and (qy >= 0) and (qy < h)
                    q = centre
                    zq = zp
                    if ok:
                        q = np.int64(qy) * w + np.int64(qx)
                        ok = mat_flat[q] == mat
                        zq = texel[q, 3]
                        ok = ok and (abs(zq - zp) <= slope * r)
                    if not ok:
                        if core_a[i]:
                            nfb += 1
                    b_ok[j] = ok
                    b_q[j] = q
                    b_zq[j] = zq
                # Stage 4: per-channel weights of the accepted samples.
                for j in range(nb):
                    if not b_ok[j]:
                        continue
                    r = b_r[j]
                    if mode != PLANAR:
                        q = b_q[j]
                        zq = b_zq[j]
                        sx = b_sx[j]
                        sy = b_sy[j]
                        if mode == ORTHO:
                            dx = (sx - px) * unit_x
                            dy = (sy - py) * unit_y
                            plane = fwfh[i]
                        else:
                            dx = ((sx - cx) * zq - (px - cx) * zp) * unit_x
                            dy = ((sy - cy) * zq - (py - cy) * zp) * unit_y
                            plane = zp * zp * unit_xy
                        dz = zq - zp
                        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
                        if dist < np.float32(1e-30):
                            dist = np.float32(1e-30)
                        jac = area[q] / plane
                        norm = (
                            _burley_pdf(r, inv3d, inv4d, rmax, 0, mat)
                            + _burley_pdf(r, inv3d, inv4d, rmax, 1, mat)
                            + _burley_pdf(r, inv3d, inv4d, rmax, 2, mat)
                        )
                        scale = zero
                        if norm > zero:
                            scale = g_s[i] * (r / dist) * jac / norm
                        b_w[j, 0] = _burley_pdf(dist, inv3d, inv4d, rmax, 0, mat) * scale
                        b_w[j, 1] = _burley_pdf(dist, inv3d, inv4d, rmax, 1, mat) * scale
                        b_w[j, 2] = _burley_pdf(dist, inv3d, inv4d, rmax, 2, mat) * scale
                    elif chrom[i]:
                        p0 = _burley_pdf(r, inv3d, inv4d, rmax, 0, mat)
                        p1 = _burley_pdf(r, inv3d, inv4d, rmax, 1, mat)
                        p2 = _burley_pdf(r, inv3d, inv4d, rmax, 2, mat)
                        norm = p0 + p1 + p2
                        scale = zero
                        if norm > zero:
                            scale = g_s[i] / norm
                        b_w[j, 0] = p0 * scale
                        b_w[j, 1] = p1 * scale
                        b_w[j, 2] = p2 * scale
                    else:
                        b_w[j, 0] = gam[i, 0]
                        b_w[j, 1] = gam[i, 1]
                        b_w[j, 2] = gam[i, 2]
                # Stage 5: gather and sum, in sample order (a rejected sample reads the
                # centre: its difference is exactly 0, so it is skipped).
                for j in range(nb):
                    if not b_ok[j]:
                        continue
                    q = b_q[j]
                    d0 = (texel[q, 0] - b0) * b_w[j, 0]
                    d1 = (texel[q, 1] - b1) * b_w[j, 1]
                    d2 = (texel[q, 2] - b2) * b_w[j, 2]
                    s0 += np.float64(d0)
                    s1 += np.float64(d1)
                    s2 += np.float64(d2)
                    if want_var:
                        y = d0 * np.float32(0.2126) + d1 * np.float32(0.7152)
                        y = y + d2 * np.float32(0.0722)
                        y64 = np.float64(y)
                        v0 += y64
                        v1 += y64 * y64
            sums[i, 0] = s0
            sums[i, 1] = s1
            sums[i, 2] = s2
            var[i, 0] = v0
            var[i, 1] = v1
            fallback[i] = nfb
    return sums, var, fallback


#: Parallel over pixels; for large frames.
pixel_sums = numba.njit(parallel=True, cache=True, nogil=True)(_pixel_sums)
# The same code compiled without threads, for small work (a tile, a tiny frame): waking
# the thread pool costs more than it saves there, and far more on an oversubscribed
# machine (measured 4x slower per 32x32 frame under load). Same bits as the parallel one:
# every pixel is computed by one thread, in sample order. Its own name keeps numba's
# disk-cache entries of the two apart.
_serial = types.FunctionType(_pixel_sums.__code__, _pixel_sums.__globals__, "pixel_sums_serial")
_serial.__qualname__ = "pixel_sums_serial"
_serial.__doc__ = _pixel_sums.__doc__
pixel_sums_serial = numba.njit(cache=True, nogil=True)(_serial)
#: Below this many samples the serial kernel runs.
PARALLEL_MIN_SAMPLES = 1 << 16


def kernel(samples: int):
    """The compiled kernel for a call taking ``samples`` samples (serial below a threshold)."""
    return pixel_sums if samples >= PARALLEL_MIN_SAMPLES else pixel_sums_serial


def warm_up() -> None:
    """Run the kernels once on one pixel (compiles them, or loads them from the disk cache)."""
    for fn in (pixel_sums, pixel_sums_serial):
        _warm(fn)


def _warm(fn) -> None:
    f32 = np.float32
    one = np.ones(1, f32)
    fn(
        np.zeros(1, np.uint32),
        np.zeros(1, np.uint32),
        np.ones(1, np.int64),
        np.array([[0, 1, 1, 1]], f32),
        np.full((1, 3), 0.1, f32),
        np.full((1, 3), 0.5, f32),
        np.ones(1, np.int32),
        np.zeros(1, f32),
        np.zeros(1, f32),
        one,
        one,
        np.zeros(1, np.int64),
        one,
        np.ones(1, np.bool_),
        np.full((1, 3), 0.5, f32),
        np.full(1, 1.5, f32),
        np.zeros(1, np.bool_),
        one,
        np.ones((1, 4), f32),
        np.ones(1, np.int32),
        one,
        np.ones(6, f32),
        np.ones((3, 2), f32),
        np.ones((3, 2), f32),
        np.ones((3, 2), f32),
        f32(16.0),
        False,
        1,
        1,
        f32(1.0),
        f32(1.0),
        f32(0.0),
        f32(0.0),
        f32(2.0),
        PLANAR,
        f32(1.0),
        f32(1.0),
        f32(1.0),
        f32(0.0),
        f32(0.0),
        True,
    )

"""The sampling step as one compiled loop per pixel (numba backend of core.mc.estimator).

:func:`pixel_sums` does, for every active pixel, what
:func:`core.mc.estimator.active_pixels` does with arrays (its hash, channel
edges and tail map), and for each of its samples what the NumPy path of
:func:`core.mc.estimator.estimate_distant` does with whole arrays: R2 point,
channel, radius and mixture density from the profile's tables, direction
from the direction table, screen position, follow-surface tests, gather,
per-channel weight (planar, chromatic or surface distance with the area
Jacobian) and the running sums. Nothing per sample is stored, so memory is
O(pixels) and the cost is proportional to Σm.

It mirrors the NumPy arithmetic operation by operation in float32 (sums in
float64, in sample order). Neither side calls a library function per sample
(the tables replace log, exp, sin and cos), so both backends draw the same
samples and agree to float32 rounding; tests/core/test_backend.py checks it.

Tables are read flat, with unsigned indices: numba then emits no
negative-index wrap-around test per read. A pixel's lighting, depth, surface
area and slot share one 32-byte texel, so a sample's reads touch one cache
line.

Pixels are independent and each writes its own output row, so the result does
not depend on the thread count, the schedule or the order the pixels are
visited in (32×32 tiles, :func:`tile_order`; tiles of core.tiling stay
bit-identical to a whole-frame run on the same backend).

The module also holds compiled twins of the other per-frame steps, each the
same arithmetic as its NumPy original and tested bit for bit against it: the
depth-buffer surface, the Burley region, the SPVG counts and history update,
the whole history step of the methods without an online control variate
(tracked luminance, update and float32 stores in place), the composite and
float maps, the history reprojection, the separable passes (the
``separable`` method and the temporal methods' noise-free proxy) and the
temporal reuse's 3×3 neighbourhood statistics.

This module imports numba at import time; import it through
:mod:`core.mc.backend`, which does so lazily and falls back to NumPy.
"""

from __future__ import annotations

import math
import types

import numba
import numpy as np

from ..eval.color import REC709
from ..sampling.sequence import DIRECTION_BITS, DIRECTIONS, R2_STEP_U32

#: Geometry modes of the kernel.
PLANAR, PERSPECTIVE, ORTHO = 0, 1, 2
#: Samples that go through each stage together (see pixel_sums): enough independent
#: work to overlap the latencies of the reads, square roots and divisions (8 measured
#: 60 % slower per sample: stage 3 then runs scalar; 32 the same).
BATCH = 16
#: The vectorised loops' shorter run (stages 1a, 2a, 2b and 3), for a batch of at most
#: this many samples: one vector of float32 lanes on AVX2 (and on AVX-512, where LLVM
#: keeps 256-bit vectors).
HALF = 8
#: Rows of the per-task batch buffer (see pixel_sums): each value's offset in it.
_ROWS = 15
(
    _ROW_R,
    _ROW_QX,
    _ROW_QY,
    _ROW_ZQ,
    _ROW_N,
    _ROW_G,
    _ROW_FX,
    _ROW_FY,
    _ROW_A,
    _ROW_MX,
    _ROW_MY,
    _ROW_X,
    _ROW_S,
    _ROW_T,
    _ROW_K,
) = range(0, _ROWS * BATCH, BATCH)
#: Pixels per parallel task (one set of batch buffers each). 256 rather than 64: the
#: same bits, 1-3 % less time per call (minimum of 15 interleaved calls of
#: docs/checks/kernel_versus.py at 34 spp and at 4-8 spp; presumably the task's
#: buffer allocations and loop starts spread over more pixels); 128 and 512 alike.
PIXELS_PER_TASK = 256
#: Side of the square pixel tiles the kernel visits the pixels in (see tile_order).
TILE = 32
_M32 = np.uint64(0xFFFFFFFF)
# numba does integer arithmetic in 64 bits: the R2 step wraps modulo 2**32 by the mask.
_A = np.uint64(R2_STEP_U32[0])
_B = np.uint64(R2_STEP_U32[1])
_DIR_SHIFT = np.uint64(32 - DIRECTION_BITS)
_LCG_A = np.uint64(1664525)
_LCG_C = np.uint64(1013904223)
_S16 = np.uint64(16)
_M16 = np.uint64(0xFFFF)
_ONE, _TWO, _THREE, _FOUR = np.uint64(1), np.uint64(2), np.uint64(3), np.uint64(4)
_FIVE, _SIX, _SEVEN, _EIGHT = np.uint64(5), np.uint64(6), np.uint64(7), np.uint64(8)


@numba.njit(cache=True, inline="always", error_model="numpy")
def _pcg3d_xy(x, y, z):
    """The first two words of :func:`core.sampling.sequence.pcg3d` (uint32 arithmetic
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


def _pixel_sums(
    active,
    order,
    counts,
    gx,
    gy,
    gamma,
    gamma_sum,
    lo,
    hi,
    gmat,
    fw,
    fh,
    gdepth,
    gindex,
    chromatic,
    gcore,
    seed_z,
    dtab,
    texel,
    rtab,
    trunc,
    dirs,
    pscale,
    inv_d,
    ptab,
    ntab,
    aspect,
    disk,
    hidden,
    direct,
    use_obj,
    inv_k,
    touch,
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
    ux64,
    uy64,
    cx64,
    cy64,
    want_var,
    distant,
    start,
    threads,
):
    """Adds to ``distant`` the mean weighted difference of each of the P active SSS pixels.

    Does, per pixel, what :func:`core.mc.estimator.active_pixels` does with
    arrays (hash, channel edges, the affine map u ↦ tail value, float32
    copies), then per sample what :func:`core.mc.estimator._numpy_sums` does,
    operation by operation in float32 (sums in float64, in sample order).

    Parameters
    ----------
    active : (P,) int64, the active pixels (indices into the Geometry's arrays)
    order : (P,) int64, the order to visit them in (a permutation of 0…P−1; see
        :func:`tile_order`): results are per pixel, so the order changes only the speed
    counts : (G,) int64, samples per SSS pixel of the Geometry (m ≥ 1 where active)
    gx, gy : (G,) int64 image coords; gamma, lo, hi : (G, 3) float64; gamma_sum : (G,)
    gmat : (G,) int32 compact slot; fw, fh, gdepth : (G,) float64, scene units
    gindex : (G,) int64, flat index into the frame's arrays; chromatic, gcore : (G,) bool
    seed_z : uint64, ``frame ^ seed`` (the hash's third word)
    dtab : (K, 3) float64, Burley d per slot (scene units)
    texel : (8N,) float32, per pixel B (3 channels), depth, surface area carrying the
        sign of the normal's z, compact slot (plus K times the object with ``use_obj``;
        exact in float32) and the normal's x
        and y (z = ±√(1 − x² − y²)): 32 bytes, so a sample's reads share one cache line
    rtab : (2(S + 1),) float32, radius table (flat); trunc : float32, truncation in d
    dirs : (2·2**DIRECTION_BITS,) float32, direction table (flat)
    pscale, inv_d : (3, K) float32, pdf table scale size/(truncate·d) and 1/d
    ptab : (2(S + 1),) float32, unit pdf table (flat)
    ntab : (12K·(S + 1),) float32, the channel mixture's density per slot and drawn
        channel (:func:`core.profiles.burley.norm_table`, flat)
    aspect : float32, footprint width / height
    disk : bool, weigh with the kernel of Cycles' disk estimator (texel normals)
    hidden : float32, the hidden-light share β (< 1: rejected samples on the background
        or another material or object count −(1 − β)·B_direct(p) at their planar weight)
    direct : (G, 3) float32, the direct part of B of the Geometry's pixels
    use_obj : bool, the texels' slot carries the object (``slot + K·object``):
        a sample on another object is rejected (or, within ``touch·r`` of the
        centre's tangent plane, counts unlit at its point of that plane)
    inv_k : float32, 1/K (a power of two); touch : float32, SSSParams.contact (0: off)
    w, h : int, frame (crop) size; full_w, full_h : float32, image size
    ox, oy : int, crop origin; slope : float32, depth slope
    mode : int, PLANAR / PERSPECTIVE / ORTHO; unit_* , cx, cy : float32 camera;
        ux64, uy64, cx64, cy64 : the same in float64 (the tangent planes)
    want_var : bool, accumulate luminance sums for the variance
    distant : (G, 3) float64, written in place: row ``active[i]`` gains
        Σ_k w_c·(B_c(q_k) − B_c(p)) / m, the pixel's sum over its m samples divided
        by m, as :func:`core.mc.estimator.estimate_distant` adds the NumPy sums (the
        same float64 operations)
    start : bool, instead set row ``active[i]`` to γ_c·B_c(p) (float64) plus that mean,
        as estimate_distant's NumPy γ·B then ``+=`` (its entries may be uninitialised)
    threads : int, the threads the parallel build runs on (``numba.get_num_threads()``;
        the tasks are dealt out over them; read here, the kernel could not be cached)

    Returns
    -------
    var : (P, 2) float64, Σ y and Σ y² of the luminance of those terms ((0, 2) without
        ``want_var``)
    fallback : (T,) int64, samples that fell back (core pixels only), per task of
        PIXELS_PER_TASK pixels
    """
    n = active.shape[0]
    n_chunks = (n + PIXELS_PER_TASK - 1) // PIXELS_PER_TASK
    # Not zeroed: every entry is written below.
    var = np.empty((n if want_var else 0, 2))
    fallback = np.empty(n_chunks, np.int64)
    inv32 = np.float32(2.0**-32)
    top = np.nextafter(np.float32(1.0), np.float32(0.0))
    one = np.float32(1.0)
    zero = np.float32(0.0)
    size = np.float32(rtab.shape[0] // 2 - 1)
    nrows = np.uint64(rtab.shape[0] // 2)
    psize = np.float32(ptab.shape[0] // 2 - 1)
    # The tasks dealt out to the threads like cards: numba splits a prange into one run
    # of consecutive iterations per thread, and tasks in tile order would give each thread
    # one part of the image; where the adaptive counts gather (a lit region at 64 spp,
    # the rest at β_min) one thread then waits for the other. Iteration t, in the run
    # of thread t // per, does task (t % per)·threads + t // per: each thread takes
    # every threads-th task of the image (on 2 threads 2-5 % less time per call on
    # steady frames, median of 3 runs of docs/checks/task_deal.py; the same bits).
    threads = max(threads, 1)
    per = (n_chunks + threads - 1) // threads
    for t in numba.prange(threads * per):
        task = (t % per) * threads + t // per
        if task >= n_chunks:
            continue
        # Samples go through the stages in batches of BATCH: each stage's samples are
        # independent (straight-line code over table reads, no library calls), so the
        # reads and long latencies of a batch overlap. Per-sample arithmetic and the
        # order of the sums are those of the plain loop.
        # One buffer for the batch's float32 values (rows of BATCH): the
        # compiler then sees that stage 3's stores cannot alias its loads, and
        # vectorises it (with one array per value it did not).
        # Zeroed: stage 3 runs over the whole batch (see there), and reads entries past
        # a partial batch's end.
        fb = np.zeros(_ROWS * BATCH, np.float32)
        b_q = np.empty(BATCH, np.int64)
        b_ch = np.empty(BATCH, np.int64)
        b_in = np.empty(BATCH, np.bool_)
        b_ok = np.zeros(BATCH, np.bool_)
        b_fill = np.empty(BATCH, np.bool_)
        b_touch = np.zeros(BATCH, np.bool_)
        b_w = np.empty((3, BATCH), np.float32)
        idch = np.empty(3, np.float32)
        # R2 word offsets of a batch's lanes: j·a mod 2**32.
        lane_a = np.empty(BATCH, np.uint64)
        for j in range(BATCH):
            lane_a[j] = (np.uint64(j) * _A) & _M32
        dch = np.empty(3, np.float32)
        first = task * PIXELS_PER_TASK
        last = min(n, first + PIXELS_PER_TASK)
        # The task's pixels' hashes, channel edges and tail maps (as active_pixels),
        # their normals, disk axes and tangent planes, first for all of them:
        # independent chains of multiplies, square roots and divisions overlap here,
        # where inside the sample loop each pixel waited for its own (the planes
        # moved here measured 9 % less time per call at 2 spp, the same at 34).
        t_hash = np.empty((PIXELS_PER_TASK, 2), np.uint64)
        t_e = np.empty((PIXELS_PER_TASK, 2), np.float32)
        t_map = np.empty((PIXELS_PER_TASK, 2, 3), np.float32)
        t_geo = np.empty((PIXELS_PER_TASK, 13), np.float32)
        nfb = 0
        for k in range(first, last):
            li = k - first
            i = order[k]
            g = active[i]
            hxi, hyi = _pcg3d_xy(np.uint64(gx[g]) & _M32, np.uint64(gy[g]) & _M32, seed_z)
            t_hash[li, 0] = hxi
            t_hash[li, 1] = hyi
            g0 = gamma[g, 0]
            g1 = gamma[g, 1]
            g2 = gamma[g, 2]
            gs = gamma_sum[g]
            e1 = np.float32(g0 / gs) if (g1 > 0 or g2 > 0) else one
            e2 = np.float32((g0 + g1) / gs) if g2 > 0 else one
            t_e[li, 0] = e1
            t_e[li, 1] = e2
            for c in range(3):
                ec = 0.0 if c == 0 else (np.float64(e1) if c == 1 else np.float64(e2))
                en = np.float64(e1) if c == 0 else (np.float64(e2) if c == 1 else 1.0)
                width = en - ec
                sl = 1.0 / max(width, 1e-300) if width > 0 else 0.0
                tb = (lo[g, c] - hi[g, c]) * sl
                t_map[li, 0, c] = np.float32(hi[g, c] - tb * ec)
                t_map[li, 1, c] = np.float32(tb)
            centre = gindex[g]
            # The centre's normal, disk axes and tangent plane (as disk_frame and
            # tangent_planes of core.mc.estimator).
            use_plane = mode != PLANAR
            pa = np.float32(np.nan)  # no plane (planar mode, or a plane through the camera)
            pb = np.float32(np.nan)
            pc = np.float32(np.nan)
            nx = ny = nz = tx = ty = tz = bx = by = bz = zero
            rho_min = zero
            if use_plane:
                c8 = np.uint64(centre) * _EIGHT
                nx = texel[c8 + _SIX]
                ny = texel[c8 + _SEVEN]
                nz = np.float32(
                    math.copysign(np.sqrt(max(one - (nx * nx + ny * ny), zero)), texel[c8 + _FOUR])
                )
                alike = (nx == ny) and (nx == nz)
                tx = nz - ny
                ty = nx + nz if alike else nx - nz
                tz = -ny - nx if alike else ny - nx
                tl = one / np.sqrt(tx * tx + ty * ty + tz * tz)
                tx = tx * tl
                ty = ty * tl
                tz = tz * tl
                bx = ny * tz - nz * ty
                by = nz * tx - nx * tz
                bz = nx * ty - ny * tx
                rho_min = np.float32(0.5 * fw[g])
                n64x = np.float64(nx)
                n64y = np.float64(ny)
                n64z = np.float64(nz)
                z64 = gdepth[g]
                x64 = np.float64(gx[g])
                y64 = np.float64(gy[g])
                if mode == ORTHO:
                    if abs(n64z) > 1e-6:
                        inv = -1.0 / n64z
                        a64 = n64x * ux64 * inv
                        b64 = n64y * uy64 * inv
                        pa = np.float32(a64)
                        pb = np.float32(b64)
                        pc = np.float32(z64 - a64 * x64 - b64 * y64)
                else:
                    qx64 = (x64 - cx64) * ux64 * z64
                    qy64 = (y64 - cy64) * uy64 * z64
                    dot = n64x * qx64 + n64y * qy64 + n64z * z64
                    if abs(dot) > 1e-6 * z64:
                        inv = 1.0 / dot
                        pa = np.float32(n64x * ux64 * inv)
                        pb = np.float32(n64y * uy64 * inv)
                        pc = np.float32((n64z - n64x * ux64 * cx64 - n64y * uy64 * cy64) * inv)
            t_geo[li, 0] = pa
            t_geo[li, 1] = pb
            t_geo[li, 2] = pc
            t_geo[li, 3] = nx
            t_geo[li, 4] = ny
            t_geo[li, 5] = nz
            t_geo[li, 6] = tx
            t_geo[li, 7] = ty
            t_geo[li, 8] = tz
            t_geo[li, 9] = bx
            t_geo[li, 10] = by
            t_geo[li, 11] = bz
            t_geo[li, 12] = rho_min
        for k in range(first, last):
            li = k - first
            i = order[k]
            g = active[i]
            m = counts[g]
            mat = gmat[g]
            centre = gindex[g]
            hxi = t_hash[li, 0]
            hyi = t_hash[li, 1]
            e1 = t_e[li, 0]
            e2 = t_e[li, 1]
            g0 = gamma[g, 0]
            g1 = gamma[g, 1]
            g2 = gamma[g, 2]
            gs = gamma_sum[g]
            for c in range(3):
                dch[c] = np.float32(dtab[mat, c])
                idch[c] = inv_d[c, mat]
            zp = np.float32(gdepth[g])
            px = np.float32(gx[g])
            py = np.float32(gy[g])
            rpx = np.float32(1.0 / fw[g])
            g_s = np.float32(gs)
            plane = zp * zp * unit_xy if mode == PERSPECTIVE else np.float32(fw[g] * fh[g])
            use_plane = mode != PLANAR
            pa = t_geo[li, 0]
            pb = t_geo[li, 1]
            pc = t_geo[li, 2]
            nx = t_geo[li, 3]
            ny = t_geo[li, 4]
            nz = t_geo[li, 5]
            tx = t_geo[li, 6]
            ty = t_geo[li, 7]
            tz = t_geo[li, 8]
            bx = t_geo[li, 9]
            by = t_geo[li, 10]
            bz = t_geo[li, 11]
            rho_min = t_geo[li, 12]
            slot3 = np.uint64(mat) * np.uint64(3)
            # The slot's pdf table scales and 1/d, per channel (loop invariants).
            ks0 = pscale[0, mat]
            ks1 = pscale[1, mat]
            ks2 = pscale[2, mat]
            i0 = inv_d[0, mat]
            i1 = inv_d[1, mat]
            i2 = inv_d[2, mat]
            chrom = chromatic[g]
            core = gcore[g]
            c8 = np.uint64(centre) * _EIGHT
            b0 = texel[c8]
            b1 = texel[c8 + _ONE]
            b2 = texel[c8 + _TWO]
            # The centre's slot (and object): a sample is accepted on the same key only.
            key = texel[c8 + _FIVE]
            obj = np.floor(key * inv_k)
            area_p = abs(texel[c8 + _FOUR])
            use_touch = use_obj and touch > zero
            use_fill = hidden < one
            f0 = np.float32(-(one - hidden)) * direct[g, 0]
            f1 = np.float32(-(one - hidden)) * direct[g, 1]
            f2 = np.float32(-(one - hidden)) * direct[g, 2]
            # The pixel's tail maps per channel (offset, slope), for stage 1a's selects.
            tm00 = t_map[li, 0, 0]
            tm01 = t_map[li, 0, 1]
            tm02 = t_map[li, 0, 2]
            tm10 = t_map[li, 1, 0]
            tm11 = t_map[li, 1, 1]
            tm12 = t_map[li, 1, 2]
            s0 = 0.0
            s1 = 0.0
            s2 = 0.0
            v0 = 0.0
            v1 = 0.0
            for k0 in range(1, m + 1, BATCH):
                nb = min(BATCH, m + 1 - k0)
                # Entries the vectorised loops (stages 1a, 2a, 2b, 3) run over: whole
                # vectors, HALF for a batch of at most HALF samples, else BATCH (see
                # stage 3).
                lanes = HALF if nb <= HALF else BATCH
                # Stages 1 and 2 each run as two loops: the first computes the table
                # and texel positions, the second reads them. A read that misses L1
                # then waits beside the other samples' reads, not at the head of a
                # long chain of arithmetic (measured 7 % less time per sample).
                # Stage 1a: R2 point, channel, position in the radius table. Written so
                # that the compiler vectorises it (measured 3-4 % less time per call at
                # 34 spp): no multiply of 64-bit integers (the batch's R2 words are its
                # first plus a per-lane constant), the word turned into float32 through
                # its two exact 16-bit halves (AVX2 has no vector conversion from 64-bit
                # or unsigned integers; one rounding, so the same float32), the channel
                # and its tail map by selects, and like stage 3 over whole vectors
                # (entries past nb are never read).
                base_u = (hxi + np.uint64(k0) * _A) & _M32
                for j in range(lanes):
                    v = (base_u + lane_a[j]) & _M32
                    u = np.float32(np.int32(v >> _S16)) * np.float32(65536.0)
                    u = (u + np.float32(np.int32(v & _M16))) * inv32
                    u = min(u, top)
                    # e1 <= e2, so the channel is the number of edges u passed.
                    hi1 = u >= e1
                    hi2 = u >= e2
                    sl = tm11 if hi1 else tm10
                    sl = tm12 if hi2 else sl
                    of = tm01 if hi1 else tm00
                    of = tm02 if hi2 else of
                    t = sl * u + of
                    t = min(max(t, zero), one)
                    fb[_ROW_T + j] = np.sqrt(t) * size
                    b_ch[j] = np.int64(hi1) + np.int64(hi2)
                # Stage 1b: radius (and mixture density) from the tables, screen position.
                for j in range(nb):
                    kk = np.uint64(k0 + j)
                    ch = b_ch[j]
                    s = fb[_ROW_T + j]
                    si = np.int32(s)  # as in _pdf
                    ti = np.uint64(np.uint32(si))
                    f = s - np.float32(si)
                    rho = f * rtab[ti * _TWO + _ONE] + rtab[ti * _TWO]
                    r = min(rho, trunc) * dch[ch]
                    if mode != PLANAR:
                        # The channel mixture's density at r, from the slot's table.
                        row = ((slot3 + np.uint64(ch)) * nrows + ti) * _FOUR
                        nv = f * ntab[row + _ONE] + ntab[row]
                        if s < ntab[row + _TWO]:
                            nv -= ntab[row + _THREE]
                        fb[_ROW_N + j] = nv * idch[ch]
                    di = ((hyi + kk * _B) & _M32) >> _DIR_SHIFT
                    rp = r * rpx
                    qx = rp * dirs[di * _TWO] + px
                    qy = rp * dirs[di * _TWO + _ONE] * aspect + py
                    fb[_ROW_R + j] = r
                    fb[_ROW_QX + j] = min(max(qx, np.float32(-1.0)), full_w)
                    fb[_ROW_QY + j] = min(max(qy, np.float32(-1.0)), full_h)
                # Stage 2a: the landing pixel (for whole vectors), its depth and key.
                for j in range(lanes):
                    fx = np.rint(fb[_ROW_QX + j])
                    fy = np.rint(fb[_ROW_QY + j])
                    ix = np.int64(np.int32(fx)) - ox
                    iy = np.int64(np.int32(fy)) - oy
                    inside = (ix >= 0) & (ix < w) & (iy >= 0) & (iy < h)
                    b_in[j] = inside
                    b_q[j] = iy * w + ix if inside else centre
                    fb[_ROW_FX + j] = fx
                    fb[_ROW_FY + j] = fy
                for j in range(nb):
                    q8 = np.uint64(b_q[j]) * _EIGHT
                    fb[_ROW_ZQ + j] = texel[q8 + _THREE]
                    fb[_ROW_K + j] = texel[q8 + _FIVE]
                # Stage 2b: the follow-surface tests. First the accept test for whole
                # vectors, without a branch (vectorised); entries past nb are never read.
                for j in range(lanes):
                    zq = fb[_ROW_ZQ + j]
                    tol = slope * fb[_ROW_R + j]
                    near = abs(zq - zp) <= tol
                    # Or within the tolerance of the centre's tangent plane.
                    wpl = pa * fb[_ROW_FX + j] + pb * fb[_ROW_FY + j] + pc
                    if mode == ORTHO:
                        on_plane = abs(zq - wpl) <= tol
                    else:
                        on_plane = (wpl > zero) & (abs(zq * wpl - one) <= tol * wpl)
                    near = near | (use_plane & on_plane)
                    b_ok[j] = b_in[j] & (fb[_ROW_K + j] == key) & near
                # Then per sample: the landing texel's area and normal for stage 3's
                # branch-free arithmetic, and what becomes of a rejected sample.
                for j in range(nb):
                    if b_ok[j]:
                        b_fill[j] = False
                        b_touch[j] = False
                        if use_plane:
                            q8 = np.uint64(b_q[j]) * _EIGHT
                            fb[_ROW_A + j] = texel[q8 + _FOUR]
                            fb[_ROW_MX + j] = texel[q8 + _SIX]
                            fb[_ROW_MY + j] = texel[q8 + _SEVEN]
                        continue
                    inside = b_in[j]
                    q = b_q[j]
                    zq = fb[_ROW_ZQ + j]
                    ok = False
                    touching = False
                    area_t = zero
                    if inside and use_touch and np.floor(fb[_ROW_K + j] * inv_k) != obj:
                        # Another object: does it touch the centre's tangent plane?
                        dz = zq - zp
                        if mode == PLANAR:
                            hq = abs(dz)
                        else:
                            qx = fb[_ROW_QX + j]
                            qy = fb[_ROW_QY + j]
                            if mode == ORTHO:
                                dx = (qx - px) * unit_x
                                dy = (qy - py) * unit_y
                            else:
                                dx = ((qx - cx) * zq - (px - cx) * zp) * unit_x
                                dy = ((qy - cy) * zq - (py - cy) * zp) * unit_y
                            hq = abs(dx * nx + dy * ny + dz * nz)
                        touching = hq <= touch * fb[_ROW_R + j]
                    fill = False
                    if touching:
                        # Unlit, at its point of the centre's tangent plane (the plane's
                        # depth along the sample's ray, the centre's area element).
                        ok = True
                        if mode != PLANAR:
                            wq = pa * fb[_ROW_QX + j] + pb * fb[_ROW_QY + j] + pc
                            if mode == ORTHO:
                                zq = wq if np.isfinite(wq) else zp
                                area_t = area_p
                            else:
                                zq = one / wq if wq > zero else zp
                                ratio = zq / zp
                                area_t = area_p * ratio * ratio
                    else:
                        # Hidden surface: on the image, not in front of the centre.
                        fill = use_fill and inside and not (zp - zq > np.float32(0.1) * zp)
                        q = centre
                        zq = zp
                        if core:
                            nfb += 1
                    b_fill[j] = fill
                    b_ok[j] = ok
                    b_touch[j] = touching
                    b_q[j] = q
                    fb[_ROW_ZQ + j] = zq
                    if use_plane:
                        q8 = np.uint64(q) * _EIGHT
                        fb[_ROW_A + j] = area_t if touching else texel[q8 + _FOUR]
                        fb[_ROW_MX + j] = texel[q8 + _SIX]
                        fb[_ROW_MY + j] = texel[q8 + _SEVEN]
                # Stage 3: per-channel weights of the accepted samples (and the planar
                # weights of the hidden-surface ones). In the surface modes the arithmetic
                # (distance, Cycles' disk gain, scale: the square roots and divisions) runs
                # first for the whole batch without a branch, so the compiler vectorises
                # it; the table reads follow in a scalar loop. A rejected sample computes
                # values it never uses (from the centre's texel): selects, not branches.
                # It runs over whole vectors, also in a partial batch (the last of most
                # pixels): a loop of nb iterations runs the compiler's scalar remainder
                # when nb is short of its vector width, measured ~12 % slower per sample
                # at 21 spp. A batch of at most HALF samples runs HALF entries (one
                # vector of 8 float32 lanes), a larger one all BATCH: at 1–8 spp the
                # pass took 10–16 % less time than over all BATCH (the same at 34 spp).
                # Entries past nb hold the previous batch's values (zeros at first);
                # what they compute is never read.
                if mode != PLANAR:
                    for j in range(lanes):
                        r = fb[_ROW_R + j]
                        zq = fb[_ROW_ZQ + j]
                        if mode == ORTHO:
                            dx = (fb[_ROW_QX + j] - px) * unit_x
                            dy = (fb[_ROW_QY + j] - py) * unit_y
                        else:
                            dx = ((fb[_ROW_QX + j] - cx) * zq - (px - cx) * zp) * unit_x
                            dy = ((fb[_ROW_QY + j] - cy) * zq - (py - cy) * zp) * unit_y
                        dz = zq - zp
                        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
                        if dist < np.float32(1e-30):
                            dist = np.float32(1e-30)
                        norm = fb[_ROW_N + j]
                        area_q = fb[_ROW_A + j]
                        gq = one
                        if disk:
                            # Cycles' disk kernel: G = |Δ|·Σ_a m_a/ρ_a.
                            mx = fb[_ROW_MX + j]
                            my = fb[_ROW_MY + j]
                            mz = np.float32(
                                math.copysign(np.sqrt(max(one - (mx * mx + my * my), zero)), area_q)
                            )
                            # From the landing pixel's own point: on a plane, G = 1.
                            if mode == ORTHO:
                                ex = (fb[_ROW_FX + j] - px) * unit_x
                                ey = (fb[_ROW_FY + j] - py) * unit_y
                            else:
                                ex = ((fb[_ROW_FX + j] - cx) * zq - (px - cx) * zp) * unit_x
                                ey = ((fb[_ROW_FY + j] - cy) * zq - (py - cy) * zp) * unit_y
                            aN = ex * nx + ey * ny + dz * nz
                            aT = ex * tx + ey * ty + dz * tz
                            aB = ex * bx + ey * by + dz * bz
                            cN = abs(mx * nx + my * ny + mz * nz) * np.float32(0.5)
                            cT = abs(mx * tx + my * ty + mz * tz) * np.float32(0.25)
                            cB = abs(mx * bx + my * by + mz * bz) * np.float32(0.25)
                            cN = cN * cN
                            cT = cT * cT
                            cB = cB * cB
                            total = cN + cT + cB
                            # G = Σ_a c_a·(|Δ|/ρ_a)/total with the squares of ρ_a/|Δ|
                            # (clamped at ρ_min) and two divisions.
                            l2 = aN * aN + aT * aT + aB * aB
                            lo2 = rho_min * rho_min
                            il2 = one / l2
                            qN = max(aT * aT + aB * aB, lo2) * il2
                            qT = max(aB * aB + aN * aN, lo2) * il2
                            qB = max(aN * aN + aT * aT, lo2) * il2
                            big = one / (qN * qT * qB * (total * total))
                            gv = cN * np.sqrt(qT * qB * big)
                            gv = gv + cT * np.sqrt(qB * qN * big)
                            gv = gv + cB * np.sqrt(qN * qT * big)
                            if total > zero and l2 > zero:
                                gq = gv
                        scale = zero
                        fscale = zero
                        if norm > zero:
                            scale = g_s * r * abs(area_q) / (dist * norm * plane)
                            fscale = g_s / norm
                        # Accepted: the profile at the surface distance; hidden-surface
                        # fills: the planar weight (the mixture density at r).
                        ok = b_ok[j]
                        fb[_ROW_X + j] = dist if ok else r
                        fb[_ROW_S + j] = scale if ok else fscale
                        # On the centre's tangent plane G = 1.
                        fb[_ROW_G + j] = one if b_touch[j] else gq
                for j in range(nb):
                    if not (b_ok[j] or b_fill[j]):
                        continue
                    if mode != PLANAR:
                        x = fb[_ROW_X + j]
                        scale = fb[_ROW_S + j]
                        b_w[0, j] = _pdf(x, ks0, i0, ptab, psize) * scale
                        b_w[1, j] = _pdf(x, ks1, i1, ptab, psize) * scale
                        b_w[2, j] = _pdf(x, ks2, i2, ptab, psize) * scale
                    elif chrom:
                        # Planar weights: every accepted sample of the planar mode.
                        r = fb[_ROW_R + j]
                        p0 = _pdf(r, ks0, i0, ptab, psize)
                        p1 = _pdf(r, ks1, i1, ptab, psize)
                        p2 = _pdf(r, ks2, i2, ptab, psize)
                        norm = p0 + p1 + p2
                        scale = zero
                        if norm > zero:
                            scale = g_s / norm
                        b_w[0, j] = p0 * scale
                        b_w[1, j] = p1 * scale
                        b_w[2, j] = p2 * scale
                    else:
                        b_w[0, j] = np.float32(g0)
                        b_w[1, j] = np.float32(g1)
                        b_w[2, j] = np.float32(g2)
                # Stage 4: gather and sum, in sample order (a rejected sample reads the
                # centre: its difference is exactly 0, so it is skipped; a hidden-surface
                # fill adds its share of the centre's direct light).
                for j in range(nb):
                    if b_ok[j]:
                        q8 = np.uint64(b_q[j]) * _EIGHT
                        l0 = texel[q8]
                        l1 = texel[q8 + _ONE]
                        l2 = texel[q8 + _TWO]
                        if b_touch[j]:  # unlit
                            l0 = l1 = l2 = zero
                        if disk:
                            gq = fb[_ROW_G + j]
                            d0 = (l0 * gq - b0) * b_w[0, j]
                            d1 = (l1 * gq - b1) * b_w[1, j]
                            d2 = (l2 * gq - b2) * b_w[2, j]
                        else:
                            d0 = (l0 - b0) * b_w[0, j]
                            d1 = (l1 - b1) * b_w[1, j]
                            d2 = (l2 - b2) * b_w[2, j]
                    elif b_fill[j]:
                        d0 = f0 * b_w[0, j]
                        d1 = f1 * b_w[1, j]
                        d2 = f2 * b_w[2, j]
                    else:
                        continue
                    s0 += np.float64(d0)
                    s1 += np.float64(d1)
                    s2 += np.float64(d2)
                    if want_var:
                        y = d0 * np.float32(0.2126) + d1 * np.float32(0.7152)
                        y = y + d2 * np.float32(0.0722)
                        y64 = np.float64(y)
                        v0 += y64
                        v1 += y64 * y64
            mf = np.float64(m)
            if start:
                distant[g, 0] = g0 * np.float64(b0) + s0 / mf
                distant[g, 1] = g1 * np.float64(b1) + s1 / mf
                distant[g, 2] = g2 * np.float64(b2) + s2 / mf
            else:
                distant[g, 0] += s0 / mf
                distant[g, 1] += s1 / mf
                distant[g, 2] += s2 / mf
            if want_var:
                var[i, 0] = v0
                var[i, 1] = v1
        fallback[task] = nfb
    return var, fallback


#: Parallel over pixels; for large frames.
# error_model="numpy": a float division by zero gives inf/nan as in NumPy instead of
# raising, and numba emits no zero test before every division.
pixel_sums = numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")(_pixel_sums)
# The same code compiled without threads, for small work (a tile, a tiny frame): waking
# the thread pool costs more than it saves there, and far more on an oversubscribed
# machine (measured 4x slower per 32x32 frame under load). Same bits as the parallel one:
# every pixel is computed by one thread, in sample order. Its own name keeps numba's
# disk-cache entries of the two apart.
_serial = types.FunctionType(_pixel_sums.__code__, _pixel_sums.__globals__, "pixel_sums_serial")
_serial.__qualname__ = "pixel_sums_serial"
_serial.__doc__ = _pixel_sums.__doc__
pixel_sums_serial = numba.njit(cache=True, nogil=True, error_model="numpy")(_serial)
#: What a pixel costs the kernel besides its samples, in samples: 206 ns per pixel
#: against 25-37 ns per sample on one thread (docs/checks/kernel_per_pixel.py).
PIXEL_SAMPLES = 8
#: Below this much work (samples, plus PIXEL_SAMPLES per pixel) the serial kernel runs.
PARALLEL_MIN_SAMPLES = 1 << 16


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _texels(light, depth, area, normal, slots, surface):
    """(8N,) float32 texels of the kernel (see pixel_sums), built in parallel."""
    n = depth.shape[0]
    out = np.empty(8 * n, np.float32)
    for i in numba.prange(n):
        o = 8 * i
        out[o] = light[i, 0]
        out[o + 1] = light[i, 1]
        out[o + 2] = light[i, 2]
        out[o + 3] = depth[i]
        out[o + 5] = np.float32(slots[i])
        if surface:
            out[o + 4] = math.copysign(area[i], normal[i, 2])
            out[o + 6] = normal[i, 0]
            out[o + 7] = normal[i, 1]
        else:
            out[o + 4] = np.float32(0.0)
            out[o + 6] = np.float32(0.0)
            out[o + 7] = np.float32(0.0)
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _relight(light, out):
    """Writes the lighting (N, 3) float32 into texels ``out`` (8N,) of the same pixels."""
    for i in numba.prange(light.shape[0]):
        o = 8 * i
        out[o] = light[i, 0]
        out[o + 1] = light[i, 1]
        out[o + 2] = light[i, 2]


#: Names of the kernel's values kept in a Geometry's memos (core.geometry.Geometry.memo).
#: The texels are a function of the Geometry and its passes except for the lighting, so
#: a Geometry reused for the next frame of a still scene (core.geometry.GeometryCache)
#: rewrites only the lighting of its last call's texels, in place (at 1920×1080 a fresh
#: 66 MB texel array took 16.4 ms per frame, inside the frame). With them, the order
#: that visits all of the Geometry's pixels. Kept for reused Geometries only
#: (Geometry.reused): the texels are 32 bytes per pixel of the frame (118 MB at
#: 2560×1440), held between frames.
_TEXELS, _ORDER = "numba_texels", "numba_tile_order"

#: Largest integer float32 holds exactly: the texels' slot-and-object keys stay below it.
_EXACT = 1 << 24


def surface_keys(slots: np.ndarray, objects: np.ndarray | None) -> tuple[np.ndarray, np.float32]:
    """(H·W,) int32 texel keys ``slot + K·object`` and ``1/K`` (K a power of two > slots).

    Two pixels have one key when they show the same material of the same object;
    ``floor(key/K)`` gives the object back. Without an Object Index pass the key is
    the slot. Object indices too large for float32 keys are renumbered by rank (only
    their equality matters).
    """
    slots = slots.astype(np.int32, copy=False)
    if objects is None:
        return slots, np.float32(1.0)
    k = 1 << max(int(slots.max(initial=0)).bit_length(), 1)
    top = int(objects.max(initial=0))
    if (top + 1) * k > _EXACT:
        objects = np.unique(objects, return_inverse=True)[1].reshape(objects.shape)
    return (slots + k * objects.astype(np.int32)).astype(np.int32), np.float32(1.0 / k)


def tile_order(
    x: np.ndarray, y: np.ndarray, width: int, active: np.ndarray | None = None
) -> np.ndarray:
    """(P,) int64: visit pixels (in row-major order) tile by tile, TILE×TILE pixels each.

    ``x``, ``y`` are the pixels' image coordinates; with ``active`` ((P,) int64) the
    order is over the pixels ``active`` of them. A sample reads a texel up to the
    profile's radius away (tens of pixels). In row-major order the rows a pixel's
    samples reach span the whole image width; at 1920×1080 that band (~2 MB of
    texels) no longer stays in a core's L2 cache, and a sample cost 40.9 ns
    against 28.2 ns in 32×32 tiles (minimum of 8 interleaved calls, 2 threads;
    640×360 is unchanged).
    """
    x = np.asarray(x, np.int64)
    if active is None:
        active = np.arange(x.size, dtype=np.int64)
    return _tile_order(x, np.asarray(y, np.int64), active, -(-int(width) // TILE))


@numba.njit(cache=True, nogil=True, error_model="numpy")
def _tile_order(x, y, active, tiles_x):
    """Stable counting sort of the active pixels by tile: the order of NumPy's stable
    argsort of the tile keys (at 640×360, 0.4 ms against 0.7 ms for the argsort alone
    and 1.0–1.4 ms for the NumPy call with its gathers of the coordinates)."""
    n = active.shape[0]
    key = np.empty(n, np.int64)
    top = 0
    for i in range(n):
        g = active[i]
        k = (y[g] // TILE) * tiles_x + x[g] // TILE
        key[i] = k
        top = max(top, k)
    start = np.zeros(top + 2, np.int64)
    for i in range(n):
        start[key[i] + 1] += 1
    for k in range(top + 1):
        start[k + 1] += start[k]
    order = np.empty(n, np.int64)
    for i in range(n):
        k = key[i]
        order[start[k]] = i
        start[k] += 1
    return order


def kernel(samples: int, pixels: int = 0):
    """The compiled kernel for a call taking ``samples`` samples over ``pixels`` pixels.

    The serial build below PARALLEL_MIN_SAMPLES of work. The work counts each pixel
    as PIXEL_SAMPLES samples: at low counts a pixel's own cost dominates (a 320×180
    frame's 25416 SSS pixels at 1 spp took 5.7 ms serial, 3.4 ms on 2 threads, when
    only its 25416 samples were counted).
    """
    work = samples + PIXEL_SAMPLES * pixels
    return pixel_sums if work >= PARALLEL_MIN_SAMPLES else pixel_sums_serial


def run_kernel(
    geom,
    profile,
    counts,
    active,
    lighting,
    depth,
    frame,
    seed,
    depth_slope,
    variance,
    disk=False,
    hidden_light=1.0,
    contact=0.0,
    *,
    distant,
    start=False,
    samples=None,
):
    """The ``active`` SSS pixels of ``geom`` with the compiled kernel.

    Adds each active pixel's mean weighted difference to its row of ``distant``
    ((G, 3) float64, in place; see pixel_sums): in the kernel, where a pixel's
    sums are at hand, instead of dividing and scattering (P, 3) sums afterwards
    (1.2 ms at 640×360, 5.7 ms through NumPy's fancy indexing when some pixels
    take no samples, against ~60 ms for the samples). With ``start`` (every
    pixel of ``geom`` active) it sets each row to γ·B(p) plus that mean, so
    ``distant`` may come uninitialised (NumPy's γ·B took 4.8 ms at 1920×1080).
    ``samples`` is Σ counts[active] where the caller has it (it picks the build,
    :func:`kernel`; otherwise summed here: a gather of the counts, 0.9 ms at
    1920×1080). Returns the (P, 2) luminance sums (None without ``variance``) and
    the fall-back count.
    """
    if start and active.size != geom.size:
        raise ValueError("start needs every pixel of the Geometry active")
    f32 = np.float32
    h, w = geom.shape
    full_h, full_w = geom.image_shape
    oy, ox = geom.origin
    surf = geom.surface
    if surf is None:
        mode, unit, centre, area = PLANAR, (1.0, 1.0), (0.0, 0.0), np.zeros(1, f32)
    else:
        mode = ORTHO if surf.ortho else PERSPECTIVE
        unit, centre, area = surf.unit, surf.centre, surf.area
    light = np.ascontiguousarray(lighting.reshape(-1, 3), dtype=f32)
    # The texels of the Geometry's last call, relit (see _TEXELS); taken out of
    # its memos while this call uses them.
    held = geom.memos.pop(_TEXELS, None)
    if held is None:
        normal = surf.normal if surf is not None else np.zeros((1, 3), f32)
        keys, inv_k = surface_keys(geom.slots, geom.objects)
        texel = _texels(
            light,
            np.ascontiguousarray(depth.reshape(-1), dtype=f32),
            np.ascontiguousarray(area, dtype=f32),
            normal,
            keys,
            surf is not None,
        )
    else:
        texel, inv_k = held
        _relight(light, texel)
    if active.size == geom.size and geom.reused:  # every SSS pixel, as in most frames
        order = geom.memo(_ORDER, lambda: tile_order(geom.x, geom.y, full_w))
    else:
        order = tile_order(geom.x, geom.y, full_w, active)
    first = active[0]
    if samples is None:
        samples = int(counts[active].sum())
    var, fb = kernel(samples, active.size)(
        active,
        order,
        counts,
        geom.x,
        geom.y,
        geom.gamma,
        geom.gamma_sum,
        geom.lo,
        geom.hi,
        geom.mat.astype(np.int32, copy=False),
        geom.fw,
        geom.fh,
        geom.depth,
        geom.index,
        geom.chromatic,
        np.ones(geom.size, np.bool_) if geom.core is None else geom.core,
        np.uint64((np.int64(frame) ^ np.int64(seed)) & 0xFFFFFFFF),
        profile.d,
        texel,
        profile._rtab.reshape(-1),
        f32(profile.truncate),
        DIRECTIONS.reshape(-1),
        profile._pscale,
        profile._inv_d,
        profile._ptab.reshape(-1),
        profile._ntab.reshape(-1),
        f32(geom.fw[first] / geom.fh[first]),
        bool(disk),
        f32(hidden_light),
        geom.direct if geom.direct is not None else np.zeros((geom.size, 3), f32),
        geom.objects is not None,
        inv_k,
        f32(contact),
        w,
        h,
        f32(full_w),
        f32(full_h),
        ox,
        oy,
        f32(depth_slope),
        mode,
        f32(unit[0]),
        f32(unit[1]),
        f32(unit[0] * unit[1]),
        f32(centre[0]),
        f32(centre[1]),
        float(unit[0]),
        float(unit[1]),
        float(centre[0]),
        float(centre[1]),
        variance,
        distant,
        bool(start),
        numba.get_num_threads(),
    )
    if geom.reused:
        geom.memos[_TEXELS] = (texel, inv_k)
    return (var if variance else None), int(fb.sum())


def warm_up(pixels: int | None = None) -> None:
    """Run the kernels once on one pixel (compiles them, or loads them from the disk cache).

    With ``pixels`` (the frame's, H·W) only the build of the sampling kernel that
    frames of that size take (:func:`kernel`, counting every pixel as an SSS pixel
    with no samples). Of a cold warm-up's 44.1 s the parallel build took 24.7 s and the
    serial one 6.9 s (one run on the 2-core bench machine).
    """
    builds = (pixel_sums, pixel_sums_serial)
    if pixels is not None:
        builds = (kernel(0, pixels),)
    for fn in builds:
        _warm(fn)
    tile_order(np.zeros(1, np.int64), np.zeros(1, np.int64), 1)
    _relight(np.ones((1, 3), np.float32), np.ones(8, np.float32))
    depth = np.full((2, 2), 2.0, np.float32)
    for ortho in (False, True):  # the compiled depth-buffer surface (core.geometry.surface)
        surface_arrays(depth, 0, 0, 1e-3, 1e-3, 0.5, 0.5, ortho, 8.0)
    _region(np.ones(1), np.zeros(1, np.int64), np.ones((1, 3)), 8.0, 0.01, np.empty((4, 1, 3)))
    one, yes = np.ones(1), np.ones(1, np.bool_)
    _counts_pass(one, one, yes, one, 1e-4, 64.0, 6.0, 0.1, 8.0, 64.0, 0.01, np.empty(1, np.int32))
    _update_pass(one, one, one, yes, one, one, 0.75, 0.1875, 0.25, 1e-4, 64.0, np.empty((3, 1)))
    one32, at0, g3 = np.ones(1, np.float32), np.zeros(1, np.int64), np.ones((1, 3))
    _history_pass(
        one32, one32.copy(), one32.copy(), *(one32.copy() for _ in range(5)), yes.copy(),
        at0, yes, g3, g3, g3, one, np.ones(1, np.int32), 2, 1.0, 0.75, 0.1875, 0.25, 1e-4,
        64.0, 1e150, 1e-4, 1e-6, np.empty(1), np.empty(1), yes.copy(),
    )  # fmt: skip
    rows, at = np.ones((1, 3), np.float32), np.zeros(1, np.int64)
    _composite_pass(rows, rows, rows, at, np.ones((1, 3)), one, True, 1.0, rows.copy(), rows.copy())
    _float_image_pass(np.ones((1, 3)), at, 0.0, 1.0, rows.copy())
    plane = np.ones((1, 1), np.float32)
    for motion in (None, np.zeros((1, 1, 2), np.float32)):
        reproject_map(motion, plane, at.reshape(1, 1), plane, at.reshape(1, 1), 0.1)
    for dtype in (np.float16, np.float32, np.bool_):  # history buffers and masks
        fetch(np.zeros(1, dtype), at, yes)
    read_column(one32, at, 1.0, g3, 0)
    write_column(g3, 0, at, 1.0, one32.copy())
    # The separable passes (the separable method, the temporal proxy) and the temporal
    # reuse's neighbourhood and per-pixel steps, in the argument types
    # core.separable.apply and core.mc.temporal pass.
    f32 = np.float32
    pix = (at, at, at, np.ones(1, np.int32), one32, at, at, one32)
    tables = (np.ones(1, f32), np.ones(1, np.int32), np.zeros((2, 3)), np.zeros((2, 3)))
    for build in (separable_pass_slope, separable_pass_exp):
        build(
            np.ones((1, 3), f32), 0, 1, *pix, yes, *tables, np.zeros(3, np.bool_),
            np.ones((2, 3, 3), f32), 1, 1, 0, 1, -1, 2.0, np.ones(2, f32), True,
            np.zeros((1, 3), f32),
        )  # fmt: skip
    table = neighbour_table(at, np.ones(1, np.int32), at, 1, 1)
    neighbourhood_pass(g3, yes, table, g3.copy(), g3.copy())
    rgb = [np.ones((1, 3)) for _ in range(8)]
    reuse_start(*rgb[:2], one, rgb[2], one, yes, *rgb[3:5], np.ones(3), MULTIPLICATIVE, 0.2, 0.3,
                *rgb[5:7], one.copy())  # fmt: skip
    reuse_finish(*rgb[:4], one, yes, *rgb[4:6], 2.0, one, 1e-12, MULTIPLICATIVE, True, 2.0, 0.1,
                 *rgb[6:8], one.copy())  # fmt: skip


def _warm(fn) -> None:
    f32 = np.float32
    one = np.ones(1)
    g3 = np.full((1, 3), 0.5)
    fn(
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        np.ones(1, np.int64),
        np.zeros(1, np.int64),
        np.zeros(1, np.int64),
        g3,
        np.full(1, 1.5),
        np.full((1, 3), 0.1),
        g3,
        np.ones(1, np.int32),
        one,
        one,
        one,
        np.zeros(1, np.int64),
        np.zeros(1, np.bool_),
        np.ones(1, np.bool_),
        np.uint64(0),
        np.ones((2, 3)),
        np.ones(8, f32),
        np.ones(10, f32),
        f32(16.0),
        DIRECTIONS.reshape(-1),
        np.ones((3, 2), f32),
        np.ones((3, 2), f32),
        np.ones(10, f32),
        np.ones(120, f32),
        f32(1.0),
        False,
        f32(1.0),
        np.zeros((1, 3), f32),
        False,
        f32(1.0),
        f32(0.0),
        1,
        1,
        f32(1.0),
        f32(1.0),
        0,
        0,
        f32(2.0),
        PLANAR,
        f32(1.0),
        f32(1.0),
        f32(1.0),
        f32(0.0),
        f32(0.0),
        1.0,
        1.0,
        0.0,
        0.0,
        True,
        np.zeros((1, 3)),
        False,
        1,
    )


# -- the depth-buffer surface (core.geometry.surface) ---------------------------------
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
def surface_arrays(depth, ox, oy, wu, hu, cx, cy, ortho, max_tilt):
    """Area and normal of every pixel of the depth buffer: core.geometry.surface's
    arithmetic in one pass (float64, the same operations in the same order, so the
    results are bit-identical; tests/core/test_backend.py checks it).

    Parameters
    ----------
    depth : (H, W) float32, planar depth (scene units, inf = background)
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
            a0, a1, a2 = _step(left, c, right, j > 0, j < w - 1, z)
            b0, b1, b2 = _step(up, c, down, i > 0, i < h - 1, z)
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


# -- the Burley distant region (core.profiles.burley.BurleyProfile.region) ------------
def burley_region(profile, r0: np.ndarray, mat: np.ndarray):
    """:meth:`core.profiles.burley.BurleyProfile.region` in one parallel pass.

    The same float64 operations in the same order (``tail`` at ``min(r0, d·truncate)``,
    the mass above the truncation tail, γ and its weight scale). The exponentials are
    libm's ``exp``, which NumPy also calls for float64 on CPUs without AVX-512; where
    NumPy has its own AVX-512 ``exp``, the two may differ in the last bit
    (tests/core/test_backend.py checks bits or 1 ulp accordingly). For 407 k
    pixels (an SSS-heavy 1280×720 frame) it took 14 ms on 2 threads against 52 ms
    for NumPy's passes over (P, 3) arrays (one-off ``timeit``).

    Parameters
    ----------
    profile : BurleyProfile
    r0 : (P,) float64, inner radius per pixel (scene units)
    mat : (P,) int, compact slot per pixel

    Returns
    -------
    Region with (P, 3) float64 arrays
    """
    from ..profiles.base import Region

    n = r0.shape[0]
    out = np.empty((4, n, 3))
    _region(
        np.ascontiguousarray(r0, dtype=np.float64),
        np.ascontiguousarray(mat, dtype=np.int64),
        np.ascontiguousarray(profile.d, dtype=np.float64),
        float(profile.truncate),
        float(profile._tail_max),
        out,
    )
    return Region(gamma=out[0], weight_scale=out[1], lo=out[2], hi=out[3])


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


# -- the SPVG counts and history update (core.mc.adaptive) ----------------------------
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


def spvg_counts(var_prev, mbar_prev, valid, gamma_max, params) -> np.ndarray:
    """:func:`core.mc.adaptive.sample_counts` in one parallel pass (the same float64
    operations in the same order, so the same counts; tests/core/test_adaptive.py
    checks it). int32, in the inputs' broadcast shape."""
    p = params
    shape = np.broadcast_shapes(*(np.shape(x) for x in (var_prev, mbar_prev, valid, gamma_max)))
    out = np.empty(shape, np.int32)
    _counts_pass(
        _flat(var_prev, shape, np.float64),
        _flat(mbar_prev, shape, np.float64),
        _flat(valid, shape, np.bool_),
        _flat(gamma_max, shape, np.float64),
        float(p.target_variance),
        float(p.initial_count),
        2.0 / p.eta - 2.0,
        float(p.kappa),
        float(p.beta_min),
        float(p.beta_max),
        float(p.eps_u),
        out.reshape(-1),
    )
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _counts_pass(
    var_prev, mbar_prev, valid, gamma_max, s0, n_init, gain, kappa, lo, hi, eps_u, out
):
    for i in numba.prange(out.shape[0]):
        var = var_prev[i] if valid[i] else s0
        mbar = mbar_prev[i] if valid[i] else n_init
        var = _finite(var, s0, _F64_MAX, -_F64_MAX)
        mbar = _finite(mbar, n_init, hi, -_F64_MAX)
        ratio = var / s0
        delta = (ratio - 1.0) * mbar * gain
        m_hat = _finite(kappa * delta + ratio * mbar, hi, hi, lo)
        m = min(max(np.rint(m_hat), lo), hi)
        out[i] = 0 if gamma_max[i] < eps_u else np.int32(m)


def spvg_update(mu, var, mbar, valid, tracked, counts, params):
    """:func:`core.mc.adaptive.update_history` in one parallel pass (the same float64
    operations in the same order; tests/core/test_adaptive.py checks the bits).
    Returns mu, var, mbar ((P,) float64) and the new valid flags ((P,) bool)."""
    p = params
    shape = np.broadcast_shapes(*(np.shape(x) for x in (mu, var, mbar, valid, tracked, counts)))
    out = np.empty((3, *shape))
    _update_pass(
        _flat(mu, shape, np.float64),
        _flat(var, shape, np.float64),
        _flat(mbar, shape, np.float64),
        _flat(valid, shape, np.bool_),
        _flat(tracked, shape, np.float64),
        _flat(counts, shape, np.float64),
        *_spvg_constants(p),
        out.reshape(3, -1),
    )
    return out[0], out[1], out[2], np.asarray(counts) > 0


def _spvg_constants(params) -> tuple[float, float, float, float, float]:
    """(keep, spread, η, σ0², n_init) of Eq. 5–7 as :func:`_spvg_step` takes them:
    keep = 1 − η, spread = η(1 − η)."""
    eta = params.eta
    return (
        1.0 - eta,
        eta * (1.0 - eta),
        eta,
        float(params.target_variance),
        float(params.initial_count),
    )


@numba.njit(inline="always", error_model="numpy")
def _spvg_step(s, ok, mu, var, mbar, count, keep, spread, eta, s0, n_init):
    """One pixel's Eq. 5–7 with the no-history rule (core.mc.adaptive.update_history):
    μ, σ², m̄ at t from those at t−1, the tracked value s and the count (float64)."""
    big = _F64_MAX
    mu_prev = mu if ok else s
    var_prev = var if ok else s0
    mbar_prev = mbar if ok else n_init
    dev = s - mu_prev
    var_new = keep * var_prev + spread * dev * dev
    mu_new = keep * mu_prev + eta * s if ok else s
    mbar_new = keep * mbar_prev + eta * count
    var_new = var_new if ok else s0
    var_new = _finite(var_new, s0, big, -big)
    return (
        _finite(mu_new, 0.0, big, -big),
        var_new if var_new > 0.0 else 0.0,
        _finite(mbar_new, n_init, big, 0.0),
    )


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _update_pass(mu, var, mbar, valid, tracked, counts, keep, spread, eta, s0, n_init, out):
    for i in numba.prange(out.shape[1]):
        out[0, i], out[1, i], out[2, i] = _spvg_step(
            tracked[i], valid[i], mu[i], var[i], mbar[i], counts[i], keep, spread, eta, s0, n_init
        )


#: Control variates of the compiled history step (:func:`history_step`): none (track
#: f̄), constant (Res = f̄ − G) and online (Res = f̄ − α·G, α from the covariance history).
CV_MODES = {"none": 0, "constant": 1, "online": 2}


def history_step(
    buffers, index, valid, distant, gamma, b, weight, counts, cv, params, cv_history=None
):
    """The history step of ``MonteCarloProcessor._update`` in one parallel pass over
    the SSS pixels, on a float32 history (stored unscaled): the tracked luminance, the
    online control variate's α and EMCM step (Alg. 2, Eq. 33), Eq. 5–7 and the stores
    into the history's buffers at ``index``, in place. The same float64 operations in
    the same order as the NumPy step, and the same float32 stores
    (tests/core/test_backend.py).

    Parameters
    ----------
    buffers : (mu, var, mbar), the History's (H, W) float32 buffers (written in place)
    index : (P,) int64, flat pixel index; valid : (P,) bool, the history was valid
    distant, gamma, b : (P, 3) float64, the distant estimate, γ and B
    weight : (P,) float64, Subsurface Weight; counts : (P,) int, m_t
    cv : {"none", "constant", "online"}, the method's control variate
    params : SSSParams (exposure, η, σ0², initial count; ε_α, η_cv)
    cv_history : with ``cv="online"``: ((sxx, sxy, syy, zf, zg), cv_valid), the
        History's (H, W) float32 J buffers (written in place) and its (H, W) bool
        mask of valid J (read)

    Returns
    -------
    var : (P,) float64, σ² at t where m_t > 0, else 0
    new_valid : (H, W) bool, the pixels with m_t > 0
    alpha : (P,) float64, α where m_t > 0 (0 without a control variate, 1 constant),
        else 0
    """
    from .processor import TRACK_LIMIT

    mu, var, mbar = buffers
    h, w = mu.shape
    n = index.shape[0]
    out = np.empty(n)
    alpha = np.empty(n)
    new_valid = np.zeros(h * w, np.bool_)
    if cv == "online":
        j_buffers, cv_valid = cv_history
        j_flat = tuple(x.reshape(-1) for x in j_buffers)
        cv_valid = np.ascontiguousarray(cv_valid).reshape(-1)
    else:  # not read
        j_flat = (np.empty(0, np.float32),) * 5
        cv_valid = np.empty(0, np.bool_)
    _history_pass(
        mu.reshape(-1),
        var.reshape(-1),
        mbar.reshape(-1),
        *j_flat,
        cv_valid,
        index,
        valid,
        np.ascontiguousarray(distant, dtype=np.float64),
        np.ascontiguousarray(gamma, dtype=np.float64),
        np.ascontiguousarray(b, dtype=np.float64),
        np.ascontiguousarray(weight, dtype=np.float64),
        np.ascontiguousarray(counts),
        CV_MODES[cv],
        float(params.exposure),
        *_spvg_constants(params),
        float(TRACK_LIMIT),
        float(params.eps_alpha),
        float(params.eta_cv),
        out,
        alpha,
        new_valid,
    )
    return out, new_valid.reshape(h, w), alpha


_F32_MAX = float(np.finfo(np.float32).max)
_R0, _R1, _R2 = (float(v) for v in REC709)


@numba.njit(inline="always", error_model="numpy")
def _bounded(x, limit):
    """core.mc.processor._bounded of one float64: clipped to ±limit, NaN → 0."""
    if np.isnan(x):
        return 0.0
    return min(max(x, -limit), limit)


@numba.njit(inline="always", error_model="numpy")
def _stored(x):
    """History.write of one float64 into float32 storage: ±inf → ±max, NaN → 0."""
    if np.isnan(x):
        return np.float32(0.0)
    return np.float32(min(max(x, -_F32_MAX), _F32_MAX))


@numba.njit(inline="always", error_model="numpy")
def _cv_alpha(s_xy, s_yy, f, g, eps_alpha):
    """core.mc.control_variates.cv_coefficient of one pixel (float64)."""
    big = _F64_MAX
    num = s_xy + eps_alpha
    den = s_yy + eps_alpha
    alpha = num / den if den > 0 else 1.0
    upper = 1.0
    if g > 0:
        q = (f + g) / g
        upper = q if (q >= 0.0 or np.isnan(q)) else 0.0  # np.maximum(q, 0.0)
    upper = _finite(upper, 1.0, big, -big)
    alpha = _finite(alpha, 1.0, big, 0.0)
    alpha = alpha if alpha > 0.0 else 0.0  # np.clip(alpha, 0.0, upper)
    return alpha if alpha < upper else upper


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _history_pass(
    mu,
    var,
    mbar,
    sxx,
    sxy,
    syy,
    zf,
    zg,
    cv_valid,
    index,
    valid,
    distant,
    gamma,
    b,
    weight,
    counts,
    cv_mode,
    exposure,
    keep,
    spread,
    eta,
    s0,
    n_init,
    limit,
    eps_alpha,
    eta_cv,
    out,
    alpha_out,
    new_valid,
):
    keep_cv = 1.0 - eta_cv
    spread_cv = eta_cv * (1.0 - eta_cv)
    for i in numba.prange(index.shape[0]):
        # f̄ = (Î·exposure)·Rec.709 and G = ((γ·B)·exposure)·Rec.709, times the weight.
        f = (
            (distant[i, 0] * exposure) * _R0
            + (distant[i, 1] * exposure) * _R1
            + (distant[i, 2] * exposure) * _R2
        )
        g = (
            ((gamma[i, 0] * b[i, 0]) * exposure) * _R0
            + ((gamma[i, 1] * b[i, 1]) * exposure) * _R1
            + ((gamma[i, 2] * b[i, 2]) * exposure) * _R2
        )
        f = _bounded(f * weight[i], limit)
        g = _bounded(g * weight[i], limit)
        j = index[i]
        m = counts[i]
        if cv_mode == 2:
            # α from Σ at t − 1 (Alg. 2), then one EMCM step (Eq. 33) of Z = (f̄, G);
            # Σ starts at 0 and ζ at Z where J is not valid (core.mc.processor._online_cv).
            jv = cv_valid[j] and valid[i]
            c_xx = np.float64(sxx[j]) if jv else 0.0
            c_xy = np.float64(sxy[j]) if jv else 0.0
            c_yy = np.float64(syy[j]) if jv else 0.0
            z_f = np.float64(zf[j]) if jv else f
            z_g = np.float64(zg[j]) if jv else g
            a = _cv_alpha(c_xy, c_yy, f, g, eps_alpha)
            d_f = f - z_f
            d_g = g - z_g
            sxx[j] = _stored(keep_cv * c_xx + spread_cv * d_f * d_f if jv else 0.0)
            sxy[j] = _stored(keep_cv * c_xy + spread_cv * d_f * d_g if jv else 0.0)
            syy[j] = _stored(keep_cv * c_yy + spread_cv * d_g * d_g if jv else 0.0)
            zf[j] = _stored(keep_cv * z_f + eta_cv * f if jv else f)
            zg[j] = _stored(keep_cv * z_g + eta_cv * g if jv else g)
            s = f - a * g
        elif cv_mode == 1:
            a = 1.0
            s = f - 1.0 * g
        else:
            a = 0.0
            s = f
        mu_t, var_t, mbar_t = _spvg_step(
            s,
            valid[i],
            np.float64(mu[j]),
            np.float64(var[j]),
            np.float64(mbar[j]),
            np.float64(m),
            keep,
            spread,
            eta,
            s0,
            n_init,
        )
        mu[j] = _stored(mu_t)
        var[j] = _stored(var_t)
        mbar[j] = _stored(mbar_t)
        out[i] = var_t if m > 0 else 0.0
        alpha_out[i] = a if m > 0 else 0.0
        new_valid[j] = m > 0


# -- the composite and the per-pixel maps (core.result) -------------------------------
def composite(frame, index: np.ndarray, shaded: np.ndarray, weight) -> tuple:
    """:func:`core.result.composite` in two parallel passes (float64 ``shaded``).

    The same float64 operations as NumPy's, so the same float32 images
    (tests/core/test_backend.py checks it). NumPy's version is a dozen passes
    over the image and fancy-indexed rows: 63 ms per 1920×1080 frame against
    9 ms here (one-off ``timeit``).
    """
    h, w = frame.lighting.shape[:2]
    out = np.empty((h, w, 3), np.float32)
    sss = np.empty((h, w, 3), np.float32)
    use_weight = weight is not None and not np.all(weight == 1.0)
    _composite_pass(
        _rows(frame.combined),
        _rows(frame.lighting),
        _rows(frame.albedo),
        np.asarray(index, np.int64),
        np.ascontiguousarray(shaded, np.float64),
        np.ascontiguousarray(weight if use_weight else np.ones(0), np.float64),
        use_weight,
        float(np.finfo(np.float32).max),
        out.reshape(-1, 3),
        sss.reshape(-1, 3),
    )
    return out, sss


def _rows(image: np.ndarray) -> np.ndarray:
    """An (H, W, 3) float32 image as contiguous (H·W, 3) rows (no copy when it is)."""
    return np.ascontiguousarray(image, np.float32).reshape(-1, 3)


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _composite_pass(combined, lighting, albedo, index, shaded, weight, use_weight, big, out, sss):
    zero = np.float32(0.0)
    for i in numba.prange(combined.shape[0]):
        for c in range(3):
            x = combined[i, c]
            out[i, c] = x if (x >= zero or np.isnan(x)) else zero  # np.maximum(x, 0)
            sss[i, c] = lighting[i, c]
    for k in numba.prange(index.shape[0]):
        i = index[k]
        for c in range(3):
            # np.clip(np.nan_to_num(s, nan=0, posinf=big), 0, big)
            s = shaded[k, c]
            s = 0.0 if np.isnan(s) else min(max(s, 0.0), big)
            change = s - np.float64(lighting[i, c])
            if use_weight:
                change *= weight[k]
            v = np.float64(combined[i, c]) + np.float64(albedo[i, c]) * change
            out[i, c] = np.float32(min(max(v, 0.0), big))
            sss[i, c] = np.float32(s)


def float_image(values: np.ndarray, index: np.ndarray, size: int, fill: float) -> np.ndarray:
    """:meth:`core.geometry.Geometry.to_image` of float values into float32, in one
    parallel pass: (size, C) or (size,), ``fill`` off ``index``, values clipped to
    ±float32 max (NaN kept), as NumPy's clip and cast give them. For the (P, 3) γ
    of a 1920×1080 frame 15 ms in NumPy (fancy-indexed rows), 6 ms here (one-off)."""
    values = np.asarray(values)
    channels = int(np.prod(values.shape[1:]))  # 1 for (P,); also when P = 0
    rows = np.ascontiguousarray(values, np.float64).reshape(values.shape[0], channels)
    out = np.empty((size, rows.shape[1]), np.float32)
    _float_image_pass(
        rows, np.asarray(index, np.int64), float(fill), float(np.finfo(np.float32).max), out
    )
    return out.reshape(size, *values.shape[1:])


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _float_image_pass(rows, index, fill, big, out):
    f = np.float32(fill)
    # The fill over the flat array: written as a loop over (pixel, channel) inside
    # prange it compiled in 6.3 s against 2.0 s (the same run time, 3.3 ms per
    # 1920×1080 (P, 3) map).
    n = out.shape[0] * out.shape[1]
    flat = out.reshape(n)
    for i in numba.prange(n):
        flat[i] = f
    channels = out.shape[1]
    for k in numba.prange(index.shape[0]):
        i = index[k]
        for c in range(channels):
            x = rows[k, c]
            out[i, c] = np.float32(x if np.isnan(x) else min(max(x, -big), big))


# -- the history's reprojection (core.mc.history) -------------------------------------
_BITS = {1: np.uint8, 2: np.uint16, 4: np.uint32, 8: np.uint64}


def reproject_map(motion, depth, material, prev_depth, prev_material, tolerance):
    """Source pixel, on-screen flag and surface match of every pixel, one parallel pass.

    :meth:`core.mc.history.History.reproject`'s arithmetic (float64 positions,
    ``rint`` of the clipped position, the relative depth test) per pixel.

    Parameters
    ----------
    motion : (H, W, 2) float32 or None (static)
    depth, prev_depth : (H, W) float32; material, prev_material : (H, W) int
    tolerance : float, relative depth change still accepted

    Returns
    -------
    src : (H·W,) int64, flat source pixel (0 off screen)
    inside, same : (H·W,) bool, on screen; and the same slot at a close depth
    """
    h, w = depth.shape
    n = h * w
    src = np.empty(n, np.int64)
    inside = np.empty(n, np.bool_)
    same = np.empty(n, np.bool_)
    flow = np.zeros((0, 2), np.float32) if motion is None else motion.reshape(n, 2)
    _reproject_pass(
        np.ascontiguousarray(flow),
        motion is not None,
        h,
        w,
        np.ascontiguousarray(depth).reshape(-1),
        np.ascontiguousarray(material, np.int64).reshape(-1),
        np.ascontiguousarray(prev_depth).reshape(-1),
        np.ascontiguousarray(prev_material, np.int64).reshape(-1),
        float(tolerance),
        src,
        inside,
        same,
    )
    return src, inside, same


@numba.njit(cache=True, inline="always", error_model="numpy")
def _source(i, flow, has_motion, w, h):
    """(flat source pixel, on screen) of pixel i moved by its motion vector."""
    if not has_motion:
        return np.int64(i), True
    y = i // w
    fx = np.float64(i - y * w) + np.float64(flow[i, 0])
    fy = np.float64(y) + np.float64(flow[i, 1])
    ok = np.isfinite(fx) and np.isfinite(fy)
    if not ok:
        fx = -1.0
        fy = -1.0
    px = np.int64(np.rint(min(max(fx, -1.0), np.float64(w))))
    py = np.int64(np.rint(min(max(fy, -1.0), np.float64(h))))
    ok = ok and px >= 0 and px < w and py >= 0 and py < h
    return (py * w + px if ok else np.int64(0)), ok


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _reproject_pass(
    flow, has_motion, h, w, depth, material, prev_depth, prev_material, tol, src, inside, same
):
    for i in numba.prange(depth.shape[0]):
        s, ok = _source(i, flow, has_motion, w, h)
        prev = np.float64(prev_depth[s])
        cur = np.float64(depth[i])
        src[i] = s
        inside[i] = ok
        same[i] = ok and prev_material[s] == material[i] and abs(prev - cur) <= tol * cur


def fetch(values: np.ndarray, src: np.ndarray, keep: np.ndarray) -> np.ndarray:
    """``values.flat[src]`` where ``keep``, zero elsewhere, in ``values``' shape and
    dtype (bits copied: float16, float32 or bool), one parallel pass."""
    values = np.ascontiguousarray(values)
    bits = _BITS[values.dtype.itemsize]
    out = np.empty(values.shape, values.dtype)
    _fetch_pass(values.reshape(-1).view(bits), src, keep, out.reshape(-1).view(bits))
    return out


@numba.njit(parallel=True, cache=True, nogil=True)
def _fetch_pass(values, src, keep, out):
    for i in numba.prange(out.shape[0]):
        out[i] = values[src[i]] if keep[i] else 0


# -- the history's reads and writes (core.mc.history.History.read_columns) -------------
@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def read_column(buf, index, scale, out, col):
    """``out[:, col] = buf[index] / scale`` in float64 (History.read of a float32 buffer:
    the same values).

    Parameters
    ----------
    buf : (H·W,) float32, a history buffer (stored units); index : (P,) int64 flat pixels
    scale : float, stored value = true value × scale; out : (P, k) float64, written
    col : int, the column of ``out`` to write
    """
    for k in numba.prange(index.shape[0]):
        v = np.float64(buf[index[k]])
        if scale != 1.0:
            v = v / scale
        out[k, col] = v


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def write_column(values, col, index, scale, buf):
    """``buf[index] = values[:, col]`` as History.write stores a float32 buffer: times
    ``scale``, then :func:`_stored` (clipped to ±float32 max, ±inf too, NaN stored as 0,
    rounded to float32).

    Parameters
    ----------
    values : (P, k) float64, true units; col : int; index : (P,) int64 flat pixels
    scale : float; buf : (H·W,) float32, written
    """
    for k in numba.prange(index.shape[0]):
        v = values[k, col]
        if scale != 1.0:
            v = v * scale
        buf[index[k]] = _stored(v)


# -- the separable passes (core.separable.apply) ---------------------------------------
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


# -- the temporal reuse's neighbourhood (core.mc.temporal) -----------------------------
@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def neighbour_table(index, mat, where, w, h):
    """Each pixel's 3×3 neighbours of the same slot, for :func:`neighbourhood_pass`.

    Parameters
    ----------
    index : (P,) int64 flat pixel; mat : (P,) int32 slot; where : (H·W,) int64, the
        Geometry pixel at each frame pixel (−1: none); w, h : int, the frame's size

    Returns
    -------
    (P, 9) int32, the Geometry pixel of each neighbour, row by row from (−1, −1) to
    (+1, +1) (the pixel itself fifth); −1 off the frame, on no SSS pixel or on
    another slot
    """
    n_pix = index.shape[0]
    out = np.empty((n_pix, 9), np.int32)
    for k in numba.prange(n_pix):
        y = index[k] // w
        x = index[k] - y * w
        e = 0
        for dy in range(-1, 2):
            for dx in range(-1, 2):
                xx = x + dx
                yy = y + dy
                j = -1
                if xx >= 0 and xx < w and yy >= 0 and yy < h:
                    j = where[yy * w + xx]
                    if j >= 0 and mat[j] != mat[k]:
                        j = -1
                out[k, e] = j
                e += 1
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def neighbourhood_pass(values, active, table, mean, std):
    """Mean and standard deviation over each pixel's 3×3 neighbours of the same slot
    holding a value (:func:`core.mc.temporal.neighbourhood`, its float64 operations in
    its order: a neighbour without a value adds 0).

    Parameters
    ----------
    values : (P, 3) float64; active : (P,) bool
    table : (P, 9) int32, :func:`neighbour_table` (a still scene's Geometry keeps it)
    mean, std : (P, 3) float64, written
    """
    n_pix = table.shape[0]
    for k in numba.prange(n_pix):
        t0 = t1 = t2 = 0.0
        q0 = q1 = q2 = 0.0
        count = 0.0
        for e in range(9):
            j = table[k, e]
            v0 = v1 = v2 = 0.0
            ok = False
            if j >= 0:
                uj = np.uint64(j)
                if active[uj] and not np.isnan(values[uj, 0]):
                    ok = True
                    v0 = values[uj, 0]
                    v1 = values[uj, 1]
                    v2 = values[uj, 2]
            t0 += v0
            t1 += v1
            t2 += v2
            q0 += v0 * v0
            q1 += v1 * v1
            q2 += v2 * v2
            count += 1.0 if ok else 0.0
        nn = max(count, 1.0)
        m0 = t0 / nn
        m1 = t1 / nn
        m2 = t2 / nn
        mean[k, 0] = m0
        mean[k, 1] = m1
        mean[k, 2] = m2
        std[k, 0] = np.sqrt(max(q0 / nn - m0 * m0, 0.0))
        std[k, 1] = np.sqrt(max(q1 / nn - m1 * m1, 0.0))
        std[k, 2] = np.sqrt(max(q2 / nn - m2 * m2, 0.0))


# -- the temporal reuse's per-pixel arithmetic (core.mc.temporal.reuse) ----------------
#: Temporal modes of the reuse kernels.
PLAIN, SUBTRACTIVE, MULTIPLICATIVE = 0, 1, 2


@numba.njit(inline="always", error_model="numpy")
def _pos(x):
    """np.maximum(x, 0.0) of one value (NaN stays NaN)."""
    return x if (np.isnan(x) or x > 0.0) else 0.0


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def reuse_start(
    distant, control, alpha, proxy, n_prev, active, ctl_prev, prox_prev, eps, mode, switch,
    tolerance, shift, value, n_out,
):  # fmt: skip
    """The reuse's first per-pixel step (:func:`core.mc.temporal.reuse` up to the
    neighbourhood clamp): the shift and the value accumulated, and the frame count cut
    by the rectification δ, in float64 with reuse's operations (``log`` and ``exp`` are
    libm's: within an ulp of NumPy's).

    Parameters
    ----------
    distant, control : (P, 3) float64; alpha : (P,) float64; proxy : (P, 3) float64
        (read in the multiplicative mode only); n_prev : (P,) float64, the history's frame
        count; active : (P,) bool; ctl_prev, prox_prev : (P, 3) float64, the history's
        control and proxy (read in the guided modes); eps : (3,) float64
    mode : PLAIN, SUBTRACTIVE or MULTIPLICATIVE; switch : float, SWITCH_WEIGHT;
        tolerance : float, τ
    shift, value : (P, 3) float64, written (shift: 0 in the plain mode)
    n_out : (P,) float64, written: the frame count after the cut
    """
    for k in numba.prange(distant.shape[0]):
        worst = -np.inf
        nan = False
        for c in range(3):
            e = eps[c]
            if mode == MULTIPLICATIVE:
                sh = _pos(proxy[k, c]) + e
                value[k, c] = distant[k, c] / sh
            elif mode == SUBTRACTIVE:
                sh = alpha[k] * control[k, c]
                value[k, c] = distant[k, c] - sh
            else:
                sh = 0.0
                value[k, c] = distant[k, c]
            shift[k, c] = sh
            if mode != PLAIN:
                d_ctl = np.log(control[k, c] + e) - np.log(_pos(ctl_prev[k, c]) + e)
                if mode == MULTIPLICATIVE:
                    d_prox = np.log(sh) - np.log(_pos(prox_prev[k, c]) + e)
                    delta = abs(d_prox - d_ctl) + switch * abs(d_ctl)
                else:
                    delta = abs(d_ctl)
                if np.isnan(delta):
                    nan = True
                elif delta > worst:
                    worst = delta
        n = n_prev[k] if active[k] else 0.0
        if mode != PLAIN:
            # NumPy's max over channels propagates NaN; nan_to_num makes it +inf.
            d = np.inf if nan else worst
            r = d / tolerance
            n = n * np.exp(-(r * r))
        n_out[k] = n


@numba.njit(inline="always", error_model="numpy")
def _clip(x, lo, hi):
    """np.clip of one value: NaN where any of the three is NaN."""
    if np.isnan(x) or np.isnan(lo) or np.isnan(hi):
        return np.nan
    return min(max(x, lo), hi)


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def reuse_finish(
    distant, prev, value, shift, n_in, active, mean, std, clamp, sigma, floor, mode,
    use_noise, noise_sigmas, min_weight, acc, out, n_new,
):  # fmt: skip
    """The reuse's last per-pixel step (:func:`core.mc.temporal.reuse` from the clamp on):
    the clamped history, the noise test's cut, λ, the accumulation and the output.

    Parameters
    ----------
    distant, prev, value, shift : (P, 3) float64 (prev: the history's accumulation)
    n_in : (P,) float64, the frame count after :func:`reuse_start`; active : (P,) bool
    mean, std : (P, 3) float64, the neighbourhood of ``value`` (with ``clamp`` finite)
    clamp : float, k (inf: no clamp); sigma : (P,) float64, the pooled noise (with
        ``use_noise``); floor : float, its lower bound 1e-12·(scale·Y)
    mode : PLAIN, SUBTRACTIVE or MULTIPLICATIVE; use_noise : bool (guided modes with a
        noise estimate); noise_sigmas : float; min_weight : float, λ_min
    acc, out : (P, 3) float64, written; n_new : (P,) float64, written
    """
    finite_clamp = np.isfinite(clamp)
    for k in numba.prange(distant.shape[0]):
        p0 = prev[k, 0]
        p1 = prev[k, 1]
        p2 = prev[k, 2]
        if finite_clamp:
            p0 = _clip(p0, mean[k, 0] - clamp * std[k, 0], mean[k, 0] + clamp * std[k, 0])
            p1 = _clip(p1, mean[k, 1] - clamp * std[k, 1], mean[k, 1] + clamp * std[k, 1])
            p2 = _clip(p2, mean[k, 2] - clamp * std[k, 2], mean[k, 2] + clamp * std[k, 2])
        n = n_in[k]
        if use_noise:
            if mode == MULTIPLICATIVE:
                g0 = p0 * shift[k, 0] - distant[k, 0]
                g1 = p1 * shift[k, 1] - distant[k, 1]
                g2 = p2 * shift[k, 2] - distant[k, 2]
            else:
                g0 = p0 + shift[k, 0] - distant[k, 0]
                g1 = p1 + shift[k, 1] - distant[k, 1]
                g2 = p2 + shift[k, 2] - distant[k, 2]
            gap = abs(g0 * _R0 + g1 * _R1 + g2 * _R2)
            z = gap / max(sigma[k], floor)
            if np.isnan(z):
                z = np.inf
            m = max(z - noise_sigmas, 0.0)
            n = n * np.exp(-0.5 * (m * m))
        r = 1.0 / (n + 1.0)
        lam = r if (np.isnan(r) or r > min_weight) else min_weight
        on = active[k]
        ps = (p0, p1, p2)
        for c in range(3):
            a = (1.0 - lam) * ps[c] + lam * value[k, c] if on else value[k, c]
            acc[k, c] = a
            if not on:
                o = distant[k, c]
            elif mode == MULTIPLICATIVE:
                o = a * shift[k, c]
            elif mode == SUBTRACTIVE:
                o = a + shift[k, c]
            else:
                o = a
            out[k, c] = o
        n_new[k] = n + 1.0 if on else 0.0

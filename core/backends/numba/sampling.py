"""The sampling step as one compiled loop per pixel (the numba side of the ``sampling``
twin, :mod:`core.mc.estimator`).

:func:`pixel_sums` does, for every active pixel, what
:func:`core.mc.samples.active_pixels` does with arrays (its hash, channel
edges and tail map), and for each of its samples what the NumPy sampling step
does with whole arrays: R2 point, channel, radius and mixture density from the
profile's tables, direction from the direction table, screen position,
follow-surface tests, gather, per-channel weight (planar, chromatic or surface
distance with the area Jacobian) and the running sums. Nothing per sample is
stored, so memory is O(pixels) and the cost is proportional to Σm.

It mirrors the NumPy arithmetic operation by operation in float32 (sums in
float64, in sample order). Neither side calls a library function per sample
(the tables replace log, exp, sin and cos), so both backends draw the same
samples and agree to float32 rounding.

Tables are read flat, with unsigned indices: numba then emits no
negative-index wrap-around test per read. A pixel's lighting, depth, surface
area and slot share one 32-byte texel, so a sample's reads touch one cache
line (a hidden-surface sample's mirror image, a second).

Pixels are independent and each writes its own output row, so the result does
not depend on the thread count, the schedule or the order the pixels are
visited in (32×32 tiles, :func:`tile_order`; tiles of core.tiling stay
bit-identical to a whole-frame run on the same backend).
"""

from __future__ import annotations

import math
import types

import numba
import numpy as np

from ...sampling.qmc import DIRECTION_BITS, R2_STEP_U32
from .common import (
    _EIGHT,
    _FIVE,
    _FOUR,
    _M16,
    _M32,
    _ONE,
    _S16,
    _SEVEN,
    _SIX,
    _THREE,
    _TWO,
    _pcg3d_xy,
)
from .per_sample import _ABOVE, _kept, _normal_z, _offset, _opposite, _pdf

#: Geometry modes of the sampling pass.
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
#: Side of the square pixel tiles the pass visits the pixels in (see tile_order).
TILE = 32
# numba does integer arithmetic in 64 bits: the R2 step wraps modulo 2**32 by the mask.
_A = np.uint64(R2_STEP_U32[0])
_B = np.uint64(R2_STEP_U32[1])
_DIR_SHIFT = np.uint64(32 - DIRECTION_BITS)


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
    mirror,
    direct,
    use_obj,
    inv_k,
    touch,
    facing,
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

    Does, per pixel, what :func:`core.mc.samples.active_pixels` does with
    arrays (hash, channel edges, the affine map u ↦ tail value, float32
    copies), then per sample what :func:`core.mc.samples.batch_sums` does,
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
    mirror : (K,) bool, per slot: a hidden-surface sample of a centre of that slot
        first reads the pixel opposite it through the centre, where that pixel has the
        centre's key and lies within the sample's depth tolerance of the centre
        (B(q') − B(p) at its planar weight)
    direct : (G, 3) float32, the direct part of B of the Geometry's pixels
    use_obj : bool, the texels' slot carries the object (``slot + K·object``):
        a sample on another object is rejected (or, where the centre's surface runs on
        hidden under that object, counts unlit at its point of the centre's tangent
        plane: core.mc.estimator's module doc, *Objects*)
    inv_k : float32, 1/K (a power of two); touch : float32, SSSParams.contact (0: off);
    facing : float32, core.params.CONTACT_FACING
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
        the tasks are dealt out over them; read here, the pass could not be cached)

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
        b_near = np.zeros(BATCH, np.bool_)
        b_fill = np.empty(BATCH, np.bool_)
        b_touch = np.zeros(BATCH, np.bool_)
        b_mir = np.zeros(BATCH, np.bool_)
        b_keep = np.zeros(BATCH, np.float32)
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
                nz = _normal_z(nx, ny, texel[c8 + _FOUR])
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
            # The contact rule's reach, contact·d (d the slot's largest, as
            # Profile.contact_scale).
            dmax = dtab[mat, 0]
            if dtab[mat, 1] > dmax:
                dmax = dtab[mat, 1]
            if dtab[mat, 2] > dmax:
                dmax = dtab[mat, 2]
            reach = np.float32(dmax) * touch
            # How squarely the centre faces the camera, |n·v| (the contact test's facing
            # branch compares another object's against it).
            if mode == ORTHO:
                face_p = abs(nz)
            else:
                vx = (px - cx) * unit_x
                vy = (py - cy) * unit_y
                face_p = abs(vx * nx + vy * ny + nz) / np.sqrt(vx * vx + vy * vy + one)
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
                    b_near[j] = near
                    b_ok[j] = b_in[j] & (fb[_ROW_K + j] == key) & near
                # Then per sample: the landing texel's area and normal for stage 3's
                # branch-free arithmetic, and what becomes of a rejected sample.
                for j in range(nb):
                    if b_ok[j]:
                        b_fill[j] = False
                        b_touch[j] = False
                        b_mir[j] = False
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
                    keep = zero
                    area_t = zero
                    if inside and use_touch and np.floor(fb[_ROW_K + j] * inv_k) != obj:
                        # Another object: does the centre's surface meet it here, running
                        # on hidden under it or ending on it (core.mc.estimator's module
                        # doc, *Objects*)?
                        dz = zq - zp
                        if mode == PLANAR:
                            height = abs(dz)
                            if height < reach:
                                touching = True
                                keep = _kept(height, reach)
                        else:
                            qx = fb[_ROW_QX + j]
                            qy = fb[_ROW_QY + j]
                            ortho = mode == ORTHO
                            dx, dy = _offset(qx, qy, zq, px, py, zp, ortho, cx, cy, unit_x, unit_y)
                            q8 = np.uint64(q) * _EIGHT
                            mx = texel[q8 + _SIX]
                            my = texel[q8 + _SEVEN]
                            mz = _normal_z(mx, my, texel[q8 + _FOUR])
                            # Stage 2b's follow-surface test, as for the centre's own object.
                            follows = b_near[j] & (dx * nx + dy * ny + dz * nz >= zero)
                            if mode == ORTHO:
                                face_q = abs(mz)
                            else:
                                vx = (qx - cx) * unit_x
                                vy = (qy - cy) * unit_y
                                face_q = abs(vx * mx + vy * my + mz) / np.sqrt(
                                    vx * vx + vy * vy + one
                                )
                            hides = follows & (face_q > facing * face_p)
                            # The other object's plane through the landing pixel's own
                            # point (its centre at its depth).
                            fx = fb[_ROW_FX + j]
                            fy = fb[_ROW_FY + j]
                            lx, ly = _offset(fx, fy, zq, px, py, zp, ortho, cx, cy, unit_x, unit_y)
                            height = abs(lx * mx + ly * my + dz * mz)
                            ends = follows & (not hides) & (height < reach)
                            touching = hides | ends
                            if ends:
                                keep = _kept(height, reach)
                                # Its point on the centre's tangent plane against that plane:
                                # above it, the landing pixel holds the centre's surface there.
                                wq = pa * qx + pb * qy + pc
                                if ortho:
                                    zh = wq if np.isfinite(wq) else zp
                                else:
                                    zh = one / wq if wq > zero else zp
                                hx, hy = _offset(
                                    qx, qy, zh, px, py, zp, ortho, cx, cy, unit_x, unit_y
                                )
                                side = mx * (hx - lx) + my * (hy - ly) + mz * ((zh - zp) - dz)
                                if side > _ABOVE * fb[_ROW_R + j]:
                                    keep = one
                    fill = False
                    mirrored = False
                    if touching:
                        # At its point of the centre's tangent plane (the plane's depth
                        # along the sample's ray, the centre's area element), keeping its
                        # share of the light of its mirror image or else of the centre
                        # (none where another object hides the surface).
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
                        q = centre
                        if keep > zero and mirror[mat]:
                            qm = _opposite(
                                px, py, fb[_ROW_FX + j], fb[_ROW_FY + j], ox, oy, w, h, texel,
                                key, zp, slope * fb[_ROW_R + j],
                            )  # fmt: skip
                            if qm >= 0:
                                q = qm
                    else:
                        # Hidden surface: on the image, not in front of the centre.
                        hid = inside and not (zp - zq > np.float32(0.1) * zp)
                        q = centre
                        if mirror[mat] and hid:
                            # The pixel opposite through the centre, if on its surface.
                            qm = _opposite(
                                px, py, fb[_ROW_FX + j], fb[_ROW_FY + j], ox, oy, w, h, texel,
                                key, zp, slope * fb[_ROW_R + j],
                            )  # fmt: skip
                            if qm >= 0:
                                mirrored = True
                                q = qm
                        fill = mirrored or (use_fill and hid)
                        zq = zp
                        if core:
                            nfb += 1
                    b_fill[j] = fill
                    b_mir[j] = mirrored
                    b_ok[j] = ok
                    b_touch[j] = touching
                    b_keep[j] = keep
                    b_q[j] = q
                    fb[_ROW_ZQ + j] = zq
                    if use_plane:
                        q8 = np.uint64(centre if mirrored else q) * _EIGHT
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
                            mz = _normal_z(mx, my, area_q)
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
                # sample adds its mirror image's difference, or else its share of the
                # centre's direct light).
                for j in range(nb):
                    if b_ok[j]:
                        q8 = np.uint64(b_q[j]) * _EIGHT
                        l0 = texel[q8]
                        l1 = texel[q8 + _ONE]
                        l2 = texel[q8 + _TWO]
                        if b_touch[j]:  # its share of its mirror image's or the centre's
                            share = b_keep[j]
                            l0 = share * l0
                            l1 = share * l1
                            l2 = share * l2
                        if disk:
                            gq = fb[_ROW_G + j]
                            d0 = (l0 * gq - b0) * b_w[0, j]
                            d1 = (l1 * gq - b1) * b_w[1, j]
                            d2 = (l2 * gq - b2) * b_w[2, j]
                        else:
                            d0 = (l0 - b0) * b_w[0, j]
                            d1 = (l1 - b1) * b_w[1, j]
                            d2 = (l2 - b2) * b_w[2, j]
                    elif b_mir[j]:
                        q8 = np.uint64(b_q[j]) * _EIGHT
                        d0 = (texel[q8] - b0) * b_w[0, j]
                        d1 = (texel[q8 + _ONE] - b1) * b_w[1, j]
                        d2 = (texel[q8 + _TWO] - b2) * b_w[2, j]
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
#: What a pixel costs the pass besides its samples, in samples: 206 ns per pixel
#: against 25-37 ns per sample on one thread (docs/checks/kernel_per_pixel.py).
PIXEL_SAMPLES = 8
#: Below this much work (samples, plus PIXEL_SAMPLES per pixel) the serial build runs.
PARALLEL_MIN_SAMPLES = 1 << 16


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def texels(light, depth, area, normal, slots, surface):
    """(8N,) float32 texels of the pass (see pixel_sums), built in parallel."""
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
def relight(light, out):
    """Writes the lighting (N, 3) float32 into texels ``out`` (8N,) of the same pixels."""
    for i in numba.prange(light.shape[0]):
        o = 8 * i
        out[o] = light[i, 0]
        out[o + 1] = light[i, 1]
        out[o + 2] = light[i, 2]


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


def build_for(samples: int, pixels: int = 0):
    """The build of :func:`pixel_sums` for a call taking ``samples`` samples over ``pixels`` pixels.

    The serial build below PARALLEL_MIN_SAMPLES of work. The work counts each pixel
    as PIXEL_SAMPLES samples: at low counts a pixel's own cost dominates (a 320×180
    frame's 25416 SSS pixels at 1 spp took 5.7 ms serial, 3.4 ms on 2 threads, when
    only its 25416 samples were counted).
    """
    work = samples + PIXEL_SAMPLES * pixels
    return pixel_sums if work >= PARALLEL_MIN_SAMPLES else pixel_sums_serial


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def estimate_variance(var_sums, active, counts, gamma_sum):
    """core.mc.estimator.estimate_variance in one parallel pass, its float64 operations
    per pixel (np.maximum's rule: NaN stays NaN).

    Parameters
    ----------
    var_sums : (A, 2) float64; active : (A,) int64, ascending; counts : (P,) int64;
    gamma_sum : (P,) float64

    Returns
    -------
    (P,) float64
    """
    n = counts.shape[0]
    # Each pixel's row of var_sums (−1: not active, sums 0).
    row = np.full(n, -1, np.int64)
    for i in numba.prange(active.shape[0]):
        row[active[i]] = i
    out = np.empty(n)
    for k in numba.prange(n):
        r = row[k]
        v0 = var_sums[r, 0] if r >= 0 else 0.0
        v1 = var_sums[r, 1] if r >= 0 else 0.0
        m = np.float64(counts[k])
        s2 = (v1 - v0 * v0 / m) / (m - 1.0)
        if m > 1:
            top = s2 if (np.isnan(s2) or s2 >= 0.0) else 0.0
            v = top / m
        else:
            v = np.inf
        out[k] = 0.0 if (m == 0 or gamma_sum[k] == 0) else v
    return out

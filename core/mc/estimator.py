"""The unified direct/distant scattering estimator (P Sec. 5).

For an SSS pixel p with lighting B(p) and a per-channel profile,

    L_c(p) = (1 − γ_c)·B_c(p) + Î_c(p),

where γ_c = 1 − C_c(r0) is the energy beyond the pixel's own footprint
``r0 = sqrt(w² + h²)/2`` and Î_c estimates ``∫_{r≥r0} p_c(r)·E_θ[B_c(q)] dr``
with m samples.

Radii are drawn from the mixture of the channels' distant densities with
weights π_c ∝ γ_c, and channel c is weighted by ``γ_c·p̂_c(r)/q(r)`` (p̂_c the
distant density normalised on [r0, r_max]), which is unbiased for every
channel. The centre value serves as an exact control:

    Î_c = γ_c·B_c(p) + (1/m)·Σ_k w_c(r_k)·(B_c(q_k) − B_c(p)),

unbiased because E[w_c] = γ_c, identical to the paper's estimator when the
three channels share one profile (then w_c ≡ γ_c), and exact for constant
lighting for any m even when the channels differ. Samples that land off
screen, on another material or across a depth discontinuity fall back to the
centre ("follow surface", Jimenez et al. 2015) and so add nothing.

With a :class:`~cvsss.core.geometry.Surface` in the Geometry (SSSParams
``distance = "surface"``), channel c's weight becomes

    w_c = γ_c·p̂_c(r)/q(r) · R_c(d)/R_c(r) · J,

with d the distance between the two points on the depth-buffer surface and J
the area Jacobian of the screen → surface mapping (SPEC §11): the estimator
is then unbiased for ``B(p) + ∫ R_c(‖x_p − x_q‖)·(B(q) − B(p)) dA_q`` over the
visible surface beyond r0 — still exact for constant lighting, and equal to
the planar estimator on a fronto-parallel plane.

Work is compacted: only pixels with m > 0 are visited, their samples are laid
out contiguously, processed in bounded batches, and summed back with
``np.bincount``. Cost is proportional to Σm, never to the maximum count.

Two backends take the same samples (:mod:`core.mc.backend`): this module's
NumPy batches, and a compiled loop per pixel
(:mod:`core.mc.estimator_numba`) for the Burley profile when numba imports.
They agree to float32 rounding.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import Geometry
from ..profiles.base import Profile
from ..profiles.burley import BurleyProfile
from ..sampling.sequence import pixel_hashes, r2_points_fixed
from . import backend as backends

TWO_PI = 2.0 * np.pi


@dataclass
class DistantEstimate:
    """Result of the Monte Carlo step.

    Attributes
    ----------
    distant : (P, 3) float64, Î per channel (linear, same units as lighting)
    samples : int, samples actually taken (Σm; of the core pixels for a crop)
    fallback : int, samples that fell back to the centre value (idem)
    variance : (P,) float64 or None, the sample variance of Î's Rec. 709
        luminance (linear²) when asked for: 0 without samples, inf with one
    """

    distant: np.ndarray
    samples: int
    fallback: int
    variance: np.ndarray | None = None


def _chunks(counts: np.ndarray, limit: int):
    """Split the active pixel list into contiguous runs of at most ``limit`` samples."""
    ends = np.cumsum(counts)
    start = 0
    n = counts.shape[0]
    while start < n:
        base = ends[start - 1] if start else 0
        stop = int(np.searchsorted(ends, base + limit, side="right"))
        stop = max(stop, start + 1)
        yield start, min(stop, n)
        start = stop


def estimate_distant(
    geom: Geometry,
    lighting: np.ndarray,
    depth: np.ndarray,
    profile: Profile,
    counts: np.ndarray,
    *,
    frame: int,
    seed: int,
    depth_slope: float,
    chunk_samples: int = 1 << 20,
    variance: bool = False,
    backend: str = "numpy",
) -> DistantEstimate:
    """Estimate Î for every SSS pixel with the given per-pixel sample counts.

    Parameters
    ----------
    geom : Geometry from :func:`core.geometry.prepare`
    lighting : (H, W, 3) float32, B (linear)
    depth : (H, W) float, planar depth, scene units
    profile : Profile (over the compact slots of ``geom``)
    counts : (P,) int, samples per SSS pixel (0 = direct only)
    frame, seed : int, select the per-pixel R2 offsets
    depth_slope : float, follow-surface tolerance (see SSSParams.depth_slope)
    chunk_samples : int, batch size bound (memory)
    variance : bool, also estimate the variance of Î's luminance from the samples
    backend : {"auto", "numpy", "numba"}, implementation (:mod:`core.mc.backend`);
        numba runs the Burley profile, other profiles run on NumPy

    Returns
    -------
    DistantEstimate
    """
    h, w = geom.shape
    # A crop (core.tiling) places samples in image coordinates, with the image's
    # bounds, and reads its own arrays; a sample that leaves the crop falls back.
    full_h, full_w = geom.image_shape
    oy, ox = geom.origin
    light = lighting.reshape(-1, 3)
    depth_flat = depth.reshape(-1)
    mat_flat = geom.slots
    distant = geom.gamma * light[geom.index].astype(np.float64)
    counts = np.asarray(counts, dtype=np.int64)
    gsum = geom.gamma_sum
    active = np.flatnonzero((counts > 0) & (gsum > 0))
    total = int(counts[active].sum())
    fallback = 0
    var_sum = np.zeros((geom.size, 2)) if variance else None
    if total == 0:
        return DistantEstimate(distant, 0, 0, np.zeros(geom.size) if variance else None)
    core_a = None if geom.core is None else geom.core[active]
    counted = total if core_a is None else int(counts[active][core_a].sum())
    # Per active pixel quantities, computed once; samples expand them with
    # np.repeat (a streaming copy) rather than random gathers.
    sx_all, sy_all = pixel_hashes(geom.x[active], geom.y[active], frame, seed)
    act_counts = counts[active]
    gam = geom.gamma[active]
    g_s = gsum[active]
    # Channel c is chosen when edges[c] <= u < edges[c + 1], with edges the
    # cumulative γ_c/Σγ; from the last channel with γ > 0 on, edges are set
    # to exactly 1 so rounding can never select an empty channel.
    edges = np.zeros((active.size, 4))
    edges[:, 1:3] = np.cumsum(gam / g_s[:, None], axis=1)[:, :2]
    last = 2 - np.argmax(gam[:, ::-1] > 0, axis=1)
    edges[np.arange(4)[None, :] > last[:, None]] = 1.0
    edges = edges.astype(np.float32)
    lo_t = geom.lo[active].astype(np.float32)
    hi_t = geom.hi[active].astype(np.float32)
    mat_a = geom.mat[active]
    x_a = geom.x[active].astype(np.float32)
    y_a = geom.y[active].astype(np.float32)
    inv_fw = (1.0 / geom.fw[active]).astype(np.float32)
    inv_fh = (1.0 / geom.fh[active]).astype(np.float32)
    idx_a = geom.index[active]
    z_a = geom.depth[active].astype(np.float32)
    slope = np.float32(depth_slope)
    chrom_a = geom.chromatic[active]
    ws_a = np.ascontiguousarray(geom.weight_scale[active].T, dtype=np.float32)
    gam_cm = np.ascontiguousarray(gam.T, dtype=np.float32)
    g_s32 = g_s.astype(np.float32)
    surf = geom.surface
    fwfh = (geom.fw[active] * geom.fh[active]).astype(np.float32)
    if (
        backend != "numpy"
        and type(profile) is BurleyProfile  # a subclass may sample differently
        and backends.resolve(backend) == "numba"
    ):
        from .estimator_numba import ORTHO, PERSPECTIVE, PLANAR, kernel

        if surf is None:
            mode, unit, centre, area = PLANAR, (1.0, 1.0), (0.0, 0.0), fwfh[:1]
        else:
            mode = ORTHO if surf.ortho else PERSPECTIVE
            unit, centre, area = surf.unit, surf.centre, surf.area
        f32 = np.float32
        texel = np.empty((light.shape[0], 4), f32)
        texel[:, :3] = light
        texel[:, 3] = depth_flat
        sums, vs, fb = kernel(total)(
            sx_all,
            sy_all,
            act_counts,
            edges,
            lo_t,
            hi_t,
            mat_a.astype(np.int32, copy=False),
            x_a,
            y_a,
            inv_fw,
            inv_fh,
            idx_a.astype(np.int64, copy=False),
            z_a,
            np.ones(active.size, np.bool_) if core_a is None else core_a,
            np.ascontiguousarray(gam, dtype=np.float32),
            g_s32,
            chrom_a,
            fwfh,
            texel,
            mat_flat.astype(np.int32, copy=False),
            area,
            profile._d32,
            profile._inv3d,
            profile._inv4d,
            profile._rmax,
            f32(profile.truncate),
            profile.inverse == "fast",
            w,
            h,
            f32(full_w),
            f32(full_h),
            f32(ox),
            f32(oy),
            slope,
            mode,
            f32(unit[0]),
            f32(unit[1]),
            f32(unit[0] * unit[1]),
            f32(centre[0]),
            f32(centre[1]),
            variance,
        )
        distant[active] += sums / act_counts[:, None]
        fallback = int(fb.sum())
        if var_sum is not None:
            var_sum[active] += vs
        chunks = ()
    else:
        # Channel-major lighting: one contiguous row per channel.
        light_cm = np.ascontiguousarray(light.T, dtype=np.float32)
        depth32 = depth_flat.astype(np.float32)
        chunks = _chunks(act_counts, chunk_samples)
    for a, b in chunks:
        c = act_counts[a:b]
        n = int(c.sum())
        m = b - a
        local = np.repeat(np.arange(m), c)
        starts = (np.cumsum(c) - c).astype(np.uint32)
        k = np.arange(1, n + 1, dtype=np.uint32) - np.repeat(starts, c)
        u, v = r2_points_fixed(
            np.repeat(sx_all[a:b], c), np.repeat(sy_all[a:b], c), k, dtype=np.float32
        )

        # Pick channel c with probability γ_c/Σγ, then rescale u to reuse it.
        e = edges[a:b]
        ch = (u >= np.repeat(e[:, 1], c)).astype(np.intp) + (u >= np.repeat(e[:, 2], c))
        e4 = local * 4 + ch
        lo_sel = np.take(e, e4)
        uu = (u - lo_sel) / (np.take(e, e4 + 1) - lo_sel)
        np.clip(uu, 0.0, np.nextafter(np.float32(1.0), np.float32(0.0)), out=uu)
        flat = local * 3 + ch

        mat = np.repeat(mat_a[a:b], c)
        r = profile.sample(uu, np.take(lo_t[a:b], flat), np.take(hi_t[a:b], flat), mat, ch)
        r = r.astype(np.float32, copy=False)
        theta = v
        theta *= np.float32(TWO_PI)
        qx = np.cos(theta)
        qx *= r
        qx *= np.repeat(inv_fw[a:b], c)
        qx += np.repeat(x_a[a:b], c)
        qy = np.sin(theta, out=theta)
        qy *= r
        qy *= np.repeat(inv_fh[a:b], c)
        qy += np.repeat(y_a[a:b], c)
        # Clip first: with a huge d (or a tiny footprint) the offset would not
        # fit the integer cast; -1 and w/h stay outside, as before the clip.
        np.clip(qx, -1, full_w, out=qx)
        np.clip(qy, -1, full_h, out=qy)
        sx, sy = (qx.copy(), qy.copy()) if surf is not None else (None, None)
        qx = np.rint(qx, out=qx)
        qy = np.rint(qy, out=qy)
        if ox:
            qx -= np.float32(ox)
        if oy:
            qy -= np.float32(oy)
        centre_idx = np.repeat(idx_a[a:b], c)
        inside = (qx >= 0) & (qx < w) & (qy >= 0) & (qy < h)
        q = np.where(inside, qy.astype(np.intp) * w + qx.astype(np.intp), centre_idx)
        ok = inside & (np.take(mat_flat, q) == mat)
        zq = np.take(depth32, q)
        zp = np.repeat(z_a[a:b], c)
        ok &= np.abs(zq - zp) <= slope * r
        if core_a is None:
            fallback += n - int(np.count_nonzero(ok))
        else:
            fallback += int(np.count_nonzero(np.repeat(core_a[a:b], c) & ~ok))
        # A rejected sample reads the centre, so its difference is exactly 0.
        q = np.where(ok, q, centre_idx)
        diff = np.take(light_cm, q, axis=1)
        diff -= np.repeat(np.take(light_cm, idx_a[a:b], axis=1), c, axis=1)

        if surf is not None:
            # Surface distance: the sample's point on the depth-buffer surface
            # (its continuous screen position at the depth of the pixel it lands
            # on) against the centre's; the profile at that distance over the
            # profile at r (R = pdf/(2πr)) times the area Jacobian.
            zq = np.where(ok, zq, zp)
            px = np.repeat(x_a[a:b], c)
            py = np.repeat(y_a[a:b], c)
            if surf.ortho:
                dx = (sx - px) * np.float32(surf.unit[0])
                dy = (sy - py) * np.float32(surf.unit[1])
                plane = np.repeat(fwfh[a:b], c)
            else:
                cx, cy = (np.float32(v) for v in surf.centre)
                dx = ((sx - cx) * zq - (px - cx) * zp) * np.float32(surf.unit[0])
                dy = ((sy - cy) * zq - (py - cy) * zp) * np.float32(surf.unit[1])
                plane = zp * zp * np.float32(surf.unit[0] * surf.unit[1])
            dz = zq - zp
            dist = np.sqrt(dx * dx + dy * dy + dz * dz)
            np.maximum(dist, np.float32(1e-30), out=dist)
            jac = np.take(surf.area, q) / plane
            dens_r = profile.pdf_channels(r, mat)
            dens = profile.pdf_channels(dist, mat)
            if profile.pixel_weight_scale:
                ws = np.repeat(ws_a[:, a:b], c, axis=1)
                dens_r *= ws
                dens *= ws
            norm = dens_r[0] + dens_r[1] + dens_r[2]
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                scale = np.where(
                    norm > 0, np.repeat(g_s32[a:b], c) * (r / dist) * jac / norm, np.float32(0)
                )
            dens *= scale
            diff *= dens
        elif chrom_a[a:b].any():
            dens = profile.pdf_channels(r, mat)
            if profile.pixel_weight_scale:
                dens *= np.repeat(ws_a[:, a:b], c, axis=1)
            norm = dens[0] + dens[1] + dens[2]
            with np.errstate(divide="ignore", invalid="ignore"):
                scale = np.where(norm > 0, np.repeat(g_s32[a:b], c) / norm, np.float32(0))
            dens *= scale
            diff *= dens
        else:  # one profile for all channels: w_c = γ_c exactly
            diff *= np.repeat(gam_cm[:, a:b], c, axis=1)
        pix = active[a:b]
        for ci in range(3):
            distant[pix, ci] += np.bincount(local, weights=diff[ci], minlength=m) / c
        if var_sum is not None:
            y = diff[0] * np.float32(0.2126) + diff[1] * np.float32(0.7152)
            y += diff[2] * np.float32(0.0722)
            var_sum[pix, 0] += np.bincount(local, weights=y, minlength=m)
            var_sum[pix, 1] += np.bincount(local, weights=y.astype(np.float64) ** 2, minlength=m)
    spread = None
    if var_sum is not None:
        m_all = counts.astype(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            s2 = (var_sum[:, 1] - var_sum[:, 0] ** 2 / m_all) / (m_all - 1.0)
            spread = np.where(m_all > 1, np.maximum(s2, 0.0) / m_all, np.inf)
        spread[(m_all == 0) | (gsum == 0)] = 0.0
    return DistantEstimate(distant, counted, fallback, spread)

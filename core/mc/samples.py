"""The NumPy sampling step: every sample's arithmetic, in batches of whole arrays.

The NumPy side of the ``sampling`` twin (:func:`core.mc.estimator.distant_sums`):
:func:`active_pixels` gathers what the loop reads per pixel (:class:`Pixels`), and
:func:`batch_sums` draws each pixel's samples and sums their weighted differences,
batch by batch, in sample order. The estimator it computes and the rules of a sample
(radius and direction, following the surface, objects, Cycles' disk kernel) are
described in :mod:`core.mc.estimator`; the compiled loop
(:mod:`core.backends.numba.sampling`) does the same float32 operations per sample.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..geometry import Geometry
from ..params import CONTACT_FACING, CONTACT_FOOT, CONTACT_LOSS
from ..profiles.base import Profile
from ..profiles.burley import BurleyProfile, pdf_from_table
from ..sampling.qmc import DIRECTION_BITS, DIRECTIONS, pixel_hashes, r2_fixed

_FACING = np.float32(CONTACT_FACING)
_LOSS = np.float32(CONTACT_LOSS)
_FOOT = np.float32(CONTACT_FOOT)
#: A touching sample's point on the centre's plane counts as above the other object's
#: plane beyond this share of its radius (not float rounding on a plane both share).
_ABOVE = np.float32(1e-4)

# The direction table's columns, contiguous: a strided column costs the sampling
# loop several times a contiguous one.
_DIR_X, _DIR_Y = (np.ascontiguousarray(col) for col in DIRECTIONS.T)


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


@dataclass
class Pixels:
    """What the sampling loop reads per active pixel (P of them), built once per frame.

    Both backends read these arrays, so they take the same samples.

    Attributes
    ----------
    counts : (P,) int64, samples m ≥ 1
    hx, hy : (P,) uint32, hashed R2 offsets (0.32 fixed point)
    edges : (P, 4) float32, cumulative channel probabilities γ_c/Σγ (channel c is
        drawn when edges[c] <= u < edges[c + 1])
    t_a, t_b : (P, 3) float32, the distant region in the profile's u-space as an
        affine map of the R2 coordinate u: a sample of channel c is at
        ``t = t_a[c] + t_b[c]·u`` (Burley: the tail value, in [lo_c, hi_c]; other
        profiles: the position in [0, 1) between their bounds)
    lo, hi : (P, 3) float32, the profile's sampling bounds (other profiles sample
        between them)
    x, y : (P,) float32, image coordinates; inv_fw : (P,) float32, 1/footprint width
    idx : (P,) int64, flat index into the frame's arrays; z : (P,) float32, depth
    mat : (P,) int32, compact slot; core : (P,) bool or None (a crop's core pixels)
    gam : (P, 3) float32, γ_c; g_s : (P,) float32, Σγ; chrom : (P,) bool
    fwfh : (P,) float32, footprint area (scene units², the ortho plane element)
    ws : (3, P) float32, γ_c/mass_c (profiles with a per-pixel weight scale)
    pscale, inv_d : (3, P) float32, Burley pdf table scale size/(truncate·d_c) and
        1/d_c (:func:`core.profiles.burley.pdf_from_table`); zeros for other profiles
    frame : (9, P) float32 or None, the disk axes N, T, B (:func:`disk_frame`, one row
        per component) for the disk kernel; rho_min : (P,) float32, half the pixel's
        footprint (scene units)
    plane : (3, P) float32 or None, the centre's tangent plane as an affine function
        of the landing pixel's image coordinates (:func:`tangent_planes`, one row per
        coefficient)
    direct : (P, 3) float32 or None, the direct part of B (``Geometry.direct``)
    aspect : float32, footprint width / height (one per camera): the vertical
        offset in pixels is the horizontal one times this
    """

    counts: np.ndarray
    hx: np.ndarray
    hy: np.ndarray
    edges: np.ndarray
    t_a: np.ndarray
    t_b: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    x: np.ndarray
    y: np.ndarray
    inv_fw: np.ndarray
    idx: np.ndarray
    z: np.ndarray
    mat: np.ndarray
    core: np.ndarray | None
    gam: np.ndarray
    g_s: np.ndarray
    chrom: np.ndarray
    fwfh: np.ndarray
    ws: np.ndarray
    pscale: np.ndarray
    inv_d: np.ndarray
    aspect: np.float32
    frame: np.ndarray | None = None
    rho_min: np.ndarray | None = None
    plane: np.ndarray | None = None
    direct: np.ndarray | None = None


def _offset(sx, sy, zq, centre, cx, cy, unit_x, unit_y, ortho: bool):
    """Camera-space x, y offset (scene units, float32) from the centre pixel (px, py) at
    depth zp to the screen point (sx, sy) at depth zq (perspective: through the
    principal point (cx, cy); ortho: depth does not scale it).

    ``centre`` is the centre's term per sample, from :func:`_centre_terms`: (px, py)
    in ortho, ((px − cx)·zp, (py − cy)·zp) in perspective.
    """
    ex, ey = centre
    if ortho:
        return (sx - ex) * unit_x, (sy - ey) * unit_y
    dx = (sx - cx) * zq
    dx -= ex
    dx *= unit_x
    dy = (sy - cy) * zq
    dy -= ey
    dy *= unit_y
    return dx, dy


def _centre_terms(pix: Pixels, cx, cy, ortho: bool) -> tuple[np.ndarray, np.ndarray]:
    """(P,) float32 twice: the centre's part of :func:`_offset`, once per pixel."""
    if ortho:
        return pix.x, pix.y
    return (pix.x - cx) * pix.z, (pix.y - cy) * pix.z


def active_pixels(
    geom: Geometry, profile: Profile, counts: np.ndarray, active: np.ndarray, frame: int, seed: int
) -> Pixels:
    """:class:`Pixels` of the ``active`` SSS pixels (indices into ``geom``)."""
    if active.size == geom.size:  # the usual case: no copies

        def sel(values):
            return values

    else:

        def sel(values):
            return np.take(values, active, axis=0)

    hx, hy = pixel_hashes(sel(geom.x), sel(geom.y), frame, seed)
    gam = sel(geom.gamma)
    g_s = sel(geom.gamma_sum)
    # Channel c is chosen when edges[c] <= u < edges[c + 1], with edges the
    # cumulative γ_c/Σγ; from the last channel with γ > 0 on, edges are set
    # to exactly 1 so rounding can never select an empty channel.
    g0, g1, g2 = gam[:, 0], gam[:, 1], gam[:, 2]
    e1 = np.where((g1 > 0) | (g2 > 0), g0 / g_s, 1.0).astype(np.float32)
    e2 = np.where(g2 > 0, (g0 + g1) / g_s, 1.0).astype(np.float32)
    edges = np.empty((active.size, 4), np.float32)
    edges[:, 0] = 0.0
    edges[:, 1] = e1
    edges[:, 2] = e2
    edges[:, 3] = 1.0
    # u ∈ [e_c, e_{c+1}) ↦ its position uu = (u − e_c)/(e_{c+1} − e_c) in the channel's
    # interval ↦ (Burley) the tail t = hi − uu·(hi − lo): both affine in u.
    e = edges.astype(np.float64)
    width = e[:, 1:] - e[:, :3]
    lo, hi = sel(geom.lo), sel(geom.hi)
    with np.errstate(divide="ignore"):
        slope = np.where(width > 0, 1.0 / np.maximum(width, 1e-300), 0.0)
    mat = sel(geom.mat)
    if type(profile) is BurleyProfile:
        t_b = (lo - hi) * slope
        t_a = hi - t_b * e[:, :3]
        pscale = np.take(profile._pscale, mat, axis=1)
        inv_d = np.take(profile._inv_d, mat, axis=1)
    else:
        t_b = slope
        t_a = -e[:, :3] * slope
        pscale = inv_d = np.zeros((3, active.size), np.float32)
    fw, fh = sel(geom.fw), sel(geom.fh)
    f32 = np.float32
    frame = rho_min = plane = None
    if geom.surface is not None and geom.surface.normal is not None:
        axes = disk_frame(np.take(geom.surface.normal, sel(geom.index), axis=0))
        rho_min = (0.5 * fw).astype(f32)
        plane = tangent_planes(geom.surface, axes[:, :3], sel(geom.x), sel(geom.y), sel(geom.depth))
        # One contiguous row per component: the sampling loop repeats rows.
        frame = np.ascontiguousarray(axes.T)
        plane = np.ascontiguousarray(plane.T)
    return Pixels(
        counts=counts[active],
        hx=hx,
        hy=hy,
        edges=edges,
        t_a=t_a.astype(f32),
        t_b=t_b.astype(f32),
        lo=lo.astype(f32),
        hi=hi.astype(f32),
        x=sel(geom.x).astype(f32),
        y=sel(geom.y).astype(f32),
        inv_fw=(1.0 / fw).astype(f32),
        idx=sel(geom.index),
        z=sel(geom.depth).astype(f32),
        mat=mat.astype(np.int32, copy=False),
        core=None if geom.core is None else sel(geom.core),
        gam=gam.astype(f32),
        g_s=g_s.astype(f32),
        chrom=sel(geom.chromatic),
        fwfh=(fw * fh).astype(f32),
        ws=np.ascontiguousarray(sel(geom.weight_scale).T, dtype=f32),
        pscale=pscale,
        inv_d=inv_d,
        frame=frame,
        rho_min=rho_min,
        plane=plane,
        direct=None if geom.direct is None else sel(geom.direct),
        aspect=f32(fw[0] / fh[0]) if active.size else f32(1.0),
    )


def batch_sums(
    geom: Geometry,
    pix: Pixels,
    lighting: np.ndarray,
    depth: np.ndarray,
    profile: Profile,
    depth_slope: float,
    variance: bool,
    chunk_samples: int,
    disk: bool = False,
    hidden_light: float = 1.0,
    contact: float = 0.0,
    mirror: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray | None, int]:
    """Per active pixel Σ_k w_c·(B_c(q_k) − B_c(p)), luminance sums and fall-backs (NumPy).

    Samples are processed in batches of at most ``chunk_samples``, pixel by
    pixel, so that each pixel's samples are contiguous and summed in order.

    Returns
    -------
    sums : (P, 3) float64; var : (P, 2) float64 Σy and Σy² (None without variance);
    fallback : int, samples that fell back (of the core pixels for a crop)
    """
    h, w = geom.shape
    # A crop (core.tiling) places samples in image coordinates, with the image's
    # bounds, and reads its own arrays; a sample that leaves the crop falls back.
    full_h, full_w = geom.image_shape
    oy, ox = geom.origin
    burley = type(profile) is BurleyProfile
    n_pix = pix.counts.size
    sums = np.empty((n_pix, 3))
    var = np.empty((n_pix, 2)) if variance else None
    fallback = 0
    # Channel-major lighting: one contiguous row per channel.
    light_cm = np.ascontiguousarray(lighting.reshape(-1, 3).T, dtype=np.float32)
    centre_light = light_cm[:, pix.idx]
    depth32 = depth.reshape(-1).astype(np.float32)
    slots = geom.slots
    surf = geom.surface
    slope = np.float32(depth_slope)
    top = np.nextafter(np.float32(1.0), np.float32(0.0))
    t_a, t_b = pix.t_a.reshape(-1), pix.t_b.reshape(-1)
    if burley:
        rcols, ncols = profile._rcols, profile._ncols
        size = np.float32(rcols[0].shape[0] - 1)
        trunc = np.float32(profile.truncate)
        # Per (slot, channel), flat: index mat·3 + ch.
        d_kc = profile._d32
        inv_d_kc = np.ascontiguousarray(profile._inv_d.T).reshape(-1)
    lo_flat, hi_flat = pix.lo.reshape(-1), pix.hi.reshape(-1)
    if surf is not None:
        unit_x, unit_y = (np.float32(v) for v in surf.unit)
        cx, cy = (np.float32(v) for v in surf.centre)
        centre_x, centre_y = _centre_terms(pix, cx, cy, surf.ortho)
    fill_value = None
    if hidden_light < 1.0 and pix.direct is not None:
        fill_value = np.float32(-(1.0 - hidden_light)) * pix.direct.T
    if disk:
        normal_cm = np.ascontiguousarray(surf.normal.T)  # (3, H·W): one row per component
    objects = geom.objects
    touch = np.float32(contact) if objects is not None and contact > 0 else None
    if touch is not None:
        contact_scale = np.asarray(profile.contact_scale(), dtype=np.float32)
    for a, b in _chunks(pix.counts, chunk_samples):
        c = pix.counts[a:b]
        n = int(c.sum())
        local = np.repeat(np.arange(a, b, dtype=np.intp), c)
        starts = np.cumsum(c) - c
        k = np.arange(1, n + 1, dtype=np.uint32)
        k -= np.repeat(starts.astype(np.uint32), c)
        uq, vq = r2_fixed(np.repeat(pix.hx[a:b], c), np.repeat(pix.hy[a:b], c), k)
        u = uq.astype(np.float32)
        u *= np.float32(2.0**-32)
        np.minimum(u, top, out=u)

        # Channel c with probability γ_c/Σγ; u's place inside the channel's interval,
        # mapped affinely, is the sample's coordinate in the profile's u-space.
        ch = (u >= np.repeat(pix.edges[a:b, 1], c)).astype(np.intp)
        ch += u >= np.repeat(pix.edges[a:b, 2], c)
        flat = local * 3
        flat += ch
        t = np.take(t_b, flat, mode="clip")
        t *= u
        t += np.take(t_a, flat, mode="clip")
        mat = np.repeat(pix.mat[a:b], c)
        norm = None
        if burley:
            # The radius from the table; in surface mode also the channel mixture's
            # density there, from the slot's table at the same position.
            np.clip(t, 0.0, 1.0, out=t)
            s = np.sqrt(t, out=t)
            s *= size
            i = s.astype(np.int32)
            f = np.subtract(s, i, dtype=np.float32)
            r = f * np.take(rcols[1], i, mode="clip")
            r += np.take(rcols[0], i, mode="clip")
            np.minimum(r, trunc, out=r)
            slot_ch = mat * 3
            slot_ch += ch
            r *= np.take(d_kc, slot_ch, mode="clip")
            if surf is not None:
                row = slot_ch.astype(np.intp) * rcols[0].shape[0]
                row += i
                norm = f * np.take(ncols[1], row, mode="clip")
                norm += np.take(ncols[0], row, mode="clip")
                # Rows that straddle another channel's truncation (a few per slot).
                cut = s < np.take(ncols[2], row, mode="clip")
                if cut.any():
                    norm[cut] -= np.take(ncols[3], row[cut])
                norm *= np.take(inv_d_kc, slot_ch, mode="clip")
        else:
            np.clip(t, 0.0, top, out=t)
            r = profile.sample(t, np.take(lo_flat, flat), np.take(hi_flat, flat), mat, ch)
            r = np.asarray(r, dtype=np.float32)
        rp = r * np.repeat(pix.inv_fw[a:b], c)
        bins = (vq >> np.uint32(32 - DIRECTION_BITS)).astype(np.intp)
        px = np.repeat(pix.x[a:b], c)
        py = np.repeat(pix.y[a:b], c)
        centre = None
        if surf is not None:
            centre = np.repeat(centre_x[a:b], c), np.repeat(centre_y[a:b], c)
        qx = rp * np.take(_DIR_X, bins, mode="clip")
        qx += px
        qy = rp * np.take(_DIR_Y, bins, mode="clip")
        if pix.aspect != 1:
            qy *= pix.aspect
        qy += py
        # Clip first: with a huge d (or a tiny footprint) the offset would not
        # fit the integer cast; -1 and w/h stay outside.
        np.clip(qx, -1, full_w, out=qx)
        np.clip(qy, -1, full_h, out=qy)
        fx = np.rint(qx)
        fy = np.rint(qy)
        centre_idx = np.repeat(pix.idx[a:b], c)
        q, inside = _crop_index(fx, fy, ox, oy, w, h, centre_idx)
        ok = inside & (np.take(slots, q, mode="clip") == mat)
        zq = np.take(depth32, q, mode="clip")
        zp = np.repeat(pix.z[a:b], c)
        tol = slope * r
        near = np.abs(zq - zp) <= tol
        if pix.plane is not None:
            # Or within the tolerance of the centre's tangent plane (a tilted surface).
            w_pl = np.repeat(pix.plane[0, a:b], c) * fx
            w_pl += np.repeat(pix.plane[1, a:b], c) * fy
            w_pl += np.repeat(pix.plane[2, a:b], c)
            if surf.ortho:
                near |= np.abs(zq - w_pl) <= tol
            else:
                e = zq * w_pl
                e -= np.float32(1.0)
                near |= (w_pl > 0) & (np.abs(e) <= tol * w_pl)
        ok &= near
        # Objects: light never passes from one object to another. A sample on another
        # object that meets the centre's surface stands for that surface where it meets
        # it: running on hidden under it unlit, or ending on it and losing part of its
        # light (core.mc.estimator's module doc, *Objects*).
        touching = share = None
        if objects is not None:
            other = np.take(objects, q, mode="clip") != np.repeat(np.take(objects, pix.idx[a:b]), c)
            other &= inside
            ok &= ~other
            if touch is not None:
                reach = np.take(contact_scale, mat)
                reach *= touch
                touching, share = _touching(
                    other, near, q, qx, qy, fx, fy, zq, zp, px, py, centre, r, reach, pix,
                    surf, local,
                )  # fmt: skip
                if not touching.any():
                    touching = share = None
        # Hidden surface: a rejected sample on the image that landed on the background,
        # another material or object, or the centre's surface beyond the depth tolerance
        # (not in front of the centre, an occluder, nor touching it). With ``mirror`` it
        # reads the point opposite it through the centre where that point is on the
        # centre's surface; otherwise it counts with the centre's light less (1 − β) of
        # its direct part. Both at its planar weight (module doc, *Hidden surface*).
        fill = None
        if fill_value is not None or mirror is not None:
            fill = inside & ~ok
            if touching is not None:
                fill &= ~touching
            fill &= ~(zp - zq > np.float32(0.1) * zp)
            mirrored = None
            if mirror is not None and fill.any():
                mirrored_q = _mirrored(
                    fill & np.take(mirror, mat), px, py, fx, fy, zp, tol, mat, centre_idx,
                    slots, objects, depth32, w, h, ox, oy,
                )  # fmt: skip
                mirrored = mirrored_q >= 0
                if fill_value is None:
                    fill = mirrored
            if fill.any():
                # The filled samples' pixels (indices into pix) and (3, n_fill) what
                # they add, B(q') − B(p) or −(1 − β)·B_direct(p), times a weight below.
                at = np.flatnonzero(fill)
                fill_pix = np.take(local, at)
                if fill_value is None:
                    fill_light = np.zeros((3, at.size), np.float32)
                else:
                    fill_light = np.take(fill_value, fill_pix, axis=1)
                if mirrored is not None:
                    qm = np.take(mirrored_q, at)
                    on = qm >= 0
                    for ci in range(3):
                        m_light = np.take(light_cm[ci], qm[on])
                        m_light -= np.take(centre_light[ci], fill_pix[on])
                        fill_light[ci, on] = m_light
            else:
                fill = None
        if touching is not None:
            # Weighed as accepted samples at their point of the centre's tangent plane.
            ok |= touching
        if pix.core is None:
            fallback += n - int(np.count_nonzero(ok))
        else:
            fallback += int(np.count_nonzero(np.repeat(pix.core[a:b], c) & ~ok))
        # A rejected sample reads the centre, so its difference is exactly 0.
        q = np.where(ok, q, centre_idx)
        diff = np.empty((3, n), np.float32)
        for ci in range(3):
            np.take(light_cm[ci], q, out=diff[ci], mode="clip")
        if touching is not None:
            # The share of light a touching sample keeps, of its mirror image's light
            # (where the slot reads mirror images and the opposite pixel is on the
            # centre's surface) or else of the centre's; none where another object hides
            # the surface.
            diff[:, touching] = np.float32(0.0)
            kept = touching & (share > 0)
            if kept.any():
                source = centre_idx
                if mirror is not None:
                    opposite = _mirrored(
                        kept & np.take(mirror, mat), px, py, fx, fy, zp, tol, mat, centre_idx,
                        slots, objects, depth32, w, h, ox, oy,
                    )  # fmt: skip
                    source = np.where(opposite >= 0, opposite, centre_idx)
                at = np.flatnonzero(kept)
                part = np.take(share, at)
                src = np.take(source, at)
                for ci in range(3):
                    diff[ci, at] = part * np.take(light_cm[ci], src)
        centre_rep = np.repeat(centre_light[:, a:b], c, axis=1)

        if surf is not None:
            # Surface distance: the sample's point on the depth-buffer surface (its
            # continuous screen position at the depth of the pixel it lands on)
            # against the centre's; the profile at that distance over the profile
            # at r (R = pdf/(2πr)) times the area Jacobian.
            zq = np.where(ok, zq, zp)
            area_q = np.take(surf.area, q, mode="clip")
            if touching is not None:
                zq, area_q = _on_plane(touching, zq, area_q, qx, qy, zp, pix, surf, local)
            dx, dy = _offset(qx, qy, zq, centre, cx, cy, unit_x, unit_y, surf.ortho)
            if surf.ortho:
                plane = np.repeat(pix.fwfh[a:b], c)
            else:
                plane = zp * zp
                plane *= np.float32(surf.unit[0] * surf.unit[1])
            dz = zq - zp
            dist = dx * dx
            dist += dy * dy
            dist += dz * dz
            np.sqrt(dist, out=dist)
            np.maximum(dist, np.float32(1e-30), out=dist)
            if norm is None:
                dens_r = _pdf(profile, r, mat, pix, a, c)
                norm = dens_r[0] + dens_r[1] + dens_r[2]
            dens = _pdf(profile, dist, mat, pix, a, c)
            if disk:
                # Cycles' kernel is the surface kernel times G = |Δ|·Σ_a m_a/ρ_a: the
                # sample's value B(q) counts G times against the centre's B(p). Δ runs
                # to the landing pixel's own point (its centre), so that on a plane it
                # lies in the plane and G = 1.
                ex, ey = _offset(fx, fy, zq, centre, cx, cy, unit_x, unit_y, surf.ortho)
                # A rejected sample reads the centre (G = 1); a touching one lies on
                # the centre's plane (G = 1).
                weighed = ok if touching is None else ok & ~touching
                diff *= _disk_gain(ex, ey, dz, q, normal_cm, pix, a, c, weighed)
            diff -= centre_rep
            # w_c = Σγ·pdf_c(dist)/Σ_c' pdf_c'(r) · (r/dist) · area_q/plane
            scale = np.repeat(pix.g_s[a:b], c)
            scale *= r
            scale *= area_q
            dist *= norm
            dist *= plane
            with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                scale /= dist
            scale = np.where(norm > 0, scale, np.float32(0.0))
            dens *= scale
            diff *= dens
            if fill is not None:
                planar = _pdf_at(profile, r[fill], pix, fill_pix)
                g_s = np.take(pix.g_s, fill_pix)
                with np.errstate(divide="ignore", invalid="ignore"):
                    planar *= np.where(norm[fill] > 0, g_s / norm[fill], np.float32(0.0))
                diff[:, fill] = fill_light * planar
        elif pix.chrom[a:b].any():
            diff -= centre_rep
            dens = _pdf(profile, r, mat, pix, a, c)
            norm = dens[0] + dens[1] + dens[2]
            scale = np.repeat(pix.g_s[a:b], c)
            with np.errstate(divide="ignore", invalid="ignore"):
                scale /= norm
            scale = np.where(norm > 0, scale, np.float32(0.0))
            dens *= scale
            diff *= dens
            if fill is not None:
                diff[:, fill] = fill_light * dens[:, fill]
        else:  # one profile for all channels: w_c = γ_c exactly
            diff -= centre_rep
            gam = np.repeat(pix.gam[a:b].T, c, axis=1)
            diff *= gam
            if fill is not None:
                diff[:, fill] = fill_light * gam[:, fill]
        starts = starts.astype(np.intp)
        sums[a:b] = np.add.reduceat(diff, starts, axis=1, dtype=np.float64).T
        if var is not None:
            y = diff[0] * np.float32(0.2126) + diff[1] * np.float32(0.7152)
            y += diff[2] * np.float32(0.0722)
            y64 = y.astype(np.float64)
            var[a:b, 0] = np.add.reduceat(y64, starts)
            y64 *= y64
            var[a:b, 1] = np.add.reduceat(y64, starts)
    return sums, var, fallback


def _crop_index(fx, fy, ox: int, oy: int, w: int, h: int, elsewhere):
    """The flat index into a (h, w) crop at origin (ox, oy) of pixels at whole image
    coordinates ``(fx, fy)`` (float arrays), ``elsewhere`` off the crop, and (n,) bool
    whether on it."""
    ix = fx.astype(np.intp)
    iy = fy.astype(np.intp)
    if ox:
        ix -= ox
    if oy:
        iy -= oy
    # Negative coordinates wrap to huge unsigned values: one test per axis.
    inside = ix.view(np.uintp) < w
    inside &= iy.view(np.uintp) < h
    q = iy * w
    q += ix
    return np.where(inside, q, elsewhere), inside


def _mirrored(
    hidden, px, py, fx, fy, zp, tol, mat, centre_idx,
    slots, objects, depth32, w, h, ox, oy,
) -> np.ndarray:  # fmt: skip
    """(n,) intp: for each ``hidden`` sample, the pixel opposite its landing pixel
    through the centre, ``2·p − q``, where that pixel is on the crop, of the centre's
    material and object, and within the sample's depth tolerance of the centre's depth
    (``tol``; not the tangent-plane test: a mirror image is a stand-in, taken only
    where it plainly continues the centre's surface); −1 elsewhere."""
    out = np.full(hidden.size, -1, np.intp)
    at = np.flatnonzero(hidden)
    mx = np.float32(2.0) * np.take(px, at)
    mx -= np.take(fx, at)
    my = np.float32(2.0) * np.take(py, at)
    my -= np.take(fy, at)
    centre = np.take(centre_idx, at)
    q, inside = _crop_index(mx, my, ox, oy, w, h, centre)
    ok = inside & (np.take(slots, q) == np.take(mat, at))
    if objects is not None:
        ok &= np.take(objects, q) == np.take(objects, centre)
    ok &= np.abs(np.take(depth32, q) - np.take(zp, at)) <= np.take(tol, at)
    out[at] = np.where(ok, q, -1)
    return out


def _touching(
    other, near, q, qx, qy, fx, fy, zq, zp, px, py, centre, r, reach, pix: Pixels, surf, local
):
    """(n,) bool and (n,) float32: the samples on ``other`` objects that stand for the
    centre's surface where it meets that object, and the share of its light each keeps
    (:mod:`core.mc.estimator`'s module doc, *Objects*).

    Such a sample follows the centre's surface in depth (``near``: the depth test a
    sample of the centre's own object passes) and is not below its tangent plane. If
    the other object faces the camera :data:`core.params.CONTACT_FACING` times more
    squarely than the centre, it hides the surface, which runs on under it unlit (share
    0). Otherwise the surface ends on it: where the centre lies within ``reach``
    (contact·d) of the other object's tangent plane through the landing pixel's own
    point (its centre at its depth), at a height h, the sample keeps ``1 − CONTACT_LOSS·min((reach − h) / (reach − CONTACT_FOOT·reach),
    1)`` of its light, all of it where its point on the centre's tangent plane lies above
    the other object's plane (the landing pixel only holds part of the centre's surface
    there, by more than ``_ABOVE·r``). Without normals (planar weights) both planes face
    the camera and h is the depth difference. Only the ``other`` samples are computed;
    ``local`` holds each sample's pixel (index into ``pix``); ``q`` each sample's landing
    pixel, ``(fx, fy)`` its centre; ``r`` its radius, ``reach`` (n,) float32.
    """
    at = np.flatnonzero(other)
    touching = np.zeros(other.size, bool)
    share = np.zeros(other.size, np.float32)
    if at.size == 0:
        return touching, share
    zq = np.take(zq, at)
    zp = np.take(zp, at)
    reach = np.take(reach, at)
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        dz = zq - zp
        if pix.frame is None:
            height = np.abs(dz)
            ends = height < reach
            touching[at] = ends
            share[at] = np.where(ends, _kept(height, reach), np.float32(0.0))
            return touching, share
        unit_x, unit_y = (np.float32(v) for v in surf.unit)
        cx, cy = (np.float32(v) for v in surf.centre)
        sx, sy = np.take(qx, at), np.take(qy, at)
        centre = np.take(centre[0], at), np.take(centre[1], at)
        dx, dy = _offset(sx, sy, zq, centre, cx, cy, unit_x, unit_y, surf.ortho)
        li = np.take(local, at)
        nx, ny, nz = (np.take(pix.frame[k], li) for k in range(3))
        qi = np.take(q, at)
        mx, my, mz = (np.take(surf.normal[:, k], qi) for k in range(3))
        above = dx * nx
        above += dy * ny
        above += dz * nz
        follows = np.take(near, at) & (above >= 0)
        if surf.ortho:
            face_p, face_q = np.abs(nz), np.abs(mz)
        else:
            face_p = _facing(np.take(px, at), np.take(py, at), nx, ny, nz, cx, cy, unit_x, unit_y)
            face_q = _facing(sx, sy, mx, my, mz, cx, cy, unit_x, unit_y)
        hides = follows & (face_q > _FACING * face_p)
        # The other object's plane through the landing pixel's own point (its centre at
        # its depth: the continuous position at that depth is off a slanted plane).
        gx, gy = _offset(
            np.take(fx, at), np.take(fy, at), zq, centre, cx, cy, unit_x, unit_y, surf.ortho
        )
        apart = gx * mx
        apart += gy * my
        apart += dz * mz
        height = np.abs(apart)
        ends = follows & ~hides & (height < reach)
        kept = _kept(height, reach)
        # The sample's point on the centre's tangent plane against that plane.
        w = np.take(pix.plane[0], li) * sx
        w += np.take(pix.plane[1], li) * sy
        w += np.take(pix.plane[2], li)
        if surf.ortho:
            zh = np.where(np.isfinite(w), w, zp)
        else:
            zh = np.where(w > 0, np.float32(1.0) / w, zp)
        hx, hy = _offset(sx, sy, zh, centre, cx, cy, unit_x, unit_y, surf.ortho)
        hx -= gx
        hy -= gy
        side = mx * hx
        side += my * hy
        side += mz * ((zh - zp) - dz)
        # Above by more than float rounding on a shared plane.
        kept = np.where(side > _ABOVE * np.take(r, at), np.float32(1.0), kept)
        touching[at] = hides | ends
        share[at] = np.where(ends, kept, np.float32(0.0))
    return touching, share


def _kept(height, reach):
    """(n,) float32: the share of its light a sample keeps where the centre's surface ends
    on another object at ``height`` of it (both (n,) float32, scene units), for
    ``height < reach``."""
    lost = reach - height
    lost /= reach - _FOOT * reach
    np.minimum(lost, np.float32(1.0), out=lost)
    lost *= _LOSS
    return np.float32(1.0) - lost


def _facing(sx, sy, nx, ny, nz, cx, cy, unit_x, unit_y) -> np.ndarray:
    """|n·v| (float32) of normals ``n`` seen along the unit view ray v through the
    screen points (sx, sy) of a perspective camera: 1 head-on, 0 edge-on."""
    vx = (sx - cx) * unit_x
    vy = (sy - cy) * unit_y
    dot = vx * nx
    dot += vy * ny
    dot += nz
    norm = vx * vx
    norm += vy * vy
    norm += np.float32(1.0)
    return np.abs(dot) / np.sqrt(norm)


def _on_plane(touching, zq, area_q, qx, qy, zp, pix: Pixels, surf, local):
    """Depth and area element of the touching samples' points on the centre's tangent plane.

    The plane's depth along the sample's own ray (its continuous screen position;
    the centre's depth where the pixel has no plane) and the centre's area element,
    scaled by (depth ratio)² in perspective (the plane has the centre's normal).
    Returns copies of ``zq`` and ``area_q`` with the touching samples' values;
    ``local`` holds each sample's pixel (index into ``pix``).
    """
    at = np.flatnonzero(touching)
    li = np.take(local, at)
    zp = np.take(zp, at)
    w = np.take(pix.plane[0], li) * np.take(qx, at)
    w += np.take(pix.plane[1], li) * np.take(qy, at)
    w += np.take(pix.plane[2], li)
    area_p = np.take(surf.area, np.take(pix.idx, li))
    with np.errstate(divide="ignore", invalid="ignore"):
        if surf.ortho:
            zh = np.where(np.isfinite(w), w, zp)
            area_h = area_p
        else:
            zh = np.where(w > 0, np.float32(1.0) / w, zp)
            ratio = zh / zp
            area_h = area_p * ratio
            area_h *= ratio
    zq, area_q = zq.copy(), area_q.copy()
    zq[at] = zh
    area_q[at] = area_h
    return zq, area_q


def tangent_planes(surf, normal, x, y, depth) -> np.ndarray:
    """(P, 3) float32 ``(A, B, C)``: the depth of each pixel's tangent plane at image pixel (i, j).

    Perspective: ``1/z = A·i + B·j + C`` on the plane through the pixel's point with
    its normal (``A = n_x·w/D``, ``B = n_y·h/D``, ``C = (n_z − n_x·w·c_x − n_y·h·c_y)/D``,
    ``D = n·x_p``). Orthographic: ``z = A·i + B·j + C``. NaN where the plane
    contains the camera (the view axis): no sample passes the test there.
    The follow-surface rule accepts a sample within the depth tolerance of
    this plane as well as of the centre's depth.
    """
    wu, hu = surf.unit
    cx, cy = surf.centre
    n = np.asarray(normal, dtype=np.float64)
    z = np.asarray(depth, dtype=np.float64)
    out = np.zeros((z.size, 3))
    with np.errstate(divide="ignore", invalid="ignore"):
        if surf.ortho:
            ok = np.abs(n[:, 2]) > 1e-6
            inv = -1.0 / n[:, 2]
            out[:, 0] = n[:, 0] * wu * inv
            out[:, 1] = n[:, 1] * hu * inv
            out[:, 2] = z - out[:, 0] * x - out[:, 1] * y
        else:
            px, py = (x - cx) * wu * z, (y - cy) * hu * z
            dot = n[:, 0] * px + n[:, 1] * py + n[:, 2] * z
            ok = np.abs(dot) > 1e-6 * z
            inv = 1.0 / dot
            out[:, 0] = n[:, 0] * wu * inv
            out[:, 1] = n[:, 1] * hu * inv
            out[:, 2] = (n[:, 2] - n[:, 0] * wu * cx - n[:, 1] * hu * cy) * inv
    out[~ok] = np.nan
    return out.astype(np.float32)


def disk_frame(normal: np.ndarray) -> np.ndarray:
    """(P, 9) float32 ``(N, T, B)`` per pixel: Cycles' ``make_orthonormals`` of unit normals.

    ``T = normalize((1, 1, 1) × N)`` (``(−1, 1, 1) × N`` when the components of N
    are all equal), ``B = N × T``, in float32, in the order the compiled
    sampling pass computes them.
    """
    n = np.asarray(normal, dtype=np.float32)
    nx, ny, nz = n[:, 0], n[:, 1], n[:, 2]
    alike = (nx == ny) & (nx == nz)
    tx = nz - ny
    ty = np.where(alike, nx + nz, nx - nz)
    tz = np.where(alike, -ny - nx, ny - nx)
    inv = np.float32(1.0) / np.sqrt(tx * tx + ty * ty + tz * tz)
    tx, ty, tz = tx * inv, ty * inv, tz * inv
    out = np.empty((n.shape[0], 9), np.float32)
    out[:, 0], out[:, 1], out[:, 2] = nx, ny, nz
    out[:, 3], out[:, 4], out[:, 5] = tx, ty, tz
    out[:, 6] = ny * tz - nz * ty
    out[:, 7] = nz * tx - nx * tz
    out[:, 8] = nx * ty - ny * tx
    return out


def _disk_gain(dx, dy, dz, q, normal_cm, pix: Pixels, a: int, c, weighed) -> np.ndarray:
    """Cycles' disk kernel over the surface kernel, ``G = |Δ|·Σ_a m_a/ρ_a`` (module doc).

    Δ = (dx, dy, dz) the offset between the two surface points, axes a = N, T, B
    of the centre (picked with probability ½, ¼, ¼), ρ_a the offset's distance
    from the axis, clamped at half a pixel, m_a the power heuristic of
    ``pick_a·|a·N_q|`` with N_q the landing pixel's normal (``normal_cm``: (3, H·W),
    one row per component). 1 where ``weighed`` is false.
    """
    n = dx.size
    axes = [np.repeat(pix.frame[j, a : a + c.size], c) for j in range(9)]
    nq = [np.take(normal_cm[j], q, mode="clip") for j in range(3)]
    tmp = np.empty(n, np.float32)

    def dot(x, y, z, ax, ay, az):  # (x·ax + y·ay) + z·az, in float32
        out = x * ax
        out += np.multiply(y, ay, out=tmp)
        out += np.multiply(z, az, out=tmp)
        return out

    sq = []
    weight = []
    for axis, pick in ((0, 0.5), (1, 0.25), (2, 0.25)):
        ax, ay, az = axes[3 * axis : 3 * axis + 3]
        along = dot(dx, dy, dz, ax, ay, az)
        along *= along
        sq.append(along)
        w = dot(nq[0], nq[1], nq[2], ax, ay, az)
        np.abs(w, out=w)
        w *= np.float32(pick)
        w *= w
        weight.append(w)
    total = weight[0] + weight[1]
    total += weight[2]
    # G = Σ_a w_a·(|Δ|/ρ_a)/total from q_a = max(ρ_a², ρ_min²)/|Δ|² with two divisions
    # (the compiled pass's operations, in its order).
    s01 = sq[0] + sq[1]
    l2 = s01 + sq[2]
    lo2 = np.repeat(pix.rho_min[a : a + c.size], c)
    lo2 *= lo2
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        il2 = np.divide(np.float32(1.0), l2)
        qa = []
        for pair in (sq[1] + sq[2], sq[2] + sq[0], s01):
            np.maximum(pair, lo2, out=pair)
            pair *= il2
            qa.append(pair)
        q01 = qa[0] * qa[1]
        big = q01 * qa[2]
        big *= np.multiply(total, total, out=tmp)
        np.divide(np.float32(1.0), big, out=big)

        def term(prod, w):  # w·sqrt(prod·big), in place in prod
            prod *= big
            np.sqrt(prod, out=prod)
            prod *= w
            return prod

        g = term(np.multiply(qa[1], qa[2], out=il2), weight[0])
        g += term(np.multiply(qa[2], qa[0], out=tmp), weight[1])
        g += term(q01, weight[2])
    weighed = weighed & (total > 0)
    weighed &= l2 > 0
    return np.where(weighed, g, np.float32(1.0))


def _pdf_at(profile: Profile, r: np.ndarray, pix: Pixels, at: np.ndarray) -> np.ndarray:
    """(3, n) float32 density of every channel at r (n,), of the pixels ``at`` (indices
    into pix): :func:`_pdf` for a few samples of scattered pixels."""
    return _density(profile, r, np.take(pix.mat, at), pix, lambda rows: np.take(rows, at, axis=1))


def _pdf(profile: Profile, r: np.ndarray, mat: np.ndarray, pix: Pixels, a: int, c) -> np.ndarray:
    """(3, n) float32 density of every channel at r, times the per-pixel weight scale, of
    a batch's samples (pixels ``a``… with ``c`` samples each)."""
    return _density(
        profile, r, mat, pix, lambda rows: np.repeat(rows[:, a : a + c.size], c, axis=1)
    )


def _density(profile: Profile, r: np.ndarray, mat: np.ndarray, pix: Pixels, per_sample):
    """(3, n) float32 density of every channel at r (n,) of slots ``mat`` (n,), times the
    per-pixel weight scale; ``per_sample`` maps a (3, P) per-pixel array to the samples'
    (3, n) rows."""
    if type(profile) is BurleyProfile:
        return pdf_from_table(r, per_sample(pix.pscale), per_sample(pix.inv_d), profile._pcols)
    dens = profile.pdf_channels(r, mat)
    if profile.pixel_weight_scale:
        dens *= per_sample(pix.ws)
    return dens

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
screen, on another material (or object) or across a depth discontinuity fall
back to the centre ("follow surface", Jimenez et al. 2015) and so add nothing.

With a :class:`~cvsss.core.geometry.Surface` in the Geometry (SSSParams
``distance = "surface"``), channel c's weight becomes

    w_c = γ_c·p̂_c(r)/q(r) · R_c(d)/R_c(r) · J,

with d the distance between the two points on the depth-buffer surface and J
the area Jacobian of the screen → surface mapping (SPEC §11): the estimator
is then unbiased for ``B(p) + ∫ R_c(‖x_p − x_q‖)·(B(q) − B(p)) dA_q`` over the
visible surface beyond r0 — still exact for constant lighting, and equal to
the planar estimator on a fronto-parallel plane.

Cycles' kernel (``distance = "cycles"``, the default)
-----------------------------------------------------
Cycles' Christensen-Burley does not integrate R(‖x_p − x_q‖): it probes a
disk around p along one of three axes (the geometric normal N with
probability ½, two tangents T, B with ¼ each; ``make_orthonormals``), weighs a
hit by the radial pdf at the true distance over the radial pdf of the disk
radius, and combines the axes with the power heuristic of ``pick_a·|a·N_q|``
(``intern/cycles/kernel/integrator/subsurface_disk.h``). Its kernel over the
surface is therefore ``p(‖Δ‖)·Σ_a m_a/(2πρ_a)``, with ρ_a the distance of
Δ = x_q − x_p from axis a: R(‖Δ‖) times ``G = ‖Δ‖·Σ_a m_a/ρ_a``. G = 1 on a
plane and exceeds 1 on curved or folded surfaces, where Cycles renders
subsurface brighter than diffuse (measured: 1.07 on a sphere of radius 5d,
1.2 and more on cube faces and thin slabs). With depth-buffer normals (the
:class:`~cvsss.core.geometry.Surface`), ρ_a clamped at half a pixel and Δ
taken between the two pixels' own points, this estimator computes

    Î_c = γ_c·B_c(p) + (1/m)·Σ_k w_c·(G_k·B_c(q_k) − B_c(p)),

unbiased for ``∫_visible K_Cycles·B dA + B(p)·(γ_c − ∫_visible R dA)``: Cycles'
kernel over the visible surface and the centre's lighting for the share of
the profile that falls on surface the camera does not see. Against Cycles
ground truth it is closer than the surface kernel on every demo scene
(README *Against Cycles* has the figures); its samples are noisier (G
varies), and constant lighting is returned exactly only where G = 1.

Following the surface
---------------------
A sample falls back to the centre when it lands off screen, on another
material, or on a depth that differs by more than ``depth_slope·r`` both from
the centre's depth and — in the surface modes — from the centre's tangent
plane (through x_p with the depth-buffer normal, evaluated along the landing
pixel's view ray). The second test keeps the samples of steep surfaces (a
table top seen at 75°, whose depth changes by 3.7·r over a radius r) that a
fixed slope would reject, without admitting a surface behind.

Objects
-------
Cycles' disk probes hit the entry point's own object only: light never
scatters from one object into another, even of the same material (a marble
block on a marble table top). With the frame's Object Index pass
(``geom.objects``) a sample on another object falls back like one on another
material. One that lands on another object within ``contact·r`` of the
centre's tangent plane (the height ``|n·(x_q − x_p)|`` of its point above the
plane; the depth difference without normals) marks where the centre's surface
runs on under an object that rests on it — the table top beneath the block,
the block's foot on the table — and that surface is unlit: the sample counts
light 0 at its point of the tangent plane (the plane's depth along the
sample's ray, the centre's area element scaled by the squared depth ratio,
G = 1), weighed as an accepted sample. On a plane, this is exactly the
estimator over one surface whose part under the other object is dark
(tests/core/test_estimator.py). Without the pass every pixel counts as one
object and nothing changes.

Work is compacted: only pixels with m > 0 are visited, their samples are laid
out contiguously, processed in batches small enough to stay in the CPU's
cache, and summed back per pixel in sample order. Cost is proportional to
Σm, never to the maximum count.

What a sample costs
-------------------
Everything that depends only on the material slot and the sample's position
in the profile is read from tables built once per profile
(:mod:`core.profiles.burley`), not computed per sample: the radius (the
inverse CDF, indexed by √t, CDF error < 5e-7), the channel mixture's density
at that radius (the weights' denominator, from the same table position), and
the unit pdf at the surface distance. The direction is one of 4096 bin
centres read from :data:`core.sampling.qmc.DIRECTIONS`. The channel and
the tail value are an affine map of the R2 coordinate per pixel (``t = t_a +
t_b·u``). A sample is then integer hashing, a square root, a handful of
table reads, the gather of its texel and a division — no logarithm,
exponential or trigonometric call.

Two backends take the same samples (the ``sampling`` twin of
:mod:`core.backends.twins`): this module's NumPy batches, and a compiled loop per
pixel (:mod:`core.backends.numba.sampling`) for the Burley profile when numba imports.
They do the same float32 operations in the same order (no library calls on
either side), so they agree to float32 rounding — on the test frames to the
last bit.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..backends.select import threads
from ..backends.twins import compiled_module, compiled_side, numpy_side
from ..geometry import Geometry
from ..profiles.base import Profile
from ..profiles.burley import BurleyProfile, pdf_from_table
from ..sampling.qmc import DIRECTION_BITS, DIRECTIONS, pixel_hashes, r2_fixed

# The direction table's columns, contiguous: a strided column costs the sampling
# loop several times a contiguous one.
_DIR_X, _DIR_Y = (np.ascontiguousarray(col) for col in DIRECTIONS.T)


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
    chunk_samples: int = 1 << 16,
    variance: bool = False,
    backend: str = "numpy",
    disk: bool = False,
    hidden_light: float = 1.0,
    contact: float = 0.0,
) -> DistantEstimate:
    """Estimate Î for every SSS pixel with the given per-pixel sample counts.

    Parameters
    ----------
    geom : Geometry from :func:`core.geometry.geometry_of`
    lighting : (H, W, 3) float32, B (linear)
    depth : (H, W) float, planar depth, scene units
    profile : Profile (over the compact slots of ``geom``)
    counts : (P,) int, samples per SSS pixel (0 = direct only)
    frame, seed : int, select the per-pixel R2 offsets
    depth_slope : float, follow-surface tolerance (see SSSParams.depth_slope)
    chunk_samples : int, samples per NumPy batch: small enough that a batch's
        arrays stay in the CPU's caches (65536 samples ≈ 8 MB in all), large enough
        that NumPy's cost per call is small (32768 took 7 % longer at 640×360)
    variance : bool, also estimate the variance of Î's luminance from the samples
    backend : {"auto", "numpy", "numba"}, implementation (:mod:`core.backends.select`);
        numba runs the Burley profile, other profiles run on NumPy
    disk : bool, weigh with the kernel of Cycles' disk estimator instead of the
        profile at the surface distance (with ``geom.surface``; module doc)
    hidden_light : float in [0, 1], share of the centre's direct light (``geom.direct``)
        a sample counts with when it lands on the background or another material or
        object nearer than an occluder (the hidden surface; module doc); 1: the
        centre's light
    contact : float >= 0, with ``geom.objects``: a sample on another object within
        ``contact·r`` of the centre's tangent plane counts, unlit, as the centre's surface
        continuing under it (module doc, *Objects*); 0: no such samples

    Returns
    -------
    DistantEstimate
    """
    # The disk kernel lives on the depth-buffer surface (geometry_of(surface_distance=True)),
    # which a frame without SSS pixels does not have.
    disk = disk and geom.surface is not None
    counts = np.asarray(counts, dtype=np.int64)
    active = np.flatnonzero((counts > 0) & (geom.gamma_sum > 0))
    # Every SSS pixel takes samples in most frames: no gather of the counts then.
    every = active.size == geom.size
    act_counts = counts if every else counts[active]
    total = int(act_counts.sum())
    if total == 0:
        distant = geom.gamma * geom.at(lighting).astype(np.float64)
        return DistantEstimate(distant, 0, 0, np.zeros(geom.size) if variance else None)
    # Visiting every pixel, the sampling step starts each row at γ·B(p) itself (the
    # compiled side in its pass over the pixels: NumPy's γ·B took 4.8 ms at 1920×1080).
    start = every and lighting.dtype == np.float32
    if start:
        distant = np.empty((geom.size, 3))
    else:
        distant = geom.gamma * geom.at(lighting).astype(np.float64)
    counted = total if geom.core is None else int(act_counts[geom.core[active]].sum())
    var_sums, fallback = distant_sums(
        geom, profile, counts, active, lighting, depth, frame=frame, seed=seed,
        depth_slope=depth_slope, variance=variance, disk=disk, hidden_light=hidden_light,
        contact=contact, chunk_samples=chunk_samples, distant=distant, start=start,
        samples=total, backend=backend,
    )  # fmt: skip
    spread = None
    if variance:
        spread = estimate_variance(var_sums, active, counts, geom.gamma_sum, backend=backend)
    return DistantEstimate(distant, counted, int(fallback), spread)


@numpy_side("estimate_variance")
def estimate_variance(
    var_sums: np.ndarray,
    active: np.ndarray,
    counts: np.ndarray,
    gamma_sum: np.ndarray,
    backend: str = "numpy",
) -> np.ndarray:
    """(P,) float64: the variance of each pixel's estimate Î (its luminance, linear²)
    from its samples' sums: the sample variance over m, 0 without samples (or without
    distant energy), inf with one sample.

    Parameters
    ----------
    var_sums : (A, 2) float64, Σy and Σy² of the active pixels' samples' luminance
    active : (A,) int64, the active pixels (counts > 0 and γ > 0), ascending
    counts : (P,) int64, samples per pixel; gamma_sum : (P,) float64, Σ_c γ_c
    backend : one of core.params.BACKENDS; where it resolves to numba, one compiled
        pass with the same float64 operations (the same values)
    """
    var_sum = np.zeros((counts.shape[0], 2))
    var_sum[active] = var_sums
    m_all = counts.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        s2 = (var_sum[:, 1] - var_sum[:, 0] ** 2 / m_all) / (m_all - 1.0)
        spread = np.where(m_all > 1, np.maximum(s2, 0.0) / m_all, np.inf)
    spread[(m_all == 0) | (gamma_sum == 0)] = 0.0
    return spread


@compiled_side("estimate_variance")
def _estimate_variance_compiled(var_sums, active, counts, gamma_sum, backend="numpy"):
    """:func:`estimate_variance` in one compiled pass (NumPy's takes a dozen)."""
    return compiled_module("sampling").estimate_variance(
        np.ascontiguousarray(var_sums, np.float64),
        np.ascontiguousarray(active, np.int64),
        np.ascontiguousarray(counts, np.int64),
        np.ascontiguousarray(gamma_sum, np.float64),
    )


@numpy_side("sampling")
def distant_sums(
    geom: Geometry,
    profile: Profile,
    counts: np.ndarray,
    active: np.ndarray,
    lighting: np.ndarray,
    depth: np.ndarray,
    *,
    frame: int,
    seed: int,
    depth_slope: float,
    variance: bool,
    disk: bool,
    hidden_light: float,
    contact: float,
    chunk_samples: int,
    distant: np.ndarray,
    start: bool,
    samples: int,
    backend: str = "numpy",
) -> tuple[np.ndarray | None, int]:
    """Add each ``active`` pixel's mean weighted difference to its row of ``distant``.

    Parameters
    ----------
    geom, profile, lighting, depth, frame, seed, depth_slope, variance, disk,
    hidden_light, contact, chunk_samples : as :func:`estimate_distant`
    counts : (G,) int64, samples per SSS pixel; active : (P,) int64, the pixels of
        ``geom`` that take samples (counts > 0 and Σγ > 0)
    distant : (G, 3) float64, written in place: γ·B(p) on entry (with ``start``, every
        pixel of ``geom`` active: uninitialised, and set here to γ·B(p) first)
    samples : int, Σ counts[active] (the compiled side picks its build with it)
    backend : one of core.params.BACKENDS (the compiled side: :func:`_distant_sums_compiled`)

    Returns
    -------
    var_sums : (P, 2) float64 Σy and Σy² of the samples' luminance (None without
        ``variance``); fallback : int, samples that fell back (of a crop's core pixels)
    """
    if start:
        distant[...] = geom.gamma * geom.at(lighting).astype(np.float64)
    pix = active_pixels(geom, profile, counts, active, frame, seed)
    sums, var_sums, fallback = _numpy_sums(
        geom,
        pix,
        lighting,
        depth,
        profile,
        depth_slope,
        variance,
        chunk_samples,
        disk,
        hidden_light,
        contact,
    )
    if active.size == geom.size:
        distant += sums / counts[:, None]
    else:
        distant[active] += sums / counts[active][:, None]
    return var_sums, fallback


def _numpy_sums(
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
        ix = fx.astype(np.intp)
        iy = fy.astype(np.intp)
        if ox:
            ix -= ox
        if oy:
            iy -= oy
        # Negative coordinates wrap to huge unsigned values: one test per axis.
        inside = ix.view(np.uintp) < w
        inside &= iy.view(np.uintp) < h
        centre_idx = np.repeat(pix.idx[a:b], c)
        q = iy * w
        q += ix
        q = np.where(inside, q, centre_idx)
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
        # object close to the centre's tangent plane is the centre's surface running
        # under it where the two touch: unlit (module doc, *Objects*).
        touching = None
        if objects is not None:
            other = np.take(objects, q, mode="clip") != np.repeat(np.take(objects, pix.idx[a:b]), c)
            other &= inside
            ok &= ~other
            if touch is not None:
                touching = _touching(other, qx, qy, zq, zp, centre, r, touch, pix, surf, local)
                if not touching.any():
                    touching = None
        # Hidden surface: a rejected sample on the image that landed on the background or
        # another material or object (not in front of the centre, an occluder, nor
        # touching it) counts with the centre's light less (1 − β) of its direct part, at
        # its planar weight.
        fill = None
        if fill_value is not None:
            fill = inside & ~ok
            if touching is not None:
                fill &= ~touching
            fill &= ~(zp - zq > np.float32(0.1) * zp)
            if fill.any():
                # The filled samples' pixels (indices into pix) and (3, n_fill) their
                # −(1 − β)·B_direct(p), times a weight below.
                fill_pix = np.take(local, np.flatnonzero(fill))
                fill_light = np.take(fill_value, fill_pix, axis=1)
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
            diff[:, touching] = np.float32(0.0)
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


def _touching(other, qx, qy, zq, zp, centre, r, touch, pix: Pixels, surf, local):
    """(n,) bool: samples on ``other`` objects within ``touch·r`` of the centre's tangent plane.

    The height of the landing point above the plane through x_p with the centre's
    normal, ``|n·(x_q − x_p)|``; without normals (planar weights) the plane faces
    the camera and the height is the depth difference. Only the ``other`` samples
    are computed; ``local`` holds each sample's pixel (index into ``pix``).
    """
    at = np.flatnonzero(other)
    touching = np.zeros(other.size, bool)
    if at.size == 0:
        return touching
    zq = np.take(zq, at)
    with np.errstate(invalid="ignore", over="ignore"):
        dz = zq - np.take(zp, at)
        if pix.frame is None:
            h = np.abs(dz)
        else:
            unit_x, unit_y = (np.float32(v) for v in surf.unit)
            cx, cy = (np.float32(v) for v in surf.centre)
            centre = np.take(centre[0], at), np.take(centre[1], at)
            dx, dy = _offset(
                np.take(qx, at), np.take(qy, at), zq, centre, cx, cy, unit_x, unit_y, surf.ortho
            )
            li = np.take(local, at)
            h = dx * np.take(pix.frame[0], li)
            h += dy * np.take(pix.frame[1], li)
            h += dz * np.take(pix.frame[2], li)
            h = np.abs(h)
        touching[at] = h <= touch * np.take(r, at)
    return touching


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
    kernel computes them.
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
    # (the compiled kernel's operations, in its order).
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


#: Names of the compiled sampling step's values kept in a Geometry's memos (core.geometry.Geometry.memo).
#: The texels are a function of the Geometry and its passes except for the lighting, so
#: a Geometry reused for the next frame of a still scene (core.geometry.GeometryCache)
#: rewrites only the lighting of its last call's texels, in place (at 1920×1080 a fresh
#: 66 MB texel array took 16.4 ms per frame, inside the frame). With them, the order
#: that visits all of the Geometry's pixels. Kept for reused Geometries only
#: (Geometry.reused): the texels are 32 bytes per pixel of the frame (118 MB at
#: 2560×1440), held between frames.
_TEXELS, _ORDER = "numba_texels", "numba_tile_order"


def _plain_burley(geom, profile, *_args, **_kwargs) -> bool:
    """The compiled sampling step reads Burley's tables (a subclass may sample otherwise)."""
    return type(profile) is BurleyProfile


@compiled_side("sampling", supports=_plain_burley)
def _distant_sums_compiled(
    geom: Geometry,
    profile: BurleyProfile,
    counts: np.ndarray,
    active: np.ndarray,
    lighting: np.ndarray,
    depth: np.ndarray,
    *,
    frame: int,
    seed: int,
    depth_slope: float,
    variance: bool,
    disk: bool,
    hidden_light: float,
    contact: float,
    chunk_samples: int,
    distant: np.ndarray,
    start: bool,
    samples: int,
    backend: str = "numpy",
) -> tuple[np.ndarray | None, int]:
    """:func:`distant_sums` with the compiled loop per pixel
    (:func:`core.backends.numba.sampling.pixel_sums`).

    Adds each active pixel's mean weighted difference to its row of ``distant``
    ((G, 3) float64, in place; see pixel_sums): in the kernel, where a pixel's
    sums are at hand, instead of dividing and scattering (P, 3) sums afterwards
    (1.2 ms at 640×360, 5.7 ms through NumPy's fancy indexing when some pixels
    take no samples, against ~60 ms for the samples). With ``start`` (every
    pixel of ``geom`` active) it sets each row to γ·B(p) plus that mean, so
    ``distant`` may come uninitialised. ``samples`` (Σ counts[active]) picks the build
    (:func:`core.backends.numba.sampling.build_for`). Returns the (P, 2) luminance sums
    (None without ``variance``) and the fall-back count.
    """
    k = compiled_module("sampling")
    if start and active.size != geom.size:
        raise ValueError("start needs every pixel of the Geometry active")
    f32 = np.float32
    h, w = geom.shape
    full_h, full_w = geom.image_shape
    oy, ox = geom.origin
    surf = geom.surface
    if surf is None:
        mode, unit, centre, area = k.PLANAR, (1.0, 1.0), (0.0, 0.0), np.zeros(1, f32)
    else:
        mode = k.ORTHO if surf.ortho else k.PERSPECTIVE
        unit, centre, area = surf.unit, surf.centre, surf.area
    light = np.ascontiguousarray(lighting.reshape(-1, 3), dtype=f32)
    # The texels of the Geometry's last call, relit (see _TEXELS); taken out of
    # its memos while this call uses them.
    held = geom.memos.pop(_TEXELS, None)
    if held is None:
        normal = surf.normal if surf is not None else np.zeros((1, 3), f32)
        keys, inv_k = k.surface_keys(geom.slots, geom.objects)
        texel = k.texels(
            light,
            np.ascontiguousarray(depth.reshape(-1), dtype=f32),
            np.ascontiguousarray(area, dtype=f32),
            normal,
            keys,
            surf is not None,
        )
    else:
        texel, inv_k = held
        k.relight(light, texel)
    if active.size == geom.size and geom.reused:  # every SSS pixel, as in most frames
        order = geom.memo(_ORDER, lambda: k.tile_order(geom.x, geom.y, full_w))
    else:
        order = k.tile_order(geom.x, geom.y, full_w, active)
    first = active[0]
    var, fb = k.build_for(samples, active.size)(
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
        threads(),
    )
    if geom.reused:
        geom.memos[_TEXELS] = (texel, inv_k)
    return (var if variance else None), int(fb.sum())

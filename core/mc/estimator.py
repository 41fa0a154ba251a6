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
the area Jacobian of the screen → surface mapping (docs/explanation/design.md §5.5): the estimator
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
A sample is rejected when it lands off screen, on another material, or on a
depth that differs by more than ``depth_slope·r`` both from the centre's
depth and — in the surface modes — from the centre's tangent plane (through
x_p with the depth-buffer normal, evaluated along the landing pixel's view
ray). The second test keeps the samples of steep surfaces (a table top seen
at 75°, whose depth changes by 3.7·r over a radius r) that a fixed slope
would reject, without admitting a surface behind. A rejected sample falls
back to the centre (it adds nothing), unless it stands for hidden surface
(*Hidden surface* below).

Objects
-------
Cycles' disk probes hit the entry point's own object only: light never
scatters from one object into another, even of the same material (a marble
block on a marble table top). With the frame's Object Index pass
(``geom.objects``) a sample on another object is rejected like one on another
material. One that lands on another object stands for the centre's surface
where it meets that object when the other object continues the centre's
surface in depth (the depth test a sample of the centre's own object passes)
and lies on the visible side of the centre's tangent plane
(``n_p·(x_q − x_p) ≥ 0``). Two cases:

- the other object faces the camera :data:`~core.params.CONTACT_FACING` times
  more squarely than the centre (``|n·v|``: a block seen head-on standing on a
  table top seen at a slant): it hides the centre's surface, which runs on
  under it unlit;
- otherwise the centre's surface ends on it (a slab's front face standing on
  a floor seen at a slant). Where the centre lies at a height
  ``h = |n_q·(x_q' − x_p)|`` of the other object's tangent plane (through the
  landing pixel's own point x_q', its centre at its depth) below
  ``reach = contact·d`` (d the slot's scattering length,
  :meth:`~core.profiles.base.Profile.contact_scale`), the sample keeps
  ``1 − CONTACT_LOSS·min((reach − h) / (reach − CONTACT_FOOT·reach), 1)`` of
  its light (:data:`~core.params.CONTACT_LOSS`, :data:`~core.params.CONTACT_FOOT`),
  all of it where its point on the centre's tangent plane lies above the other
  object's plane (the landing pixel holds part of the centre's surface there).

Either way the sample counts at its point of the tangent plane (the plane's
depth along the sample's ray, the centre's area element scaled by the squared
depth ratio, G = 1), weighed as an accepted sample, with its share of the light
of its mirror image (where the slot reads mirror images and the opposite pixel
is on the centre's surface, *Hidden surface*) or else of the centre: none
where hidden. Without normals (planar weights) both planes face the camera and
h is the depth difference. On a plane, the hidden case is exactly the
estimator over one surface whose part under the other object is dark, and the
ending case at the foot the one over a surface continued at that share of the
light (tests/core/mc/test_estimator.py). Without the pass every pixel counts
as one object and nothing changes.

Hidden surface
--------------
Cycles integrates the whole object within the profile's reach, also where the
camera does not see it: behind a silhouette, or behind another object in
front. A rejected sample that lands on the image — on the background, on
another material or object, or on the centre's surface beyond its depth
tolerance — stands for that hidden surface unless it touches the centre's
surface (*Objects*) or lies in front of the centre by more than a tenth of
its depth (an occluder). With ``mirror`` it reads the pixel opposite it
through the centre, ``2·p − q``, when that pixel is on the crop, of the
centre's material and object, and within ``depth_slope·r`` of the centre's
depth (the tangent-plane test is not applied to it): the surface on the far
side of a silhouette is taken to continue as the visible side the sample's
mirror image lands on, as an image filter reflects at a border. The rim of a candle lit from above then loses its light to the
dim wall below it, as Cycles' does, where reading the centre's own light kept
it; under light that is even across the silhouette both read the same. Where
the mirrored pixel is not on the surface either, the sample counts the centre's
light less ``(1 − β)`` of its direct part (``hidden_light``, β = 1: the
centre's light, nothing added). Both weigh the sample at its planar weight
(the profile at the sampled radius), as for a plane facing the camera.

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
from ..params import CONTACT_FACING
from ..profiles.base import Profile
from ..profiles.burley import BurleyProfile
from ..sampling.qmc import DIRECTIONS
from .samples import active_pixels, batch_sums


def mirror_slots(profile, hidden_mirror: bool) -> np.ndarray | None:
    """(K,) bool: the slots of ``profile`` whose hidden-surface samples read the mirror
    image (``hidden_mirror``), or None when none does.

    Christensen-Burley slots only. Cycles' disk probes read the light on the hidden
    side, which the mirror stands in for; its random walk leaves through that side and
    loses what goes out there, so on the demo scenes switched to Random Walk the mirror
    moved their frames away from Cycles' (docs/explanation/accuracy.md §2.1).
    """
    if not hidden_mirror:
        return None
    slots = np.ones(profile.n_slots, np.bool_)
    if profile.energy is not None:
        slots &= ~profile.energy.modelled()
    return slots if slots.any() else None


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
    hidden_mirror: bool = False,
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
        a hidden-surface sample counts with where its mirror image does not apply
        (module doc, *Hidden surface*); 1: the centre's light
    contact : float >= 0, multiple of the slot's d, with ``geom.objects``: a sample on
        another object that continues the centre's surface counts as the centre's
        surface meeting it: unlit where that object hides the surface, keeping a share
        of its light where the surface ends on it within ``contact·d`` (module doc,
        *Objects*); 0: no such samples
    hidden_mirror : bool, a hidden-surface sample reads the pixel opposite it through
        the centre where that pixel is on the centre's surface (module doc, *Hidden
        surface*); before ``hidden_light``; Christensen-Burley slots only
        (:func:`mirror_slots`)

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
    hidden_mirror = mirror_slots(profile, hidden_mirror)
    var_sums, fallback = distant_sums(
        geom, profile, counts, active, lighting, depth, frame=frame, seed=seed,
        depth_slope=depth_slope, variance=variance, disk=disk, hidden_light=hidden_light,
        contact=contact, hidden_mirror=hidden_mirror, chunk_samples=chunk_samples,
        distant=distant, start=start, samples=total, backend=backend,
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
    hidden_mirror: np.ndarray | None,
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
    hidden_mirror : (K,) bool or None, the slots that read the mirror image
        (:func:`mirror_slots`)
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
    sums, var_sums, fallback = batch_sums(
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
        hidden_mirror,
    )
    if active.size == geom.size:
        distant += sums / counts[:, None]
    else:
        distant[active] += sums / counts[active][:, None]
    return var_sums, fallback


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
    hidden_mirror: np.ndarray | None,
    chunk_samples: int,
    distant: np.ndarray,
    start: bool,
    samples: int,
    backend: str = "numpy",
) -> tuple[np.ndarray | None, int]:
    """:func:`distant_sums` with the compiled loop per pixel
    (:func:`core.backends.numba.sampling.pixel_sums`).

    Adds each active pixel's mean weighted difference to its row of ``distant``
    ((G, 3) float64, in place; see pixel_sums): in the pass, where a pixel's
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
        np.zeros(profile.n_slots, np.bool_) if hidden_mirror is None else hidden_mirror,
        geom.direct if geom.direct is not None else np.zeros((geom.size, 3), f32),
        geom.objects is not None,
        inv_k,
        f32(contact),
        f32(CONTACT_FACING),
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

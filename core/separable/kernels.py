"""Separable subsurface scattering (Jimenez et al. 2015), the real-time baseline.

The 2D diffusion kernel of each material slot is approximated by a sum of J
separable terms ``Σ_j v_j(y)·h_j(x)`` and applied as a horizontal then a
vertical pass of n taps per term (2J one-dimensional passes):

``pre_integrated`` (S.5–S.6)
    ``A_p = a_p(x)a_p(y)/‖R‖₁`` with ``a_p`` the profile integrated along one
    axis; exact for additively separable lighting (axis-aligned or linear
    edges). J = 1.
``svd1`` … ``svd4`` (S.2–S.4)
    The rank-k truncated SVD of the discrete 2D profile (the best rank-k
    approximation in the Frobenius norm), rescaled so the kernel sums to
    ‖R‖₁ (energy). J = k.
``gaussians`` (S.1)
    A sum of N 2D Gaussians fitted to the discrete profile (weights summing
    to ‖R‖₁, as d'Eon et al.). J = N.
``artist``
    The production kernel of the reference implementation: one 1D kernel,
    the near/far Gaussian profile evaluated along the axis and normalised,
    blended with the identity by the strength c in each pass. Its parameters
    are the slot's artist-friendly profile, or fitted to the slot's profile
    (:func:`cvsss.core.profiles.artist.from_radial`). J = 1.

Kernels are built in scene units, per slot and channel, from the pixel's
material profile (Burley, dipole or artist, :mod:`cvsss.core.profiles.radial`):
the discrete 2D profile lives on a per-channel grid of ``grid``² cells out to
the channel's truncation radius, the decomposition is computed there, and the
1D term functions are integrated over the taps' cells. The taps are shared by
the channels (RGB weights per tap, as on the GPU), spaced like the reference
implementation (``o_i = R·sign(t)|t|^2`` for t uniform in [−1, 1], R the
slot's largest truncation radius) and weighted by the area of their cell.

Runtime, per SSS pixel: each tap's scene-unit offset becomes pixels with the
pixel's footprint (:meth:`cvsss.core.camera.Camera.footprint` at its depth),
the source is read at the nearest pixel (``filter="nearest"``, default: like
the Monte Carlo estimator, B is constant per pixel, so sub-pixel taps read
the centre) or between the two nearest pixels (``"linear"``, what GPU bilinear
fetches do; it also spreads the sub-pixel part of the kernel over the
neighbours), and each read follows the surface: a pixel of another material or off screen
contributes the centre value, and so does a same-material pixel across a depth
discontinuity. ``follow="slope"`` (default) uses the Monte Carlo estimator's
bilateral rule, a read at screen distance r (scene units) falls back when
``|Δz| > depth_slope·r`` (SSSParams.depth_slope), so that separable and Monte
Carlo results differ only by their kernels; ``follow="exponential"`` is the
supplementary's depth correction (S.E), blending the read towards the centre
by ``1 − exp(−Δz²/(2τ))`` with τ the largest channel variance of the slot's
projected 1D kernel, which also shrinks the kernel on steep surfaces. With ``jitter``
the taps within ``jitter_threshold`` (33 %, as in the supplementary's Figure
S.7; Blender EEVEE's Jitter Threshold likewise randomises the samples below a
share of the radius, default 0.3) of the kernel range — the heavy inner
taps whose discrete steps show as bands — are moved per pixel, pass and frame
to a uniformly random position inside their own cell (pcg3d hash; fixed seed
⇒ identical reruns): the staircase a step edge produces becomes, on average,
the cell-filtered kernel, and the bands turn into unstructured noise. The
sparse outer taps stay put (coherent reads, low weights). Results are
clamped to >= 0 (SVD terms of rank ≥ 2 have negative lobes).

The approximation error of each kernel (:func:`kernel_errors`) is the relative
Frobenius (L2) norm ``‖R − A‖/‖R‖`` on the discrete 2D profile, per channel
(the supplementary's Figure S.3 in numbers).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ..mc.estimator import Geometry, prepare
from ..params import ParameterError
from ..profiles.artist import ArtistProfile, from_radial
from ..profiles.base import Profile
from ..profiles.factory import MixedProfile
from ..profiles.radial import (
    GRID,
    RadialModel,
    discretize,
    fit_gaussians,
    gaussian_cells,
    radial_model,
)
from ..sampling.sequence import pcg3d

KERNELS = ("pre_integrated", "svd1", "svd2", "svd3", "svd4", "gaussians", "artist")
TAP_COUNTS = (11, 17, 25)
#: Taps within this share of the kernel range are jittered (Jimenez et al.'s 33 %).
JITTER_THRESHOLD = 0.33
#: Follow-surface rules: the estimator's bilateral test, or the supplementary's exponential.
FOLLOW_RULES = ("slope", "exponential")
#: Tap reads: the nearest pixel (as the Monte Carlo estimator), or linear between two.
FILTERS = ("nearest", "linear")

_INV_2_32 = 1.0 / 2**32


@dataclass(frozen=True)
class SeparableParams:
    """Parameters of separable SSS.

    Attributes
    ----------
    kernel : str, one of :data:`KERNELS`
    taps : int, taps per 1D pass, one of :data:`TAP_COUNTS`
    jitter : bool, jitter the inner taps per pixel against banding
    jitter_threshold : float in [0, 1], share of the kernel range within
        which taps are jittered (1: all taps)
    gaussians : int in [1, 6], N of the ``gaussians`` kernel (2N passes)
    grid : int, odd in [33, 513], cells per side of the discrete 2D profile
    follow : {"slope", "exponential"}, follow-surface rule (see module doc)
    filter : {"nearest", "linear"}, how a tap reads the image (see module doc)
    """

    kernel: str = "pre_integrated"
    taps: int = 17
    jitter: bool = False
    jitter_threshold: float = JITTER_THRESHOLD
    gaussians: int = 4
    grid: int = GRID
    follow: str = "slope"
    filter: str = "nearest"

    def __post_init__(self) -> None:
        if self.kernel not in KERNELS:
            raise ParameterError(f"kernel must be one of {', '.join(KERNELS)}, got {self.kernel!r}")
        if self.taps not in TAP_COUNTS:
            raise ParameterError(f"taps must be one of {TAP_COUNTS}, got {self.taps!r}")
        if not isinstance(self.jitter, bool):
            raise ParameterError(f"jitter must be a bool, got {self.jitter!r}")
        t = self.jitter_threshold
        if isinstance(t, bool) or not isinstance(t, int | float) or not 0.0 <= t <= 1.0:
            raise ParameterError(f"jitter_threshold must be in [0, 1], got {t!r}")
        g = self.gaussians
        if isinstance(g, bool) or not isinstance(g, int) or not 1 <= g <= 6:
            raise ParameterError(f"gaussians must be an integer in [1, 6], got {g!r}")
        m = self.grid
        if isinstance(m, bool) or not isinstance(m, int) or not 33 <= m <= 513 or m % 2 == 0:
            raise ParameterError(f"grid must be an odd integer in [33, 513], got {m!r}")
        if self.follow not in FOLLOW_RULES:
            raise ParameterError(
                f"follow must be one of {', '.join(FOLLOW_RULES)}, got {self.follow!r}"
            )
        if self.filter not in FILTERS:
            raise ParameterError(f"filter must be one of {', '.join(FILTERS)}, got {self.filter!r}")

    @property
    def terms(self) -> int:
        """J, separable terms (the method runs 2J one-dimensional passes)."""
        if self.kernel.startswith("svd"):
            return int(self.kernel[3:])
        return self.gaussians if self.kernel == "gaussians" else 1


# -- decompositions of a discrete 2D kernel ----------------------------------------------------
def pre_integrated_terms(kern: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """``[(a_p, a_p/‖K‖₁)]`` with ``a_p = Σ_y K`` (S.5–S.6); terms are (h over x, v over y)."""
    a = kern.sum(axis=0)
    total = float(kern.sum())
    return [(a, a / total if total else a)]


def svd_terms(
    kern: np.ndarray, rank: int, conserve: bool = True
) -> list[tuple[np.ndarray, np.ndarray]]:
    """Rank-k truncated SVD ``Σ σ_j u_j v_jᵀ`` as (h_j = v_j, v_j = σ_j u_j) terms (S.2–S.4).

    With ``conserve`` the terms are rescaled so the approximation sums to
    ‖K‖₁ (the supplementary's energy-conserving variant); without, this is
    the Eckart–Young optimum.
    """
    u, s, vt = np.linalg.svd(kern)
    terms = []
    for j in range(min(rank, s.size)):
        h, v = vt[j].copy(), s[j] * u[:, j]
        if h.sum() < 0:
            h, v = -h, -v
        terms.append((h, v))
    if conserve:
        total = sum(float(h.sum() * v.sum()) for h, v in terms)
        if abs(total) > 1e-12:
            terms = [(h, v * (kern.sum() / total)) for h, v in terms]
    return terms


def gaussian_terms(kern: np.ndarray, delta: float, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """N separable Gaussians fitted to the kernel (S.1), as (g_i, w_i·g_i) terms."""
    m = kern.shape[0]
    x = (np.arange(m) - m // 2) * delta
    w, v = fit_gaussians(kern, delta, n)
    g = gaussian_cells(x, delta, v)
    return [(g[i], w[i] * g[i]) for i in range(n)]


def artist_terms(
    params: dict, channel: int, x: np.ndarray, delta: float
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The production kernel: ``k = (1 − c)δ + c·a`` in both passes (see module doc)."""
    c = float(params["strength"][channel])
    vn = float(params["near"][channel]) ** 2
    vf = float(params["far"][channel]) ** 2
    w = float(params["weight"][channel])
    g = gaussian_cells(x, delta, np.array([vn, vf]))
    a = w * g[0] / math.sqrt(vn) + (1.0 - w) * g[1] / math.sqrt(vf)
    a = a / a.sum() if a.sum() > 0 else a
    k = c * a
    k[x.size // 2] += 1.0 - c
    return [(k, k)]


def approximation(terms: list[tuple[np.ndarray, np.ndarray]], m: int) -> np.ndarray:
    """The 2D kernel ``Σ_j v_j ⊗ h_j`` (rows y, columns x) of separable terms."""
    out = np.zeros((m, m))
    for h, v in terms:
        out += np.outer(v, h)
    return out


def relative_error(kern: np.ndarray, terms) -> float:
    """``‖K − A‖_F / ‖K‖_F``."""
    return float(np.linalg.norm(kern - approximation(terms, kern.shape[0])) / np.linalg.norm(kern))


# -- per-slot kernels ---------------------------------------------------------------------------
@dataclass
class SlotKernel:
    """Separable kernel of one material slot, ready for the passes.

    Attributes
    ----------
    offsets : (n,) float64, tap offsets, scene units (ascending, 0 in the middle)
    cells : (n, 2) float64, each tap's cell [a, b], scene units
    h, v : (J, n, 3) float32, horizontal and vertical tap weights per term
    tau : float, depth-correction variance, scene units²
    error : (3,) float, relative L2 error of the 2D approximation per channel
    range : float, kernel range R, scene units
    """

    offsets: np.ndarray
    cells: np.ndarray
    h: np.ndarray
    v: np.ndarray
    tau: float
    error: np.ndarray
    range: float


def tap_offsets(n: int, radius: float, exponent: float = 2.0) -> tuple[np.ndarray, np.ndarray]:
    """Offsets ``R·sign(t)|t|^e`` (t uniform in [−1, 1]) and their area cells.

    >>> [round(v, 2) for v in tap_offsets(5, 1.0)[0]]
    [-1.0, -0.25, 0.0, 0.25, 1.0]
    """
    t = np.linspace(-1.0, 1.0, n)
    o = radius * np.sign(t) * np.abs(t) ** exponent
    mid = 0.5 * (o[1:] + o[:-1])
    a = np.concatenate([[o[0] - (o[1] - o[0]) / 2], mid])
    b = np.concatenate([mid, [o[-1] + (o[-1] - o[-2]) / 2]])
    return o, np.stack([a, b], axis=1)


def _to_taps(vec: np.ndarray, delta: float, cells: np.ndarray) -> np.ndarray:
    """Integrate a fine-grid vector (cell integrals) over the tap cells.

    The centre grid cell (where the kernel peaks) goes to the centre tap whole.
    """
    m = vec.size
    h = m // 2
    n = cells.shape[0]
    out = np.zeros(n)
    if delta <= 0:
        out[n // 2] = vec[h]
        return out
    rest = vec.copy()
    rest[h] = 0.0
    edges = (np.arange(m + 1) - h - 0.5) * delta
    cum = np.concatenate([[0.0], np.cumsum(rest)])
    out = np.interp(cells[:, 1], edges, cum) - np.interp(cells[:, 0], edges, cum)
    out[n // 2] += vec[h]
    return out


def _artist_parameters(profile: Profile, slot: int, model: RadialModel, grid: int) -> dict:
    sub = profile.profiles[profile.owner[slot]] if isinstance(profile, MixedProfile) else profile
    if isinstance(sub, ArtistProfile):
        return {k: getattr(sub, k)[slot] for k in ("strength", "near", "far", "weight")}
    return from_radial(model, grid)


def slot_terms(
    model: RadialModel, params: SeparableParams, channel: int, artist: dict | None = None
) -> tuple[np.ndarray, float, list]:
    """(K, δ, terms) of one channel: its discrete 2D profile and decomposition."""
    kern, delta = discretize(model, channel, params.grid)
    m = kern.shape[0]
    x = (np.arange(m) - m // 2) * delta
    if delta <= 0:  # no scattering in this channel: the identity
        e = np.zeros(m)
        e[m // 2] = 1.0
        return kern, delta, [(e, e)]
    kind = params.kernel
    if kind == "pre_integrated":
        terms = pre_integrated_terms(kern)
    elif kind.startswith("svd"):
        terms = svd_terms(kern, int(kind[3:]))
    elif kind == "gaussians":
        terms = gaussian_terms(kern, delta, params.gaussians)
    else:
        terms = artist_terms(artist, channel, x, delta)
    return kern, delta, terms


def build_slot_kernel(profile: Profile, slot: int, params: SeparableParams) -> SlotKernel:
    """The :class:`SlotKernel` of one slot of ``profile``."""
    model = radial_model(profile, slot)
    radius = float(np.max(model.rmax))
    offsets, cells = tap_offsets(params.taps, radius)
    n, j = params.taps, params.terms
    h = np.zeros((j, n, 3), np.float32)
    v = np.zeros((j, n, 3), np.float32)
    error = np.zeros(3)
    tau = 0.0
    artist = (
        _artist_parameters(profile, slot, model, params.grid) if params.kernel == "artist" else None
    )
    for c in range(3):
        kern, delta, terms = slot_terms(model, params, c, artist)
        error[c] = relative_error(kern, terms)
        if delta > 0:
            x = (np.arange(kern.shape[0]) - kern.shape[0] // 2) * delta
            tau = max(tau, float(np.sum(x * x * kern.sum(axis=0))))
        for t, (hv, vv) in enumerate(terms):
            h[t, :, c] = _to_taps(hv, delta, cells)
            v[t, :, c] = _to_taps(vv, delta, cells)
    return SlotKernel(offsets, cells, h, v, max(tau, 1e-30), error, radius)


def build_kernels(profile: Profile, params: SeparableParams) -> dict[int, SlotKernel]:
    """Kernels of every scattering slot of ``profile``."""
    return {
        int(s): build_slot_kernel(profile, int(s), params)
        for s in np.flatnonzero(profile.scatters())
    }


def kernel_errors(
    profile: Profile,
    slot: int,
    kernels=KERNELS,
    taps: int = 17,
    gaussians: int = 4,
    grid: int = GRID,
) -> dict[str, np.ndarray]:
    """Relative L2 error per channel of each kernel of one slot (Figure S.3 in numbers)."""
    return {
        k: build_slot_kernel(
            profile, slot, SeparableParams(kernel=k, taps=taps, gaussians=gaussians, grid=grid)
        ).error
        for k in kernels
    }


def svd_optimum_errors(
    profile: Profile, slot: int, ranks=(1, 2, 3, 4), grid: int = GRID
) -> dict[int, np.ndarray]:
    """Relative L2 error per channel of the rank-k SVD *without* energy rescaling.

    This is the Eckart–Young optimum (``sqrt(Σ_{i>k} σ_i²)/‖R‖``); the kernels
    applied at run time are rescaled to conserve energy, which costs some L2
    accuracy for peaked profiles.
    """
    model = radial_model(profile, slot)
    out = {k: np.zeros(3) for k in ranks}
    for c in range(3):
        kern, delta = discretize(model, c, grid)
        if delta <= 0:
            continue
        s = np.linalg.svd(kern, compute_uv=False)
        for k in ranks:
            out[k][c] = math.sqrt(float(np.sum(s[k:] ** 2))) / float(np.linalg.norm(kern))
    return out


# -- the passes -----------------------------------------------------------------------------------
@dataclass
class _Tables:
    """Per-slot kernel tables (K = n_slots, n taps, J terms)."""

    offsets: np.ndarray  # (K, n) scene units
    width: np.ndarray  # (K, n) cell widths where jittered, else 0
    h: np.ndarray  # (K, n, 3J) float32, index term·3 + channel
    v: np.ndarray  # (K, n, 3J) float32
    inv2tau: np.ndarray  # (K,) 1/(2τ)


def _stack(kernels: dict[int, SlotKernel], n_slots: int, params: SeparableParams) -> _Tables:
    n, j = params.taps, params.terms
    off = np.zeros((n_slots, n))
    width = np.zeros((n_slots, n))
    h = np.zeros((n_slots, n, 3 * j), np.float32)
    v = np.zeros((n_slots, n, 3 * j), np.float32)
    inv2tau = np.zeros(n_slots)
    for s, k in kernels.items():
        off[s] = k.offsets
        if params.jitter:
            near = np.abs(k.offsets) <= params.jitter_threshold * k.range * (1.0 + 1e-12)
            near[n // 2] = False
            width[s] = np.where(near, k.cells[:, 1] - k.cells[:, 0], 0.0)
        h[s] = k.h.transpose(1, 0, 2).reshape(n, 3 * j)
        v[s] = k.v.transpose(1, 0, 2).reshape(n, 3 * j)
        inv2tau[s] = 0.5 / k.tau
    return _Tables(off, width, h, v, inv2tau)


@dataclass
class _Pixels:
    """SSS pixels sorted by slot, so per-slot constants apply to contiguous runs."""

    order: np.ndarray  # (P,) position in the Geometry of each sorted pixel
    runs: list  # [(slot, start, stop)]
    lengths: np.ndarray  # (R,) run lengths
    slots: np.ndarray  # (R,) run slots
    index: np.ndarray  # (P,) flat pixel index
    x: np.ndarray
    y: np.ndarray
    mat: np.ndarray  # (P,) int32
    z: np.ndarray  # (P,) float32 depth
    inv_fw: np.ndarray  # (P,) float32 pixels per scene unit
    inv_fh: np.ndarray


def _pixels(geom: Geometry) -> _Pixels:
    order = np.argsort(geom.mat, kind="stable")
    mat = geom.mat[order]
    slots, starts, lengths = np.unique(mat, return_index=True, return_counts=True)
    runs = [(int(s), int(a), int(a + n)) for s, a, n in zip(slots, starts, lengths)]
    return _Pixels(
        order,
        runs,
        lengths,
        slots,
        geom.index[order],
        geom.x[order],
        geom.y[order],
        mat,
        geom.depth[order].astype(np.float32),
        (1.0 / geom.fw[order]).astype(np.float32),
        (1.0 / geom.fh[order]).astype(np.float32),
    )


def _one_pass(
    src: np.ndarray,
    px: _Pixels,
    shape: tuple[int, int],
    depth_flat: np.ndarray,
    mat_flat: np.ndarray,
    tab: _Tables,
    weights: np.ndarray,
    axis: int,
    jitter_key: int | None,
    depth_slope: float | None,
    linear: bool = False,
) -> tuple[np.ndarray, int]:
    """One 1D pass over the SSS pixels.

    Parameters
    ----------
    src : (C, H·W) float32, channel-major source image
    px : sorted SSS pixels
    depth_flat : (H·W,) float32 depth; mat_flat : (H·W,) material slots
    weights : (K, n, 3J) float32 tap weights; C divides 3J (the horizontal pass
        reads the 3 lighting channels and feeds all J terms)
    axis : 0 horizontal (x), 1 vertical (y)
    jitter_key : per pass and frame hash key, or None (no jitter)
    depth_slope : bilateral tolerance (follow "slope"), or None (follow "exponential")
    linear : read between the two nearest pixels (else the nearest pixel)

    Returns
    -------
    out : (3J, P) float32, ``Σ_i w_i·sample_i`` per term and channel, sorted order
    fallback : reads with zero weight: other material, off screen, or a depth
        difference that removes them entirely
    """
    h, w = shape
    c_in = src.shape[0]
    c_out = weights.shape[2]
    reps = c_out // c_in
    p_count = px.index.size
    n = tab.offsets.shape[1]
    # A read is q = base + clip(p)·stride; a p outside [0, size) fails the inside test.
    if axis == 0:
        coord, base, stride, size, scale = px.x, px.y * w, 1, w, px.inv_fw
    else:
        coord, base, stride, size, scale = px.y, px.x, w, h, px.inv_fh
    coord_i = coord.astype(np.intp)
    coord = coord.astype(np.float32)
    base = base.astype(np.intp)
    neg_inv2tau = np.repeat((-tab.inv2tau[px.slots]).astype(np.float32), px.lengths)
    centre = np.take(src, px.index, axis=1)
    slot_depth = {s: np.where(mat_flat == s, depth_flat, np.float32(np.inf)) for s, _, _ in px.runs}
    out = np.zeros((reps, c_in, p_count), np.float32)
    fallback = 0

    def accumulate(i: int, val: np.ndarray) -> None:
        for s, a, b in px.runs:
            wi = weights[s, i].reshape(reps, c_in, 1)
            out[:, :, a:b] += wi * val[None, :, a:b]

    for i in range(n):
        if i == n // 2:
            accumulate(i, centre)
            continue
        pos = np.repeat(tab.offsets[px.slots, i].astype(np.float32), px.lengths)
        if jitter_key is not None:
            jw = tab.width[px.slots, i]
            if np.any(jw > 0):
                hx, _, _ = pcg3d(px.x, px.y, np.int64(jitter_key) * 67 + i)
                jit = (hx * np.float32(_INV_2_32)).astype(np.float32)
                jit -= np.float32(0.5)
                jit *= np.repeat(jw.astype(np.float32), px.lengths)
                pos += jit
        pos *= scale
        pos += coord
        if linear:
            p0f = np.floor(pos)
            f = pos - p0f
            p0 = p0f.astype(np.intp)
            reads = ((p0, 1.0 - f), (p0 + 1, f))
        else:
            reads = ((np.rint(pos).astype(np.intp), None),)
        val = np.zeros_like(centre)
        for p, a in reads:
            pc = np.clip(p, 0, size - 1)
            q = pc * stride if stride != 1 else pc + base
            if stride != 1:
                q += base
            # Depth of the read where it has the run's material, +inf elsewhere:
            # the weight exp(−Δz²/2τ) is then 0 for other materials.
            wz = np.empty(p_count, np.float32)
            for s, ra, rb in px.runs:
                np.take(slot_depth[s], q[ra:rb], out=wz[ra:rb])
            wz -= px.z
            if depth_slope is None:
                wz *= wz
                wz *= neg_inv2tau
                with np.errstate(invalid="ignore", over="ignore"):
                    np.exp(wz, out=wz)
            else:
                dist = np.abs(p - coord_i)
                with np.errstate(invalid="ignore"):
                    wz = (np.abs(wz) * scale <= np.float32(depth_slope) * dist).astype(np.float32)
            np.copyto(wz, 0.0, where=p != pc)
            fallback += p_count - int(np.count_nonzero(wz))
            if a is not None:
                wz *= a
            d = np.take(src, q, axis=1)
            d -= centre
            d *= wz
            val += d
        val += centre
        accumulate(i, val)
    return out.reshape(c_out, p_count), fallback


def apply(
    frame,
    profile: Profile,
    params: SeparableParams,
    kernels: dict[int, SlotKernel] | None = None,
    *,
    seed: int = 0,
    depth_slope: float = 2.0,
    geom: Geometry | None = None,
) -> tuple[Geometry, np.ndarray, dict]:
    """Separable SSS of one frame.

    Parameters
    ----------
    frame : core.frame.Frame
    profile : Profile of the frame's materials
    params : SeparableParams
    kernels : per-slot kernels (built if None; pass them to reuse across frames)
    seed : int, jitter stream (with the frame number)
    depth_slope : float, bilateral tolerance of ``follow="slope"`` (SSSParams.depth_slope)
    geom : Geometry from :func:`cvsss.core.mc.estimator.prepare`, optional

    Returns
    -------
    geom : Geometry of the SSS pixels
    shaded : (P, 3) float64, L per SSS pixel (linear, >= 0)
    stats : dict with ``pass_ms`` (both passes), ``reads``, ``fallback``
    """
    if kernels is None:
        kernels = build_kernels(profile, params)
    if geom is None:
        geom = prepare(frame.depth, frame.material, frame.camera, profile)
    if geom.size == 0:
        return geom, np.zeros((0, 3)), {"pass_ms": 0.0, "reads": 0, "fallback": 0}
    j = params.terms
    tab = _stack(kernels, profile.n_slots, params)
    px = _pixels(geom)
    hgt, wid = geom.shape
    light = np.ascontiguousarray(frame.lighting.reshape(-1, 3).T, dtype=np.float32)
    depth_flat = frame.depth.reshape(-1).astype(np.float32)
    mat_flat = frame.material.reshape(-1)
    key = None
    if params.jitter:
        key = ((int(frame.number) ^ int(seed)) & 0xFFFFFFF) * 2
    t0 = time.perf_counter()
    slope = depth_slope if params.follow == "slope" else None
    linear = params.filter == "linear"
    first, fb1 = _one_pass(
        light, px, geom.shape, depth_flat, mat_flat, tab, tab.h, 0, key, slope, linear
    )
    inter = np.zeros((3 * j, hgt * wid), np.float32)
    inter[:, px.index] = first
    second, fb2 = _one_pass(
        inter,
        px,
        geom.shape,
        depth_flat,
        mat_flat,
        tab,
        tab.v,
        1,
        None if key is None else key + 1,
        slope,
        linear,
    )
    pass_ms = (time.perf_counter() - t0) * 1e3
    shaded = np.empty((geom.size, 3))
    shaded[px.order] = second.reshape(j, 3, -1).sum(axis=0, dtype=np.float64).T
    big = float(np.finfo(np.float32).max)
    shaded = np.clip(np.nan_to_num(shaded, nan=0.0, posinf=big), 0.0, big)
    reads = 2 * (2 if linear else 1) * (params.taps - 1) * geom.size
    return geom, shaded, {"pass_ms": pass_ms, "reads": reads, "fallback": fb1 + fb2}


class SeparableProcessor:
    """Frame-by-frame separable SSS with the FrameResult of the other methods.

    Parameters
    ----------
    sss : SSSParams (seed, ε_u for the reported distant share)
    params : SeparableParams
    profile_for : callable Frame -> Profile (cached by the caller)
    method : str, name written in the results
    """

    def __init__(
        self,
        sss,
        params: SeparableParams,
        profile_for: Callable[[object], Profile],
        method: str = "separable",
    ):
        self.sss = sss
        self.params = params
        self.profile_for = profile_for
        self.method = method
        self._kernels: tuple[Profile, dict] | None = None

    def kernels(self, profile: Profile) -> dict[int, SlotKernel]:
        if self._kernels is None or self._kernels[0] is not profile:
            self._kernels = (profile, build_kernels(profile, self.params))
        return self._kernels[1]

    def process(self, frame):
        from ..mc.processor import FrameResult

        t_start = time.perf_counter()
        profile = self.profile_for(frame)
        kernels = self.kernels(profile)
        geom, shaded, stats = apply(
            frame,
            profile,
            self.params,
            kernels,
            seed=self.sss.seed,
            depth_slope=self.sss.depth_slope,
        )
        b = frame.lighting.reshape(-1, 3)[geom.index].astype(np.float64)
        big = float(np.finfo(np.float32).max)
        albedo = frame.albedo.reshape(-1, 3)[geom.index]
        composite = frame.combined.copy()
        flat = composite.reshape(-1, 3)
        flat[geom.index] = np.clip(flat[geom.index] + albedo * (shaded - b), 0.0, big)
        sss = frame.lighting.copy()
        sss.reshape(-1, 3)[geom.index] = shaded
        n = geom.size
        counts = np.full(n, self.params.taps, np.int32)
        return FrameResult(
            number=frame.number,
            method=self.method,
            sss=sss,
            composite=np.maximum(composite, 0.0),
            counts=geom.to_image(counts, 0, np.int32),
            alpha=geom.to_image(np.zeros(n)),
            gamma=geom.to_image(geom.gamma),
            variance=geom.to_image(np.zeros(n)),
            valid_history=geom.to_image(np.zeros(n, bool), False, bool),
            mask=geom.mask(),
            spp=float(self.params.taps) if n else 0.0,
            samples=int(stats["reads"]),
            pass_ms=stats["pass_ms"],
            update_ms=0.0,
            total_ms=(time.perf_counter() - t_start) * 1e3,
            distant_share=float(np.mean(geom.gamma_max >= self.sss.eps_u)) if n else 0.0,
            fallback_share=stats["fallback"] / stats["reads"] if stats["reads"] else 0.0,
            repaired=frame.repaired,
        )

"""Separable kernels (Jimenez et al. 2015): the 2D profile as a sum of separable terms.

The 2D diffusion kernel of each material slot is approximated by a sum of J
separable terms ``Σ_j v_j(y)·h_j(x)``, applied by :mod:`.apply` as a
horizontal then a vertical pass of n taps per term (2J one-dimensional
passes):

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

The approximation error of each kernel (:func:`kernel_errors`) is the relative
Frobenius (L2) norm ``‖R − A‖/‖R‖`` on the discrete 2D profile, per channel
(the supplementary's Figure S.3 in numbers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..params import KERNELS, PROFILE_GRID, SeparableParams
from ..profiles.artist import ArtistProfile, from_radial
from ..profiles.base import Profile
from ..profiles.factory import MixedProfile
from ..profiles.radial import (
    RadialModel,
    discretize,
    fit_gaussians,
    gaussian_cells,
    radial_model,
)

GRID = PROFILE_GRID


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

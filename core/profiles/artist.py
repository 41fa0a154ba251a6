"""Artist-friendly separable-SSS profile (Jimenez et al. 2015) in the unified model.

Table 2 of the paper realises the artist-friendly dipole as

    γ = c (the artist's *strength*),  R_F = R̃_d = R_{d,ms} − R_{G0},

i.e. the multiple-scattering dipole profile approximated by a sum of
Gaussians (d'Eon et al.) minus its narrowest Gaussian G0, which is folded into
the un-blurred part. What is left is the artist model's pair of Gaussians::

    R̃(r) ∝ w·G(r; σ_near²) + (1 − w)·G(r; σ_far²),   G(r; v) = e^{−r²/(2v)}/(2πv),

with per-channel strength c, standard deviations σ_near, σ_far (scene units)
and near weight w. The shaded value is ``L = (1 − c)·B + c·E_R̃[B]`` where,
in the unified estimator, ``E_R̃`` is taken over the distant region
``[r0, r_max]`` with R̃ renormalised there — so the weight scale γ/mass
depends on the pixel (``pixel_weight_scale = True``). ``r_max`` keeps 99.7 %
of the far Gaussian (``3.41·σ_far``). γ is c while R̃ has support beyond r0
and 0 once r0 ≥ r_max (all scattering inside the pixel).

:func:`from_radial` derives the parameters from any radial profile: three
Gaussians are fitted to its discrete 2D kernel, G0 is the narrowest,
``c = 1 − w0`` (the energy outside G0), and near/far are the other two.

Consistency with the dipole (P Eq. 17): the artist result equals the dipole
one iff ``c = γ_d·(B − L_s(R_d)) / (B − L_s(R̃))`` (:func:`eq17_strength`);
``L_s`` is the normalised distant average, which :func:`distant_mean`
evaluates by quadrature for any profile of this package.

Sampling is exact: a component is chosen with its share of the distant mass,
then the truncated Rayleigh radius is inverted in closed form,
``r² = r0² − 2v·ln(1 − u(1 − e^{−(r_max² − r0²)/(2v)}))``. u-space stores
``lo = r0`` and ``hi = P(near | distant)``.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable

import numpy as np

from .base import Profile, Region
from .radial import GRID, RadialModel, discretize, fit_gaussians, gaussian_radial_cdf, radial_model

#: r_max = KEEP_SIGMAS·σ_far keeps 99.7 % of the far Gaussian: sqrt(−2 ln 0.003).
KEEP_SIGMAS = math.sqrt(-2.0 * math.log(0.003))


def _as_table(name: str, value, k: int, lo: float, hi: float, open_lo: bool = False) -> np.ndarray:
    a = np.array(value, dtype=np.float64)
    if a.ndim == 1 and a.shape == (3,):
        a = np.broadcast_to(a, (k, 3)).copy()
    if a.shape != (k, 3):
        raise ValueError(f"{name} must have shape (K, 3) or (3,), got {a.shape}")
    bad = ~np.isfinite(a) | (a > hi) | ((a <= lo) if open_lo else (a < lo))
    if np.any(bad[1:]):
        left = "(" if open_lo else "["
        raise ValueError(f"{name} must be in {left}{lo:g}, {hi:g}], got {a[1:][bad[1:]].tolist()}")
    return a


class ArtistProfile(Profile):
    """Artist-friendly profile per material slot.

    Parameters
    ----------
    strength : (K, 3) or (3,) float in [0, 1]
        c, share of the lighting that scatters (γ).
    near, far : (K, 3) or (3,) float > 0
        Standard deviations of the near and far Gaussians, scene units.
    weight : (K, 3) or (3,) float in [0, 1]
        w, weight of the near Gaussian.

    Row 0 (no SSS) and rows with zero strength do not scatter.
    """

    name = "artist"
    pixel_weight_scale = True

    def __init__(self, strength, near, far, weight):
        k = np.asarray(strength, dtype=np.float64).reshape(-1, 3).shape[0]
        self.strength = _as_table("strength", strength, k, 0.0, 1.0)
        self.near = _as_table("near", near, k, 0.0, math.inf, open_lo=True)
        self.far = _as_table("far", far, k, 0.0, math.inf, open_lo=True)
        self.weight = _as_table("weight", weight, k, 0.0, 1.0)
        self.strength[0] = 0.0
        self.near[0] = self.far[0] = 1.0
        self.weight[0] = 1.0
        vn, vf = self.near**2, self.far**2
        self._vn, self._vf = vn, vf
        self._rmax = KEEP_SIGMAS * np.maximum(self.near, self.far)
        w = self.weight
        self._total = w * gaussian_radial_cdf(self._rmax, vn) + (1.0 - w) * gaussian_radial_cdf(
            self._rmax, vf
        )
        # Channel-major (3, K) float32 tables for the per-sample pdf.
        cm = lambda a: np.ascontiguousarray(a.T, dtype=np.float32)  # noqa: E731
        self._a_near = cm(w / vn / self._total)
        self._a_far = cm((1.0 - w) / vf / self._total)
        self._h_near = cm(-0.5 / vn)
        self._h_far = cm(-0.5 / vf)
        self._rmax32 = cm(self._rmax)
        self._vn_flat = vn.astype(np.float32).reshape(-1)
        self._vf_flat = vf.astype(np.float32).reshape(-1)
        self._rmax_flat = self._rmax.astype(np.float32).reshape(-1)

    @property
    def n_slots(self) -> int:
        return self.strength.shape[0]

    def scatters(self):
        return self.strength.max(axis=1) > 0

    def chromatic(self):
        diff = lambda a: np.any(a[:, 1:] != a[:, :1], axis=1)  # noqa: E731
        return self.scatters() & (diff(self.near) | diff(self.far) | diff(self.weight))

    # -- radial description (tests, separable kernels, Eq. 17) -------------------------
    def support(self, slot: int) -> np.ndarray:
        return self._rmax[int(slot)].copy()

    def direct_weight(self, slot: int) -> np.ndarray:
        """(3,) 1 − c: the un-scattered share, a Dirac peak of the 2D kernel."""
        return 1.0 - self.strength[int(slot)]

    def radial_pdf(self, r, slot):
        s = int(slot)
        r = np.asarray(r, dtype=np.float64).reshape(1, -1)
        vn, vf = self._vn[s][:, None], self._vf[s][:, None]
        w = self.weight[s][:, None]
        with np.errstate(under="ignore"):
            p = w * r / vn * np.exp(-r * r / (2 * vn)) + (1 - w) * r / vf * np.exp(
                -r * r / (2 * vf)
            )
        return np.where(r <= self._rmax[s][:, None], p / self._total[s][:, None], 0.0)

    def radial_cdf(self, r, slot):
        s = int(slot)
        r = np.minimum(np.asarray(r, dtype=np.float64).reshape(1, -1), self._rmax[s][:, None])
        w = self.weight[s][:, None]
        c = w * gaussian_radial_cdf(r, self._vn[s][:, None]) + (1 - w) * gaussian_radial_cdf(
            r, self._vf[s][:, None]
        )
        return np.minimum(c / self._total[s][:, None], 1.0)

    def radial_model(self, slot: int) -> RadialModel:
        return RadialModel(
            pdf=lambda r: self.radial_pdf(r, slot),
            cdf=lambda r: self.radial_cdf(r, slot),
            rmax=self.support(slot),
            delta=self.direct_weight(slot),
        )

    # -- estimator interface ----------------------------------------------------------------
    def region(self, r0, mat, backend="numpy"):
        r0 = np.asarray(r0, dtype=np.float64)[:, None]
        rmax = self._rmax[mat]
        vn, vf, w = self._vn[mat], self._vf[mat], self.weight[mat]
        r0c = np.minimum(r0, rmax)
        # Masses beyond r0 of the two components (un-normalised), in a stable form.
        with np.errstate(under="ignore"):
            m_near = w * (np.exp(-(r0c**2) / (2 * vn)) - np.exp(-(rmax**2) / (2 * vn)))
            m_far = (1.0 - w) * (np.exp(-(r0c**2) / (2 * vf)) - np.exp(-(rmax**2) / (2 * vf)))
        mass = np.maximum(m_near + m_far, 0.0)
        inside = (r0 < rmax) & (mass > 0)
        gamma = np.where(inside, self.strength[mat], 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(inside & (gamma > 0), gamma * self._total[mat] / mass, 0.0)
            share = np.where(mass > 0, m_near / mass, 0.0)
        return Region(
            gamma=gamma,
            weight_scale=scale,
            lo=np.broadcast_to(r0c, gamma.shape).copy(),
            hi=np.clip(share, 0.0, 1.0),
        )

    def sample(self, u, lo, hi, mat, channel):
        u = np.asarray(u, dtype=np.float64)
        lo = np.asarray(lo, dtype=np.float64)
        hi = np.asarray(hi, dtype=np.float64)
        flat = np.asarray(mat, dtype=np.intp) * 3 + channel
        near = u < hi
        with np.errstate(divide="ignore", invalid="ignore"):
            uu = np.where(near, u / hi, (u - hi) / (1.0 - hi))
        uu = np.clip(np.nan_to_num(uu), 0.0, 1.0 - 1e-12)
        v = np.where(near, np.take(self._vn_flat, flat), np.take(self._vf_flat, flat)).astype(
            np.float64
        )
        rmax = np.take(self._rmax_flat, flat).astype(np.float64)
        span = -np.expm1(-(rmax * rmax - lo * lo) / (2.0 * v))
        r2 = lo * lo - 2.0 * v * np.log1p(-uu * span)
        return np.clip(np.sqrt(np.maximum(r2, 0.0)), lo, rmax).astype(np.float32)

    def pdf(self, r, mat):
        return self.pdf_channels(r, mat).T

    def pdf_channels(self, r, mat):
        r = np.asarray(r, dtype=np.float32)
        r2 = r * r
        with np.errstate(under="ignore"):
            a = np.exp(np.take(self._h_near, mat, axis=1) * r2)
            a *= np.take(self._a_near, mat, axis=1)
            b = np.exp(np.take(self._h_far, mat, axis=1) * r2)
            b *= np.take(self._a_far, mat, axis=1)
        a += b
        a *= r
        np.copyto(a, 0.0, where=r > np.take(self._rmax32, mat, axis=1))
        return a

    def describe(self, slot):
        s = int(slot)
        return {
            "profile": self.name,
            "slot": s,
            "strength": self.strength[s].tolist(),
            "near": self.near[s].tolist(),
            "far": self.far[s].tolist(),
            "weight": self.weight[s].tolist(),
        }


# -- derivation from a physical profile -----------------------------------------------------
def from_radial(model: RadialModel, m: int = GRID) -> dict[str, np.ndarray]:
    """Artist parameters (strength, near, far, weight; each (3,)) fitted to a radial model.

    Three Gaussians are fitted to each channel's discrete 2D kernel
    (:func:`~cvsss.core.profiles.radial.fit_gaussians`); the narrowest (G0)
    is dropped: ``c = 1 − w0``, near/far are the other two (standard
    deviations, scene units), ``w = w_near/(w_near + w_far)``.
    """
    out = {k: np.zeros(3) for k in ("strength", "near", "far", "weight")}
    for c in range(3):
        if model.rmax[c] <= 0:
            out["near"][c] = out["far"][c] = 1.0
            out["weight"][c] = 1.0
            continue
        kern, delta = discretize(model, c, m)
        w, v = fit_gaussians(kern, delta, 3)
        w = w / w.sum()
        rest = w[1] + w[2]
        out["strength"][c] = min(max(rest, 0.0), 1.0)
        out["near"][c] = math.sqrt(v[1])
        out["far"][c] = math.sqrt(v[2])
        out["weight"][c] = w[1] / rest if rest > 0 else 1.0
    return out


# -- consistency with the dipole (P Eq. 17) ---------------------------------------------------
def distant_mean(
    profile: Profile,
    slot: int,
    r0: float,
    lighting: Callable[[np.ndarray, np.ndarray], np.ndarray],
    n_r: int = 400,
    n_theta: int = 64,
) -> tuple[np.ndarray, np.ndarray]:
    """γ and the normalised distant average ``L_s = E_{p̂}[B]`` of one slot, by quadrature.

    Parameters
    ----------
    profile : a profile of core.profiles (uses its region and pdf)
    slot : int
    r0 : float, direct-scattering radius, scene units
    lighting : callable (dx, dy) -> (N, 3), B at offsets from the pixel (scene units)
    n_r, n_theta : quadrature nodes in radius (Gauss–Legendre on each of 8
        log-spaced segments) and angle (midpoint)

    Returns
    -------
    gamma : (3,), L_s : (3,) (B at the centre where γ = 0)
    """
    mat = np.array([slot], dtype=np.int32)
    region = profile.region(np.array([r0], dtype=np.float64), mat)
    gamma = region.gamma[0]
    rmax = float(np.max(radial_model(profile, slot).rmax))
    if gamma.max() <= 0 or rmax <= r0:
        return gamma, lighting(np.zeros(1), np.zeros(1))[0]
    edges = np.geomspace(max(r0, 1e-12), rmax, 9)
    xg, wg = np.polynomial.legendre.leggauss(max(n_r // 8, 4))
    rs, ws = [], []
    for a, b in itertools.pairwise(edges):
        rs.append(0.5 * (b - a) * xg + 0.5 * (a + b))
        ws.append(0.5 * (b - a) * wg)
    r = np.concatenate(rs)
    wr = np.concatenate(ws)
    theta = (np.arange(n_theta) + 0.5) * (2 * math.pi / n_theta)
    rr = np.repeat(r, n_theta)
    tt = np.tile(theta, r.size)
    b = lighting(rr * np.cos(tt), rr * np.sin(tt)).reshape(r.size, n_theta, 3).mean(axis=1)
    p = profile.pdf(r.astype(np.float32), np.full(r.size, slot, np.int32)).astype(np.float64)
    mass = (p * wr[:, None]).sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        ls = np.where(
            mass > 0,
            (p * wr[:, None] * b).sum(axis=0) / mass,
            lighting(np.zeros(1), np.zeros(1))[0],
        )
    return gamma, ls


def eq17_strength(
    gamma_d: np.ndarray, b: np.ndarray, ls_dipole: np.ndarray, ls_artist: np.ndarray
) -> np.ndarray:
    """The strength c that makes the artist result equal the dipole one (P Eq. 17).

    ``c = γ_d·(B − L_s(R_d)) / (B − L_s(R̃))``; NaN where the artist's distant
    average equals B (then every c is consistent iff the dipole's does too).
    """
    num = np.asarray(gamma_d) * (np.asarray(b) - np.asarray(ls_dipole))
    den = np.asarray(b) - np.asarray(ls_artist)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(np.abs(den) > 1e-12 * np.maximum(np.abs(b), 1e-300), num / den, np.nan)

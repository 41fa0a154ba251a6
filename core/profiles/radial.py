"""Radial profiles as discrete 2D kernels, and sums of Gaussians fitted to them.

Shared by the artist-friendly model (its near/far Gaussians are fitted to a
profile) and separable SSS (its kernels approximate the discrete 2D profile).

A *radial model* of one material slot is what every profile exposes through
:func:`radial_model`: per channel the normalised radial pdf ``p_c(r)`` (this is
``2πr·R_c(r)``), its CDF, the truncation radius and the weight of a Dirac
peak at r = 0 (the artist model's ``1 − c``, zero for physical profiles).

The discrete 2D kernel of a channel (:func:`discretize`) lives on an m×m grid
of square cells of side δ centred on the origin, whose outer edge is the
channel's truncation radius. Each cell holds the kernel's integral over it
(supersampled; the centre cell, where Burley's ``R ∝ 1/r`` is singular, from
the CDF of the disc of the same area), then the kernel is normalised to sum 1.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from . import burley
from .base import Profile

#: Cells per side of the discrete 2D kernel (odd).
GRID = 129


@dataclass
class RadialModel:
    """Radial description of one slot (scene units).

    Attributes
    ----------
    pdf : callable r (N,) -> (3, N), normalised radial pdf (1/scene unit)
    cdf : callable r (N,) -> (3, N), its CDF
    rmax : (3,) float, truncation radius per channel
    delta : (3,) float, weight of a Dirac peak at r = 0 (the rest is ``1 − delta``)
    """

    pdf: Callable[[np.ndarray], np.ndarray]
    cdf: Callable[[np.ndarray], np.ndarray]
    rmax: np.ndarray
    delta: np.ndarray


def radial_model(profile: Profile, slot: int) -> RadialModel:
    """The :class:`RadialModel` of ``slot`` of any profile of core.profiles."""
    slot = int(slot)
    if isinstance(profile, burley.BurleyProfile):
        d = profile.d[slot]
        total = 1.0 - profile._tail_max
        rmax = d * profile.truncate

        def pdf(r, d=d, rmax=rmax, total=total):
            r = np.asarray(r, dtype=np.float64).reshape(1, -1)
            return np.where(r <= rmax[:, None], burley.pdf(r, d[:, None]) / total, 0.0)

        def cdf(r, d=d, rmax=rmax, total=total):
            r = np.asarray(r, dtype=np.float64).reshape(1, -1)
            return np.minimum(burley.cdf(np.minimum(r, rmax[:, None]), d[:, None]) / total, 1.0)

        return RadialModel(pdf, cdf, rmax.astype(np.float64), np.zeros(3))
    if hasattr(profile, "radial_model"):
        return profile.radial_model(slot)
    return RadialModel(
        pdf=lambda r: profile.radial_pdf(r, slot),
        cdf=lambda r: profile.radial_cdf(r, slot),
        rmax=np.asarray(profile.support(slot), dtype=np.float64),
        delta=np.asarray(getattr(profile, "direct_weight", lambda s: np.zeros(3))(slot)),
    )


# -- discrete 2D kernels -------------------------------------------------------------
def cell_centres(rmax: float, m: int = GRID) -> tuple[np.ndarray, float]:
    """Cell centres (m,) and cell side δ of the grid whose outer edge is ``rmax``."""
    h = m // 2
    delta = rmax / (h + 0.5)
    return (np.arange(m) - h) * delta, delta


def discretize(model: RadialModel, channel: int, m: int = GRID) -> tuple[np.ndarray, float]:
    """Discrete 2D kernel (m, m) of one channel, summing to 1, and its cell side δ.

    Includes the Dirac weight ``delta`` of the model in the centre cell.
    """
    if m % 2 == 0 or m < 3:
        raise ValueError(f"m must be odd and >= 3, got {m}")
    rmax = float(model.rmax[channel])
    h = m // 2
    k = np.zeros((m, m))
    if rmax <= 0:
        k[h, h] = 1.0
        return k, 0.0
    x, delta = cell_centres(rmax, m)
    xs = x[h:]

    def cells(n_cells: int, sub: int) -> np.ndarray:
        off = ((np.arange(sub) + 0.5) / sub - 0.5) * delta
        p = (xs[:n_cells, None] + off[None, :]).reshape(-1)
        rr = np.hypot(p[:, None], p[None, :])
        dens = model.pdf(rr.reshape(-1))[channel].reshape(rr.shape)
        dens /= 2.0 * math.pi * np.maximum(rr, 1e-300)
        return dens.reshape(n_cells, sub, n_cells, sub).sum(axis=(1, 3)) * (delta / sub) ** 2

    # One quadrant (axes included) suffices: the kernel is radially symmetric.
    q = cells(h + 1, 4)
    near = min(3, h + 1)
    q[:near, :near] = cells(near, 32)
    q[0, 0] = float(model.cdf(np.array([delta / math.sqrt(math.pi)]))[channel, 0])
    full = np.zeros((m, m))
    full[h:, h:] = q
    full[h:, : h + 1] = q[:, ::-1]
    full[: h + 1, h:] = q[::-1, :]
    full[: h + 1, : h + 1] = q[::-1, ::-1]
    total = full.sum()
    full = full / total if total > 0 else full
    dw = float(model.delta[channel])
    full *= 1.0 - dw
    full[h, h] += dw
    return full, delta


# -- Gaussians ---------------------------------------------------------------------------
def erf(x: np.ndarray) -> np.ndarray:
    """Error function, Abramowitz & Stegun 7.1.26 (absolute error < 1.5e-7).

    >>> round(float(erf(np.array(0.5))), 6)
    0.5205
    """
    x = np.asarray(x, dtype=np.float64)
    s = np.sign(x)
    a = np.abs(x)
    t = 1.0 / (1.0 + 0.3275911 * a)
    y = t * (
        0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429)))
    )
    with np.errstate(under="ignore"):
        return s * (1.0 - y * np.exp(-a * a))


def gaussian_cells(x: np.ndarray, delta: float, variance: np.ndarray) -> np.ndarray:
    """Integrals of the unit 1D Gaussians of ``variance`` (N,) over the cells (m,) of side δ.

    Returns (N, m).
    """
    v = np.asarray(variance, dtype=np.float64).reshape(-1, 1)
    edges = np.append(x - 0.5 * delta, x[-1] + 0.5 * delta)
    return 0.5 * np.diff(erf(edges / np.sqrt(2.0 * v)), axis=1)


def gaussian_radial_cdf(r: np.ndarray, variance: np.ndarray) -> np.ndarray:
    """Radial CDF ``1 − e^{−r²/(2v)}`` of 2D Gaussians, broadcast (…)."""
    with np.errstate(under="ignore"):
        return -np.expm1(-np.square(r) / (2.0 * np.asarray(variance, dtype=np.float64)))


def _weights(g: np.ndarray, kern: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares weights ≥ 0 of separable Gaussians g (N, m) fitting kern (m, m)."""
    gram = (g @ g.T) ** 2
    b = ((g @ kern) * g).sum(axis=1)
    gram_d = gram + np.eye(g.shape[0]) * (1e-12 * np.trace(gram))
    keep = np.ones(g.shape[0], dtype=bool)
    w = np.zeros(g.shape[0])
    for _ in range(g.shape[0]):
        idx = np.flatnonzero(keep)
        sol = np.linalg.solve(gram_d[np.ix_(idx, idx)], b[idx])
        w[:] = 0.0
        w[idx] = sol
        if np.all(sol >= 0):
            break
        keep[idx[np.argmin(sol)]] = False
    w = np.maximum(w, 0.0)
    err2 = float(np.sum(kern * kern) - 2.0 * w @ b + w @ gram @ w)
    return w, max(err2, 0.0)


def _nelder_mead(f, x0: np.ndarray, step: float, iters: int) -> np.ndarray:
    n = x0.size
    pts = [x0] + [x0 + step * np.eye(n)[i] for i in range(n)]
    vals = [f(p) for p in pts]
    for _ in range(iters):
        order = np.argsort(vals)
        pts = [pts[i] for i in order]
        vals = [vals[i] for i in order]
        if abs(vals[-1] - vals[0]) <= 1e-7 * max(abs(vals[0]), 1e-300):
            break
        centre = np.mean(pts[:-1], axis=0)
        xr = centre + (centre - pts[-1])
        fr = f(xr)
        if fr < vals[0]:
            xe = centre + 2.0 * (centre - pts[-1])
            fe = f(xe)
            pts[-1], vals[-1] = (xe, fe) if fe < fr else (xr, fr)
        elif fr < vals[-2]:
            pts[-1], vals[-1] = xr, fr
        else:
            xc = centre + 0.5 * (pts[-1] - centre)
            fc = f(xc)
            if fc < vals[-1]:
                pts[-1], vals[-1] = xc, fc
            else:
                pts = [pts[0] + 0.5 * (p - pts[0]) for p in pts]
                vals = [vals[0]] + [f(p) for p in pts[1:]]
    return pts[int(np.argmin(vals))]


def fit_gaussians(kern: np.ndarray, delta: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Sum of n 2D Gaussians closest to a discrete kernel in the Frobenius norm (S.1).

    Variances by Nelder–Mead in log space; for given variances the weights
    are the non-negative least-squares solution (variable projection).
    The weights are then rescaled to sum to the kernel's sum (the L1
    constraint of d'Eon et al., energy conservation).

    Parameters
    ----------
    kern : (m, m) float, discrete kernel (cells of side δ centred on the origin)
    delta : float, cell side, scene units
    n : int, number of Gaussians, 1..8

    Returns
    -------
    weights : (n,) float >= 0, sorted by increasing variance
    variances : (n,) float, scene units²
    """
    if not 1 <= n <= 8:
        raise ValueError(f"n must be in [1, 8], got {n}")
    m = kern.shape[0]
    x = (np.arange(m) - m // 2) * delta
    lo, hi = math.log((0.25 * delta) ** 2), math.log((0.5 * m * delta) ** 2)

    def cost(logv):
        logv = np.clip(logv, lo - 4.0, hi + 2.0)
        return _weights(gaussian_cells(x, delta, np.exp(logv)), kern)[1]

    x0 = np.linspace(lo + 1.0, hi - 2.0, n) if n > 1 else np.array([0.5 * (lo + hi)])
    best = _nelder_mead(cost, x0, 1.0, 120 * n)
    best = _nelder_mead(cost, best, 0.1, 60 * n)
    v = np.exp(np.clip(best, lo - 4.0, hi + 2.0))
    g = gaussian_cells(x, delta, v)
    w, _ = _weights(g, kern)
    s = w @ (g.sum(axis=1) ** 2)
    if s > 0:
        w = w * kern.sum() / s
    order = np.argsort(v)
    return w[order], v[order]

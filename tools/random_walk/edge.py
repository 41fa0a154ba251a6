"""Edge responses of radial profiles, read from renders and fitted with Burley's profile.

A surface lit with irradiance ``E0`` on the half-plane x > 0 (dark for x < 0)
and scattering with the normalised radial pdf ``p(r)`` (``∫p = 1``, this is
``2πr·R(r)``) and total reflectance ``ρ`` leaves radiance

    L(x) = ρ·E0/π · G(x),   G(x) = P(X ≤ x),

where ``X = r·cos φ`` is the x offset of a point drawn from the profile (φ
uniform): ``G`` is the profile's *edge response*. For ``x ≥ 0``

    1 − G(x) = (1/π) ∫_x^∞ p(r)·arccos(x/r) dr,   G(−x) = 1 − G(x),

and with ``r = x/cos θ`` the integrand is smooth in θ. A pixel of width δ
(box filter) sees the mean of G over its width: :func:`pixel_edge` uses the
antiderivative of G tabulated in units of d.

The profile fitted is the post-process's: Burley's pdf truncated at
``truncate·d`` and renormalised (:mod:`cvsss.core.profiles.burley`).
"""

from __future__ import annotations

import functools
import json
import math
from pathlib import Path

import numpy as np
import OpenEXR
from scipy.optimize import minimize_scalar

#: Tabulation of the unit edge response: u = x/d on [-U_MAX, U_MAX] in steps of U_STEP.
U_MAX = 40.0
U_STEP = 1.0 / 256.0


def burley_pdf(r: np.ndarray, truncate: float = 16.0) -> np.ndarray:
    """Burley's radial pdf for d = 1, truncated at ``truncate`` and renormalised."""
    r = np.asarray(r, dtype=np.float64)
    total = 1.0 - 0.25 * np.exp(-truncate) - 0.75 * np.exp(-truncate / 3.0)
    p = (np.exp(-r) + np.exp(-r / 3.0)) / 4.0 / total
    return np.where(r <= truncate, p, 0.0)


@functools.lru_cache(maxsize=8)
def unit_edge_table(truncate: float = 16.0, n_theta: int = 4096):
    """(u, G(u), H(u)) of Burley's profile with d = 1; H the antiderivative of G from −U_MAX.

    Returns
    -------
    u, g, h : (N,) float64 arrays, N = 2·U_MAX/U_STEP + 1
    """
    u_pos = np.arange(0.0, U_MAX + U_STEP / 2, U_STEP)
    tail = np.zeros_like(u_pos)
    # Gauss-Legendre in θ over [0, arccos(x/R)] for each x (R = truncation radius).
    nodes, weights = np.polynomial.legendre.leggauss(n_theta // 16)
    for i, x in enumerate(u_pos):
        if x >= truncate:
            continue
        if x == 0.0:
            tail[i] = 0.5
            continue
        top = np.arccos(x / truncate)
        th = 0.5 * top * (nodes + 1.0)
        r = x / np.cos(th)
        integrand = burley_pdf(r, truncate) * th * r * np.tan(th)
        tail[i] = 0.5 * top * np.dot(weights, integrand) / np.pi
    g_pos = 1.0 - tail
    u = np.concatenate([-u_pos[:0:-1], u_pos])
    g = np.concatenate([1.0 - g_pos[:0:-1], g_pos])
    h = np.concatenate([[0.0], np.cumsum(0.5 * (g[1:] + g[:-1]) * U_STEP)])
    return u, g, h


def pixel_edge(x: np.ndarray, width: float, d: float, truncate: float = 16.0) -> np.ndarray:
    """Mean of the edge response G over pixels of ``width`` centred at ``x`` (scene units).

    Beyond the table (|x| > U_MAX·d) G is 0 or 1.
    """
    u, _, h = unit_edge_table(truncate)
    x = np.asarray(x, dtype=np.float64)

    def antider(v):
        inside = np.interp(v, u, h)
        beyond = h[-1] + (v - u[-1])  # G = 1 right of the table
        return np.where(v > u[-1], beyond, np.where(v < u[0], 0.0, inside))

    lo, hi = (x - width / 2) / d, (x + width / 2) / d
    return (antider(hi) - antider(lo)) * d / width


def read_exr(path: Path) -> dict[str, np.ndarray]:
    """Pass name ('Combined', 'Diffuse Color', ...) -> (H, W, C) float32 of a Blender EXR."""
    out = {}
    for part in OpenEXR.File(str(path)).parts:
        for key, ch in part.channels.items():
            out[key.split(".", 1)[-1]] = np.asarray(ch.pixels, dtype=np.float32)
    return out


def column_profile(path: Path) -> dict:
    """The edge measurement of one slab render.

    Returns
    -------
    dict with ``x`` (W,) pixel centres and ``width`` their width on the slab
    (scene units, edge at 0, lit side x > 0),
    ``y`` (W, 3) column means of Combined RGB, ``sem`` (W, 3) their standard
    errors over the rows, ``albedo_pass`` (3,) mean Diffuse Color (the closure
    weight Cycles gives the subsurface: Base Color times the specular layer's
    transmission), ``case`` the render's record.
    """
    case = json.loads(Path(path).with_suffix(".json").read_text())
    passes = read_exr(path)
    img = passes["Combined"][..., :3].astype(np.float64)
    h, w = img.shape[:2]
    # A camera tilted about y by the view angle stretches a pixel across the edge.
    width = case["pixel"] / math.cos(math.radians(case.get("view_angle", 0.0)))
    x = (np.arange(w) - w / 2 + 0.5) * width
    return {
        "width": width,
        "x": x,
        "y": img.mean(axis=0),
        "sem": img.std(axis=0, ddof=1) / np.sqrt(h),
        "albedo_pass": passes["Diffuse Color"][..., :3].reshape(-1, 3).mean(axis=0),
        "case": case,
    }


def fit_channel(x, y, width, d0, truncate: float = 16.0) -> dict:
    """Least-squares fit of ``K·pixel_edge(x; d)`` to one channel's edge profile.

    K is solved in closed form for each d; d is searched in log space over
    [d0/20, 20·d0].

    Returns
    -------
    dict: ``d`` (scene units), ``K`` (the lit side's radiance), ``rms`` and
    ``max_abs`` of the residual relative to K.
    """
    y = np.asarray(y, dtype=np.float64)

    def solve(logd):
        m = pixel_edge(x, width, float(np.exp(logd)), truncate)
        k = float(np.dot(m, y) / np.dot(m, m))
        return k, m

    def cost(logd):
        k, m = solve(logd)
        return float(np.sum((y - k * m) ** 2))

    lo, hi = np.log(d0 / 20), np.log(d0 * 20)
    grid = np.linspace(lo, hi, 61)
    best = grid[int(np.argmin([cost(g) for g in grid]))]
    step = grid[1] - grid[0]
    res = minimize_scalar(
        cost, bounds=(best - step, best + step), method="bounded", options={"xatol": 1e-6}
    )
    k, m = solve(res.x)
    resid = (y - k * m) / k
    return {
        "d": float(np.exp(res.x)),
        "K": k,
        "rms": float(np.sqrt(np.mean(resid**2))),
        "max_abs": float(np.max(np.abs(resid))),
    }

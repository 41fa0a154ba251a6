"""Burley's normalized diffusion profile (Christensen & Burley 2015).

Radial pdf ``p(r) = (e^{−r/d} + e^{−r/(3d)}) / (4d)`` (this is 2πr·R(r)), CDF
``C(r) = 1 − ¼e^{−r/d} − ¾e^{−r/(3d)}``. Sampling uses Golubev's exact inverse
or the one-line approximation of the defense slides (D, slide 41). Radii and
``d`` are in scene units.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from .base import Profile, Region

#: Constant of the fast inverse approximation (D, slide 41); Unreal ships 2.6.
FAST_C = 2.5715
#: Cycles truncates Burley at 16·d (``BURLEY_TRUNCATE``).
CYCLES_TRUNCATE = 16.0


def blender_shape(radius: Sequence[float], scale: float) -> np.ndarray:
    """Burley shape ``d`` (scene units) from Principled BSDF inputs, Cycles 4.x mapping.

    ``d_c = Subsurface Radius_c · Subsurface Scale · 0.25 / π``, independent of
    albedo.

    >>> [round(v, 6) for v in blender_shape([1.0, 0.2, 0.1], 0.05)]
    [0.003979, 0.000796, 0.000398]
    """
    radius = np.asarray(radius, dtype=np.float64)
    if radius.shape != (3,):
        raise ValueError(f"radius must have 3 components (R, G, B), got shape {radius.shape}")
    if not np.all(np.isfinite(radius)) or np.any(radius < 0):
        raise ValueError(f"radius must be finite and >= 0, got {radius.tolist()}")
    if not (math.isfinite(scale) and scale >= 0):
        raise ValueError(f"scale must be finite and >= 0, got {scale}")
    return radius * scale * 0.25 / math.pi


def tail(r: np.ndarray, d: np.ndarray) -> np.ndarray:
    """``1 − C(r)`` computed directly (no cancellation for large r).

    Parameters
    ----------
    r, d : broadcastable float arrays, scene units; ``d <= 0`` means no
        scattering (tail 0 for r > 0, 1 at r = 0).
    """
    r = np.asarray(r, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    safe = np.where(d > 0, d, 1.0)
    with np.errstate(over="ignore", under="ignore"):
        t = 0.25 * np.exp(-r / safe) + 0.75 * np.exp(-r / (3.0 * safe))
    return np.where(d > 0, t, np.where(r > 0, 0.0, 1.0))


def cdf(r: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Burley CDF ``C(r)``; see :func:`tail`.

    >>> round(float(cdf(16.0, 1.0)), 10)
    0.9963790094
    """
    return 1.0 - tail(r, d)


def pdf(r: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Radial pdf ``(e^{−r/d} + e^{−r/(3d)}) / (4d)`` in 1/scene unit (0 for d <= 0)."""
    r = np.asarray(r, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    safe = np.where(d > 0, d, 1.0)
    with np.errstate(over="ignore", under="ignore"):
        p = (np.exp(-r / safe) + np.exp(-r / (3.0 * safe))) / (4.0 * safe)
    return np.where(d > 0, p, 0.0)


def radius_from_tail(t: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Exact inverse (Golubev 2019) in terms of the tail ``u = 1 − ξ``.

    ``G = 1 + 4u(2u + sqrt(1 + 4u²))``,
    ``r = 3d·ln((1 + G^{−1/3} + G^{1/3}) / (4u))``.

    Computed in the precision of ``t`` (float32 input stays float32, used by
    the sampler where radii only need ~1e-6 relative accuracy; anything else
    is evaluated in float64).
    """
    t = np.asarray(t)
    dt = np.float32 if t.dtype == np.float32 else np.float64
    u = np.clip(t.astype(dt, copy=False), np.finfo(dt).tiny, 1.0)
    g = u * u
    g *= 4.0
    g += 1.0
    np.sqrt(g, out=g)
    g += 2.0 * u
    g *= 4.0 * u
    g += 1.0
    # G >= 1, so G^{1/3} = exp(ln(G)/3) is safe and cheaper than cbrt.
    g13 = np.log(g, out=g)
    g13 *= 1.0 / 3.0
    np.exp(g13, out=g13)
    inner = 1.0 / g13
    inner += g13
    inner += 1.0
    inner /= 4.0 * u
    r = np.log(inner, out=inner)
    r *= 3.0 * np.asarray(d, dtype=dt)
    return np.maximum(r, 0.0, out=r)


def inverse_cdf(xi: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Exact inverse CDF ``r = C⁻¹(ξ)``."""
    return radius_from_tail(1.0 - np.asarray(xi, dtype=np.float64), d)


def radius_from_tail_fast(t: np.ndarray, d: np.ndarray, c: float = FAST_C) -> np.ndarray:
    """Fast approximation ``r ≈ d((2 − c)ξ − 2)·ln(1 − ξ)`` with ``ξ = 1 − t``."""
    t = np.clip(np.asarray(t, dtype=np.float64), 1e-300, 1.0)
    return np.maximum(
        np.asarray(d, dtype=np.float64) * ((2.0 - c) * (1.0 - t) - 2.0) * np.log(t), 0.0
    )


def fast_inverse_error(c: float = FAST_C, n: int = 100_001) -> dict[str, float]:
    """CDF error of the fast approximation: ``C(r_fast(ξ)) − ξ`` over ξ ∈ [0, 0.997].

    Returns
    -------
    dict with ``max_abs`` (largest absolute CDF error) and ``mean_abs``.
    The error is independent of ``d`` (both scale with it).
    """
    xi = np.linspace(0.0, 0.997, n)
    err = cdf(radius_from_tail_fast(1.0 - xi, 1.0, c), 1.0) - xi
    return {"max_abs": float(np.max(np.abs(err))), "mean_abs": float(np.mean(np.abs(err)))}


class BurleyProfile(Profile):
    """Burley profile per material slot, truncated at ``truncate·d`` and renormalised.

    Parameters
    ----------
    d : (K, 3) float array
        Shape ``d`` per slot and channel, scene units. Row 0 (no SSS) is
        forced to zero.
    truncate : float
        Truncation radius in units of ``d`` (Cycles: 16).
    inverse : {"exact", "fast"}
        Radius sampler. "fast" draws with the approximation but weights with
        the exact pdf, so it is biased by its CDF error
        (:func:`fast_inverse_error`).

    Notes
    -----
    u-space is the tail ``T = 1 − C``: the distant region ``[r0, r_max]`` is
    ``T ∈ [T(r_max), T(r0)]``, so γ = (T(r0) − T(r_max)) / (1 − T(r_max)).
    Per-slot tables of ``1/(3d)``, ``1/(4d)`` and ``r_max`` make the
    per-sample pdf one exp per channel (``e^{−r/d} = (e^{−r/(3d)})³``), in
    float32. The truncation renormalisation is the same for every channel and
    pixel, so the per-pixel weight scale cancels (``pixel_weight_scale``).
    """

    name = "burley"

    def __init__(self, d: np.ndarray, truncate: float = CYCLES_TRUNCATE, inverse: str = "exact"):
        d = np.array(d, dtype=np.float64, copy=True)
        if d.ndim != 2 or d.shape[1] != 3 or d.shape[0] < 1:
            raise ValueError(f"d must have shape (K, 3) with K >= 1, got {d.shape}")
        if not np.all(np.isfinite(d)) or np.any(d < 0):
            raise ValueError("d must be finite and >= 0 (scene units)")
        if inverse not in ("exact", "fast"):
            raise ValueError(f"inverse must be 'exact' or 'fast', got {inverse!r}")
        if not (0 < truncate <= 64):
            raise ValueError(f"truncate must be in (0, 64], got {truncate}")
        d[0] = 0.0
        self.d = d
        self.truncate = float(truncate)
        self.inverse = inverse
        self._tail_max = float(tail(self.truncate, 1.0))
        safe = np.where(d > 0, d, np.inf)
        # Channel-major (3, K) tables for the per-sample pdf.
        self._inv3d = np.ascontiguousarray((1.0 / (3.0 * safe)).T, dtype=np.float32)
        self._inv4d = np.ascontiguousarray((1.0 / (4.0 * safe)).T, dtype=np.float32)
        self._rmax = np.ascontiguousarray((d * self.truncate).T, dtype=np.float32)
        self._d32 = d.astype(np.float32).reshape(-1)

    @property
    def n_slots(self) -> int:
        return self.d.shape[0]

    def scatters(self):
        return self.d.max(axis=1) > 0

    pixel_weight_scale = False

    def chromatic(self):
        return np.any(self.d[:, 1:] != self.d[:, :1], axis=1)

    def region(self, r0, mat):
        d = self.d[mat]
        r0 = np.asarray(r0, dtype=np.float64)[:, None]
        rmax = d * self.truncate
        t_hi = tail(np.minimum(r0, rmax), d)
        t_lo = np.where(d > 0, self._tail_max, 0.0)
        mass = np.where(d > 0, np.maximum(t_hi - t_lo, 0.0), 0.0)
        total = 1.0 - self._tail_max
        gamma = mass / total
        with np.errstate(divide="ignore", invalid="ignore"):
            scale = np.where(mass > 0, gamma / mass, 0.0)
        return Region(gamma=gamma, weight_scale=scale, lo=t_lo, hi=t_hi)

    def sample(self, u, lo, hi, mat, channel):
        t = hi - u * (hi - lo)
        d = np.take(self._d32, mat * 3 + channel)
        if self.inverse == "fast":
            r = radius_from_tail_fast(t, d).astype(np.float32)
        else:
            r = radius_from_tail(t, d)
        return np.minimum(r, d * np.float32(self.truncate))

    def pdf(self, r, mat):
        return self.pdf_channels(r, mat).T

    def pdf_channels(self, r, mat):
        r = np.asarray(r, dtype=np.float32)
        a = np.take(self._inv3d, mat, axis=1)
        a *= -r
        np.exp(a, out=a)
        a *= a * a + 1.0
        a *= np.take(self._inv4d, mat, axis=1)
        np.copyto(a, 0.0, where=r > np.take(self._rmax, mat, axis=1))
        return a

    def describe(self, slot):
        return {"profile": self.name, "slot": int(slot), "d": self.d[slot].tolist()}

"""Burley's normalized diffusion profile (Christensen & Burley 2015).

Radial pdf ``p(r) = (e^{−r/d} + e^{−r/(3d)}) / (4d)`` (this is 2πr·R(r)), CDF
``C(r) = 1 − ¼e^{−r/d} − ¾e^{−r/(3d)}``. Sampling uses Golubev's exact inverse
or the one-line approximation of the defense slides (D, slide 41). Radii and
``d`` are in scene units.

The sampler of the estimator does not evaluate either inverse per sample: it
looks radii up in a table of the chosen inverse (:func:`tail_inverse_table`),
indexed by ``√t`` (t the tail value ``1 − ξ``) and linearly interpolated.
In ``√t`` the inverse is smooth down to the truncation radius (in t it has a
logarithmic singularity at t → 0), so 4096 intervals keep the sampler's CDF
within 2e-7 of the exact inverse's (:func:`table_error`; the float32 rounding of
t is most of it), and a sample costs a square root and one table read instead
of two logarithms, an exponential and a square root.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..backends.twins import compiled_module, compiled_side, numpy_side
from .base import Profile, Region

#: Constant of the fast inverse approximation (D, slide 41); Unreal ships 2.6.
FAST_C = 2.5715
#: Cycles truncates Burley at 16·d (``BURLEY_TRUNCATE``).
CYCLES_TRUNCATE = 16.0
#: Intervals of the radius table over √t ∈ [0, 1] (:func:`tail_inverse_table`).
TABLE_SIZE = 4096


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


def tail_inverse_table(
    truncate: float = CYCLES_TRUNCATE, inverse: str = "exact", size: int = TABLE_SIZE
) -> np.ndarray:
    """Radius table of the sampler: ``r/d`` at ``√t = i/size``, with the slope to the next node.

    Parameters
    ----------
    truncate : float, radii are capped at ``truncate`` (units of d)
    inverse : {"exact", "fast"}, the inverse tabulated (:func:`radius_from_tail`
        or :func:`radius_from_tail_fast`)
    size : int, intervals

    Returns
    -------
    (size + 1, 2) float32: row i holds ``ρ_i = r(t = (i/size)²)/d`` and
    ``ρ_{i+1} − ρ_i`` (0 in the last row), so that :func:`radius_from_table`
    is one read, one multiply-add and the cap at ``truncate``. Radii decrease
    with i: ``ρ_size = 0`` (t = 1, r = 0). Nodes are not capped (a capped node
    would bend the interval that holds the truncation radius); ρ_0 (t = 0) is
    the finite radius at t = 1e-300.
    """
    if inverse not in ("exact", "fast"):
        raise ValueError(f"inverse must be 'exact' or 'fast', got {inverse!r}")
    s = np.arange(size + 1, dtype=np.float64) / size
    t = np.maximum(s * s, 1e-300)
    rho = radius_from_tail(t, 1.0) if inverse == "exact" else radius_from_tail_fast(t, 1.0)
    rho = rho.astype(np.float32)
    rho[-1] = 0.0
    table = np.zeros((size + 1, 2), dtype=np.float32)
    table[:, 0] = rho
    table[:-1, 1] = rho[1:] - rho[:-1]
    return table


def radius_from_table(t: np.ndarray, table: np.ndarray, truncate: float) -> np.ndarray:
    """``r/d`` for tail values ``t`` (clipped to [0, 1]) from :func:`tail_inverse_table`.

    ``s = √t·size``, ``i = ⌊s⌋``, ``ρ = min(ρ_i + (s − i)·(ρ_{i+1} − ρ_i), truncate)``,
    all in float32 (the compiled backend does the same operations in the same order).
    """
    size = table.shape[0] - 1
    s = np.sqrt(np.clip(np.asarray(t, dtype=np.float32), 0.0, 1.0))
    s *= np.float32(size)
    i = s.astype(np.int32)
    np.subtract(s, i, out=s, dtype=np.float32)  # exact; no float64 detour
    rows = np.take(table, i, axis=0)
    s *= rows[:, 1]
    s += rows[:, 0]
    return np.minimum(s, np.float32(truncate), out=s)


def pdf_table(truncate: float = CYCLES_TRUNCATE, size: int = TABLE_SIZE) -> np.ndarray:
    """The unit pdf ``P(x) = (e^{−x} + e^{−x/3})/4`` at ``x_i = i·truncate/size``, with slopes.

    ``pdf(r) = P(r/d)/d`` for r ≤ truncate·d, 0 beyond. Row i holds ``P(x_i)``
    and ``P(x_{i+1}) − P(x_i)``; row ``size`` is (0, 0), so that the lookup
    ``s = min(r·size/(truncate·d), size)``, ``i = ⌊s⌋``,
    ``P ≈ P_i + (s − i)·ΔP_i`` gives 0 beyond the truncation without a
    branch. Linear interpolation over 4096 intervals is within 1.2e-6 of P
    (relative, float32 rounding included).

    Returns
    -------
    (size + 1, 2) float32
    """
    x = np.arange(size + 1, dtype=np.float64) * (truncate / size)
    p = 0.25 * (np.exp(-x) + np.exp(-x / 3.0))
    table = np.zeros((size + 1, 2), dtype=np.float32)
    table[:size, 0] = p[:size]
    table[:size, 1] = p[1:] - p[:size]
    return table


def pdf_from_table(
    r: np.ndarray, scale: np.ndarray, inv_d: np.ndarray, columns: tuple[np.ndarray, np.ndarray]
) -> np.ndarray:
    """``pdf(r)`` from :func:`pdf_table` with ``scale = size/(truncate·d)`` and ``inv_d = 1/d``.

    ``columns`` are the table's two columns (contiguous). Broadcasts ``r``
    against the per-channel ``scale`` and ``inv_d`` (float32 arithmetic; the
    compiled backend does the same operations in the same order). ``d = 0``
    is ``scale = inv_d = 0``: the pdf is 0.
    """
    value, slope = columns
    size = np.float32(value.shape[0] - 1)
    s = np.asarray(r, dtype=np.float32) * scale
    np.minimum(s, size, out=s)
    i = s.astype(np.int32)  # the lookup took 3.1 ns per value in all, 3.7 with intp
    np.subtract(s, i, out=s, dtype=np.float32)  # exact; no float64 detour
    s *= np.take(slope, i, mode="clip")  # in range by construction; "clip" skips a check
    s += np.take(value, i, mode="clip")
    s *= inv_d
    return s


def norm_table(
    d: np.ndarray, truncate: float = CYCLES_TRUNCATE, inverse: str = "exact", size: int = TABLE_SIZE
) -> np.ndarray:
    """The sampling density of every slot and drawn channel, on the radius table's nodes.

    A sample of slot k whose channel ch was drawn sits at ``r = ρ(s)·d_ch``
    (:func:`radius_from_table`, ``s = √t·size``). The estimator divides by the
    density of the channel mixture there, ``Σ_c pdf_c(r) = N(s)/d_ch`` with

        N(s) = Σ_c a_c·P(ρ(s)·a_c)·[ρ(s)·a_c ≤ truncate],  a_c = d_ch/d_c,

    which depends on the slot, ch and s only: this table holds it, read with
    the same ``i = ⌊s⌋`` and ``s − i`` as the radius, so that the per-sample
    work is two reads and a multiply-add instead of three pdf evaluations.

    A channel with a smaller d is cut off at ``ρ = truncate·d_c/d_ch`` inside
    the range: N jumps there, and linear interpolation across the jump would
    be wrong in that one interval. Its row therefore holds the line of N
    *with* that channel's term and the jump itself: for ``s`` below the jump
    position ``s*`` (larger radii) the term ``J`` (its value at the jump) is
    subtracted. The drawn channel is never cut inside its own range.

    Parameters
    ----------
    d : (K, 3) float, Burley d per slot and channel (scene units)
    truncate, inverse, size : as :func:`tail_inverse_table`

    Returns
    -------
    (3K·(size + 1), 4) float32, row ``(k·3 + ch)·(size + 1) + i``:
    ``N_i``, ``N_{i+1} − N_i``, ``s*`` (−1 where there is no jump) and ``J``.
    ``N ≈ N_i + (s − i)·ΔN_i − [s < s*]·J``. Rows of channels with d = 0 are 0.
    """
    d = np.asarray(d, dtype=np.float64)
    k_slots = d.shape[0]
    s = np.arange(size + 1, dtype=np.float64) / size
    t = np.maximum(s * s, 1e-300)
    rho = radius_from_tail(t, 1.0) if inverse == "exact" else radius_from_tail_fast(t, 1.0)
    rho = rho.astype(np.float32).astype(np.float64)  # the nodes the sampler reads
    rho[-1] = 0.0

    def unit_pdf(x):
        return 0.25 * (np.exp(-x) + np.exp(-x / 3.0))

    table = np.zeros((k_slots, 3, size + 1, 4))
    table[..., 2] = -1.0
    for k in range(k_slots):
        for ch in range(3):
            if d[k, ch] <= 0:
                continue
            n_full = np.zeros(size + 1)
            n_cut = np.zeros(size + 1)
            jumps = []
            for c in range(3):
                if d[k, c] <= 0:
                    continue
                a = d[k, ch] / d[k, c]
                term = a * unit_pdf(rho * a)
                n_full += term
                if a <= 1.0:  # never cut inside the drawn channel's range
                    n_cut += term
                    continue
                rho_star = truncate / a
                n_cut += np.where(rho <= rho_star, term, 0.0)
                s_star = math.sqrt(float(tail(rho_star, 1.0))) * size
                jumps.append((s_star, rho_star, term, a * unit_pdf(truncate)))
            rows = table[k, ch]
            rows[:, 0] = n_cut
            rows[:-1, 1] = n_cut[1:] - n_cut[:-1]
            for s_star, rho_star, term, jump in jumps:
                i = min(int(s_star), size - 1)
                if not rho[i] > rho_star:  # the cut falls on node i: no jump inside
                    continue
                # Node i (larger radius) lies beyond the cut, node i + 1 inside: the row
                # becomes the line with the channel's term, minus J below s*.
                rows[i, 0] += term[i]
                rows[i, 1] = n_cut[i + 1] - rows[i, 0]
                rows[i, 2] = max(rows[i, 2], s_star)
                rows[i, 3] += jump
    return table.reshape(-1, 4).astype(np.float32)


def table_error(
    truncate: float = CYCLES_TRUNCATE, inverse: str = "exact", n: int = 200_001
) -> dict:
    """CDF error of the tabulated sampler against the inverse it tabulates.

    ``|C(r_table(t)) − C(r(t))|`` over tail values from ``T(truncate)`` to 1
    (uniform and geometric spacing), radii in units of d.

    Returns
    -------
    dict with ``max_abs`` and ``mean_abs`` (independent of d).
    """
    t_lo = float(tail(truncate, 1.0))
    t = np.concatenate([np.linspace(t_lo, 1.0, n), np.geomspace(max(t_lo, 1e-30), 1.0, n)])
    exact = radius_from_tail(t, 1.0) if inverse == "exact" else radius_from_tail_fast(t, 1.0)
    exact = np.minimum(exact, truncate)
    tab = radius_from_table(t, tail_inverse_table(truncate, inverse), truncate)
    err = np.abs(tail(exact, 1.0) - tail(tab.astype(np.float64), 1.0))
    return {"max_abs": float(err.max()), "mean_abs": float(err.mean())}


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
        (:func:`fast_inverse_error`). Either is read from its table
        (:func:`tail_inverse_table`; CDF error ≤ 5e-7 against the formula).

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
        # The sampler's tables: radii (tail_inverse_table) and the pdf (pdf_table) read
        # with s = r·size/(truncate·d) and scaled by 1/d, per (channel, slot).
        self._rtab = tail_inverse_table(self.truncate, inverse)
        self._ptab = pdf_table(self.truncate)
        self._pscale = np.ascontiguousarray((TABLE_SIZE / (self.truncate * safe)).T, np.float32)
        self._inv_d = np.ascontiguousarray((1.0 / safe).T, dtype=np.float32)
        self._ntab = norm_table(d, self.truncate, inverse)
        # The same tables column by column (contiguous: what np.take reads fastest).
        self._rcols = tuple(np.ascontiguousarray(c) for c in self._rtab.T)
        self._pcols = tuple(np.ascontiguousarray(c) for c in self._ptab.T)
        self._ncols = tuple(np.ascontiguousarray(c) for c in self._ntab.T)

    @property
    def n_slots(self) -> int:
        return self.d.shape[0]

    def scatters(self):
        return self.d.max(axis=1) > 0

    pixel_weight_scale = False

    def chromatic(self):
        return np.any(self.d[:, 1:] != self.d[:, :1], axis=1)

    def contact_scale(self):
        return self.d.max(axis=1).astype(np.float32)

    def region(self, r0, mat, backend="numpy"):
        return burley_region(self, r0, mat, backend=backend)

    def sample(self, u, lo, hi, mat, channel):
        t = hi - u * (hi - lo)
        d = np.take(self._d32, mat * 3 + channel)
        return radius_from_table(t, self._rtab, self.truncate) * d

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


@numpy_side("burley_region")
def burley_region(
    profile: BurleyProfile, r0: np.ndarray, mat: np.ndarray, backend: str = "numpy"
) -> Region:
    """:meth:`BurleyProfile.region`: γ, weight scale and sampling bounds of P pixels.

    Parameters
    ----------
    profile : BurleyProfile
    r0 : (P,) float, inner radius per pixel (scene units); mat : (P,) int, compact slot
    backend : one of core.params.BACKENDS; where it resolves to numba one compiled pass
        computes the same values (:func:`_burley_region_compiled`; NumPy's passes over
        (P, 3) float64 arrays were half of preparing a frame's Geometry)

    Returns
    -------
    Region with (P, 3) float64 arrays
    """
    d = np.take(profile.d, mat, axis=0)
    r0 = np.asarray(r0, dtype=np.float64)[:, None]
    rmax = d * profile.truncate
    t_hi = tail(np.minimum(r0, rmax), d)
    t_lo = np.where(d > 0, profile._tail_max, 0.0)
    mass = np.where(d > 0, np.maximum(t_hi - t_lo, 0.0), 0.0)
    total = 1.0 - profile._tail_max
    gamma = mass / total
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(mass > 0, gamma / mass, 0.0)
    return Region(gamma=gamma, weight_scale=scale, lo=t_lo, hi=t_hi)


def _plain_burley(profile, *_args, **_kwargs) -> bool:
    """The compiled region is Burley's own: a subclass may define the region otherwise."""
    return type(profile) is BurleyProfile


@compiled_side("burley_region", supports=_plain_burley)
def _burley_region_compiled(
    profile: BurleyProfile, r0: np.ndarray, mat: np.ndarray, backend: str = "numpy"
) -> Region:
    """:func:`burley_region` in one compiled pass (libm's ``exp``: where NumPy has its
    own AVX-512 ``exp`` the two may differ in the last bit)."""
    gamma, scale, lo, hi = compiled_module("region").burley_region(
        r0, mat, profile.d, profile.truncate, profile._tail_max
    )
    return Region(gamma=gamma, weight_scale=scale, lo=lo, hi=hi)

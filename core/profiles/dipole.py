"""Jensen et al. 2001 dipole diffusion profile, with single scattering, tabulated.

Physics in millimetres (the unit of the measured σa, σs′ of seeds/004 section
G); the profile converts to scene units with one factor per slot,
``unit = scale / mm_per_unit`` (scene units per mm: 1/1000 for metres, times
an artist ``scale`` that makes a measured material's scattering visible in a
scene not modelled at real size, like Blender's Subsurface Scale).

Multiple scattering (the dipole of docs/explanation/design.md §4)::

    σt′ = σa + σs′, α′ = σs′/σt′, σtr = sqrt(3σa σt′),
    F_dr = −1.440/η² + 0.710/η + 0.668 + 0.0636η, A = (1 + F_dr)/(1 − F_dr),
    z_r = 1/σt′, z_v = z_r(1 + 4A/3), d_{r,v} = sqrt(r² + z_{r,v}²),
    R_ms(r) = α′/(4π)·Σ_{z} z(σtr d + 1)e^{−σtr d}/d³          [mm⁻²]

has the closed-form radial CDF (substitute ``d dd = r dr``)::

    ∫_0^r 2πr′R_ms dr′ = α′/2·Σ_{z} (e^{−σtr z} − z e^{−σtr d}/d),

whose limit is Jensen's total diffuse reflectance.

Single scattering (Table 2's ``R_{d,ss+ms}``): light entering at normal
incidence (Fresnel transmittance ``1 − F(0)``), scattering once at depth z
with the isotropic phase function (g = 0, as in the measured table, so
σs = σs′) and leaving through the surface towards the point at distance r,
attenuated along both legs and transmitted by the exit Fresnel term (zero
beyond the critical angle)::

    R_ss(r) = (1 − F(0))·σs/(4π)·∫_0^∞ e^{−σt z} e^{−σt D} T(z/D) z/D³ dz,  D = sqrt(r² + z²).

With the exit angle θ (``z = r cot θ``) this is a smooth integral over
``θ ∈ (0, θ_c]``::

    2πr·R_ss(r) = (1 − F(0))·α′σt′/2·∫_0^{θ_c} e^{−σt′ r (cot θ + csc θ)} T(cos θ) cos θ dθ,

evaluated with 96-point Gauss–Legendre. Without Fresnel (η = 1) its total is
``α′(1 − ln 2)/2``, which the tests check. Single scattering is included by
default because the MCML profiles the supplementary fits contain every order
and Table 2 lists it for the dipole row; ``single_scattering=False`` gives the
multiple-scattering profile ``R_{d,ms}`` that the artist-friendly model
starts from.

Tabulation and accuracy
-----------------------
Per slot, one log-spaced radius grid (``GRID`` nodes from 1e-4·min ℓ to where
the far tail holds < 1e-6 of the energy, ℓ = 1/σt′) carries the radial pdf
``p_c(r) = 2πr R_c(r) / A_c`` of each channel and its CDF (multiple scattering
closed form, single scattering by cumulative trapezoids). The profile is
truncated where the CDF reaches ``cdf_truncate`` (0.997) and renormalised.
Sampling inverts the CDF from a table of radii at ``INVERSE`` + 1 uniformly
spaced CDF values with linear interpolation: O(1) per sample, and the CDF of
a sampled radius is within :data:`INVERSE_CDF_ACCURACY` (absolute) of the
requested value (measured by :func:`inverse_round_trip_error` and tested).
"""

from __future__ import annotations

import math

import numpy as np

from .base import Profile, Region

#: Nodes of the per-slot log-spaced radius grid.
GRID = 4096
#: Cells of the uniform-CDF inverse table (per slot and channel).
INVERSE = 8192
#: Bound on |C(C⁻¹(ξ)) − ξ| of the tabulated sampler (checked in the tests).
INVERSE_CDF_ACCURACY = 2e-5
#: Default truncation: keep the radii holding this share of the energy.
CDF_TRUNCATE = 0.997
#: Millimetres per scene unit when the scene is modelled in metres.
MM_PER_METRE = 1000.0

_GL_X, _GL_W = np.polynomial.legendre.leggauss(96)


def fresnel_diffuse_reflectance(eta: float | np.ndarray) -> np.ndarray:
    """Average diffuse Fresnel reflectance ``F_dr`` (Jensen et al. 2001 polynomial).

    >>> round(float(fresnel_diffuse_reflectance(1.3)), 4)
    0.4448
    """
    eta = np.asarray(eta, dtype=np.float64)
    return -1.440 / eta**2 + 0.710 / eta + 0.668 + 0.0636 * eta


def _coefficients(sigma_a, sigma_s, eta):
    sa = np.asarray(sigma_a, dtype=np.float64)
    ss = np.asarray(sigma_s, dtype=np.float64)
    st = sa + ss
    alpha = np.where(st > 0, ss / np.where(st > 0, st, 1.0), 0.0)
    sigma_tr = np.sqrt(3.0 * sa * st)
    fdr = fresnel_diffuse_reflectance(eta)
    a = (1.0 + fdr) / (1.0 - fdr)
    zr = 1.0 / np.where(st > 0, st, np.inf)
    zv = zr * (1.0 + 4.0 * a / 3.0)
    return st, alpha, sigma_tr, zr, zv


def multiple_scattering(r, sigma_a, sigma_s, eta) -> np.ndarray:
    """Dipole diffuse reflectance ``R_ms(r)`` in mm⁻² at radius r (mm).

    Parameters
    ----------
    r, sigma_a, sigma_s, eta : broadcastable float arrays; r and 1/σ in mm,
        σa, σs′ in mm⁻¹, η relative index of refraction.
    """
    r = np.asarray(r, dtype=np.float64)
    _, alpha, sigma_tr, zr, zv = _coefficients(sigma_a, sigma_s, eta)
    out = 0.0
    for z in (zr, zv):
        d = np.sqrt(r * r + z * z)
        out = out + z * (sigma_tr * d + 1.0) * np.exp(-sigma_tr * d) / d**3
    return alpha / (4.0 * math.pi) * out


def multiple_scattering_cdf(r, sigma_a, sigma_s, eta) -> np.ndarray:
    """``∫_0^r 2πr′R_ms(r′)dr′`` (closed form), unnormalised: tends to the total A_ms."""
    r = np.asarray(r, dtype=np.float64)
    _, alpha, sigma_tr, zr, zv = _coefficients(sigma_a, sigma_s, eta)
    out = 0.0
    for z in (zr, zv):
        d = np.sqrt(r * r + z * z)
        out = out + np.exp(-sigma_tr * z) - z * np.exp(-sigma_tr * d) / d
    return 0.5 * alpha * out


def multiple_scattering_total(sigma_a, sigma_s, eta) -> np.ndarray:
    """Jensen's total diffuse reflectance ``α′/2·(1 + e^{−4A/3·√(3(1−α′))})e^{−√(3(1−α′))}``.

    >>> round(float(multiple_scattering_total(0.032, 0.74, 1.3)), 4)
    0.436
    """
    _, alpha, sigma_tr, zr, zv = _coefficients(sigma_a, sigma_s, eta)
    return 0.5 * alpha * (np.exp(-sigma_tr * zr) + np.exp(-sigma_tr * zv))


def fresnel_transmittance(cos_i: np.ndarray, eta: float) -> np.ndarray:
    """Unpolarised Fresnel transmittance from the medium (index η) into air.

    ``cos_i`` is the cosine of the internal angle; zero beyond the critical
    angle (total internal reflection).
    """
    cos_i = np.clip(np.asarray(cos_i, dtype=np.float64), 0.0, 1.0)
    sin_t2 = eta * eta * (1.0 - cos_i * cos_i)
    cos_t = np.sqrt(np.clip(1.0 - sin_t2, 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = (eta * cos_i - cos_t) / (eta * cos_i + cos_t)
        rp = (cos_i - eta * cos_t) / (cos_i + eta * cos_t)
    f = np.nan_to_num(0.5 * (rs * rs + rp * rp), nan=1.0)
    return np.where(sin_t2 < 1.0, 1.0 - f, 0.0)


def single_scattering_pdf(r, sigma_a: float, sigma_s: float, eta: float) -> np.ndarray:
    """Unnormalised radial density ``2πr·R_ss(r)`` in mm⁻¹ for one channel (see module doc)."""
    r = np.asarray(r, dtype=np.float64)
    st = sigma_a + sigma_s
    if st <= 0 or sigma_s <= 0:
        return np.zeros_like(r)
    theta_c = math.asin(min(1.0, 1.0 / eta)) if eta > 1 else 0.5 * math.pi
    theta = 0.5 * theta_c * (_GL_X + 1.0)
    w = 0.5 * theta_c * _GL_W * fresnel_transmittance(np.cos(theta), eta) * np.cos(theta)
    f = 1.0 / np.tan(theta) + 1.0 / np.sin(theta)
    t0 = 1.0 - ((eta - 1.0) / (eta + 1.0)) ** 2
    s = (st * r).reshape(-1, 1)
    with np.errstate(under="ignore"):
        integral = np.exp(-s * f) @ w
    return (t0 * 0.5 * sigma_s * integral).reshape(r.shape)


def single_scattering_total(sigma_a: float, sigma_s: float, eta: float) -> float:
    """Total single-scattering albedo ``∫2πr R_ss dr`` (no Fresnel: ``α′(1 − ln 2)/2``)."""
    st = sigma_a + sigma_s
    if st <= 0 or sigma_s <= 0:
        return 0.0
    # ∫_0^∞ e^{−st·r·f} dr = 1/(st·f): the radial integral in closed form per angle.
    theta_c = math.asin(min(1.0, 1.0 / eta)) if eta > 1 else 0.5 * math.pi
    theta = 0.5 * theta_c * (_GL_X + 1.0)
    w = 0.5 * theta_c * _GL_W * fresnel_transmittance(np.cos(theta), eta) * np.cos(theta)
    f = 1.0 / np.tan(theta) + 1.0 / np.sin(theta)
    t0 = 1.0 - ((eta - 1.0) / (eta + 1.0)) ** 2
    return float(t0 * 0.5 * sigma_s * np.sum(w / (st * f)))


def external_diffuse_reflectance(eta: float) -> float:
    """Hemispherical-average Fresnel reflectance of light arriving from air, ``2∫F(μ)μ dμ``.

    >>> round(external_diffuse_reflectance(1.3), 4)
    0.0611
    """
    mu = 0.5 * (_GL_X + 1.0)
    sin_t2 = (1.0 - mu * mu) / (eta * eta)
    cos_t = np.sqrt(1.0 - sin_t2)
    rs = (mu - eta * cos_t) / (mu + eta * cos_t)
    rp = (eta * mu - cos_t) / (eta * mu + cos_t)
    return float(np.sum(0.5 * _GL_W * 0.5 * (rs * rs + rp * rp) * 2.0 * mu))


def boundary_factor(eta: float) -> float:
    """Weight of the diffusion term next to single scattering: ``T(0)·(1 − F_dr,ext)``.

    Single scattering enters with the normal-incidence transmittance T(0) and
    leaves with the exact angular transmittance; the diffusion exitance is
    (nearly) cosine-distributed and leaves with the hemispherical average.
    Only the sum ``R_{d,ss+ms}`` uses it; ``R_{d,ms}`` alone is normalised anyway.
    """
    t0 = 1.0 - ((eta - 1.0) / (eta + 1.0)) ** 2
    return t0 * (1.0 - external_diffuse_reflectance(eta))


def total_reflectance(sigma_a, sigma_s, eta, single_scattering: bool = True) -> np.ndarray:
    """Total diffuse reflectance A_tot per channel.

    With ``single_scattering`` (the profile ``R_{d,ss+ms}``):
    ``boundary_factor(η)·A_ms + A_ss``; without, Jensen's ``A_ms``.

    Parameters
    ----------
    sigma_a, sigma_s : (3,) float, mm⁻¹
    eta : float
    """
    sa = np.broadcast_to(np.asarray(sigma_a, dtype=np.float64), (3,))
    ss = np.broadcast_to(np.asarray(sigma_s, dtype=np.float64), (3,))
    out = multiple_scattering_total(sa, ss, eta)
    if single_scattering:
        out = boundary_factor(eta) * out + np.array(
            [single_scattering_total(a, s, eta) for a, s in zip(sa, ss)]
        )
    return out


def _far_radius(sa: float, ss: float, eta: float) -> float:
    """Radius (mm) beyond which less than 1e-6 of the energy lies."""
    st, _, sigma_tr, zr, zv = _coefficients(sa, ss, eta)
    total = float(multiple_scattering_total(sa, ss, eta))
    lo, hi = float(zr), float(zr)
    while float(multiple_scattering_cdf(hi, sa, ss, eta)) < total * (1.0 - 1e-6) and hi < 1e12:
        hi *= 2.0
    del lo, sigma_tr, zv
    return max(hi, 40.0 / float(st))


class DipoleTable:
    """Tabulated radial pdf, CDF and inverse CDF of one slot, in millimetres.

    Attributes
    ----------
    r : (GRID,) float64, log-spaced radii, mm (``r[0] = r_min``)
    log_r0, inv_step : float, ``index = (ln r − log_r0)·inv_step``
    pdf : (3, GRID) float64, ``2πr R_c(r) / A_c`` (lookups give 0 beyond r_max_c), mm⁻¹
    cdf : (3, GRID) float64, normalised CDF (1 beyond r_max_c)
    rmax : (3,) float64, truncation radii, mm
    total : (3,) float64, A_tot of the untruncated profile
    kept : (3,) float64, share of A_tot kept by the truncation
    inverse : (3, INVERSE + 1) float64, radii at CDF values ``k/INVERSE``, mm
    """

    def __init__(
        self,
        sigma_a,
        sigma_s,
        eta: float,
        single_scattering: bool = True,
        cdf_truncate: float = CDF_TRUNCATE,
        grid: int = GRID,
        inverse: int = INVERSE,
    ):
        sa = np.asarray(sigma_a, dtype=np.float64)
        ss = np.asarray(sigma_s, dtype=np.float64)
        st = sa + ss
        ell = 1.0 / st
        r_far = max(_far_radius(a, s, eta) for a, s in zip(sa, ss))
        r_min = 1e-4 * float(ell.min())
        step = math.log(r_far / r_min) / (grid - 1)
        r = r_min * np.exp(step * np.arange(grid))
        self.r = r
        self.log_r0 = math.log(r_min)
        self.inv_step = 1.0 / step
        pdf = np.empty((3, grid))
        cdf = np.empty((3, grid))
        rmax = np.empty(3)
        total = np.empty(3)
        kept = np.empty(3)
        inv = np.empty((3, inverse + 1))
        k_ms = boundary_factor(eta) if single_scattering else 1.0
        for c in range(3):
            p = k_ms * 2.0 * math.pi * r * multiple_scattering(r, sa[c], ss[c], eta)
            cum = k_ms * multiple_scattering_cdf(r, sa[c], ss[c], eta)
            if single_scattering:
                pss = single_scattering_pdf(r, sa[c], ss[c], eta)
                p0 = float(single_scattering_pdf(0.0, sa[c], ss[c], eta))
                seg = 0.5 * (pss[1:] + pss[:-1]) * np.diff(r)
                cum = cum + np.concatenate([[0.5 * (p0 + pss[0]) * r[0]], seg]).cumsum()
                p = p + pss
            total[c] = cum[-1]
            cut = cdf_truncate * total[c]
            k = int(np.searchsorted(cum, cut))
            k = min(max(k, 1), grid - 1)
            # Linear interpolation of the radius where the CDF reaches the cut.
            frac = (cut - cum[k - 1]) / max(cum[k] - cum[k - 1], 1e-300)
            rmax[c] = r[k - 1] + frac * (r[k] - r[k - 1])
            mass = cum[k - 1] + frac * (cum[k] - cum[k - 1])
            kept[c] = mass / total[c]
            pdf[c] = p / mass  # not cut: the lookups zero r > r_max exactly
            cdf[c] = np.minimum(cum / mass, 1.0)
            cdf[c, r >= rmax[c]] = 1.0
            # Inverse table: radii at uniform CDF values, from (0, 0) + the grid.
            cc = np.concatenate([[0.0], cdf[c, :k], [1.0]])
            rr = np.concatenate([[0.0], r[:k], [rmax[c]]])
            cc, first = np.unique(cc, return_index=True)
            inv[c] = np.interp(np.linspace(0.0, 1.0, inverse + 1), cc, rr[first])
        self.pdf, self.cdf, self.rmax, self.total, self.kept, self.inverse = (
            pdf,
            cdf,
            rmax,
            total,
            kept,
            inv,
        )

    def index(self, r_mm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grid cell and interpolation weight of radii (mm)."""
        with np.errstate(divide="ignore", over="ignore"):
            f = (np.log(np.fmax(r_mm, 1e-300)) - self.log_r0) * self.inv_step
        f = np.clip(f, 0.0, self.r.size - 1.000001)
        i = f.astype(np.intp)
        return i, f - i

    def cdf_at(self, r_mm: np.ndarray) -> np.ndarray:
        """(3, N) normalised CDF at radii r (N,) mm (linear in the log grid)."""
        r_mm = np.asarray(r_mm, dtype=np.float64)
        i, w = self.index(r_mm)
        out = self.cdf[:, i] * (1.0 - w) + self.cdf[:, i + 1] * w
        below = r_mm < self.r[0]
        if np.any(below):  # 0 at r = 0, linear up to the first node
            out[:, below] = self.cdf[:, :1] * (np.maximum(r_mm[below], 0.0) / self.r[0])
        return np.where(r_mm[None, :] >= self.rmax[:, None], 1.0, out)

    def pdf_at(self, r_mm: np.ndarray) -> np.ndarray:
        """(3, N) normalised radial pdf at radii r (N,) mm, 0 beyond r_max."""
        r_mm = np.asarray(r_mm, dtype=np.float64)
        i, w = self.index(r_mm)
        out = self.pdf[:, i] * (1.0 - w) + self.pdf[:, i + 1] * w
        return np.where(r_mm[None, :] <= self.rmax[:, None], out, 0.0)

    def sample(self, xi: np.ndarray, channel: int) -> np.ndarray:
        """Radii (mm) at normalised CDF values ξ (N,) in [0, 1] of one channel."""
        m = self.inverse.shape[1] - 1
        t = np.clip(np.asarray(xi, dtype=np.float64), 0.0, 1.0) * m
        i = np.minimum(t.astype(np.intp), m - 1)
        f = t - i
        row = self.inverse[channel]
        return row[i] + f * (row[i + 1] - row[i])


def exact_cdf(
    r_mm,
    sigma_a: float,
    sigma_s: float,
    eta: float,
    single_scattering: bool = True,
    n: int = 20_001,
) -> np.ndarray:
    """Unnormalised CDF by direct quadrature (reference for the tests), mm."""
    r_mm = np.asarray(r_mm, dtype=np.float64)
    out = multiple_scattering_cdf(r_mm, sigma_a, sigma_s, eta)
    if single_scattering:
        out = boundary_factor(eta) * out
        # Fine geometric grid + trapezoids, independent of the table's grid.
        top = float(np.max(r_mm))
        g = np.concatenate([[0.0], np.geomspace(1e-7 / (sigma_a + sigma_s), max(top, 1e-6), n)])
        p = single_scattering_pdf(g, sigma_a, sigma_s, eta)
        cum = np.concatenate([[0.0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(g))])
        out = out + np.interp(r_mm, g, cum)
    return out


def inverse_round_trip_error(
    table: DipoleTable,
    sigma_a,
    sigma_s,
    eta: float,
    single_scattering: bool = True,
    n: int = 20_001,
) -> float:
    """max |C(C⁻¹(ξ)) − ξ| over ξ ∈ [0, 1] and channels, C by independent quadrature."""
    worst = 0.0
    xi = np.linspace(0.0, 1.0, n)
    for c in range(3):
        r = table.sample(xi, c)
        mass = table.total[c] * table.kept[c]
        back = exact_cdf(r, sigma_a[c], sigma_s[c], eta, single_scattering) / mass
        worst = max(worst, float(np.max(np.abs(back - xi))))
    return worst


class DipoleProfile(Profile):
    """Dipole profile per material slot, tabulated and truncated (see module doc).

    Parameters
    ----------
    sigma_a, sigma_s : (K, 3) float arrays
        Absorption and reduced scattering coefficients per slot and channel,
        mm⁻¹. Rows with all σs′ = 0 (and row 0) do not scatter.
    eta : (K,) float array or float
        Relative index of refraction, in [1, 3].
    unit : (K,) float array or float
        Scene units per millimetre (``scale / mm_per_unit``; 1e-3 for a
        scene in metres), > 0.
    single_scattering : bool
        Profile ``R_{d,ss+ms}`` (True, Table 2) or ``R_{d,ms}``.
    cdf_truncate : float
        Energy share kept by the truncation, in (0.5, 1).

    Notes
    -----
    u-space is the normalised CDF ξ: the distant region ``[r0, r_max]`` is
    ``ξ ∈ [C(r0), 1]`` and γ = 1 − C(r0). Because every channel is
    renormalised on ``[0, r_max]`` independently of r0, γ_c·p̂_c = pdf_c and
    the per-pixel weight scale cancels (``pixel_weight_scale = False``).
    """

    name = "dipole"
    pixel_weight_scale = False

    def __init__(
        self,
        sigma_a,
        sigma_s,
        eta=1.3,
        unit=1.0 / MM_PER_METRE,
        single_scattering: bool = True,
        cdf_truncate: float = CDF_TRUNCATE,
    ):
        sa = np.array(sigma_a, dtype=np.float64, copy=True)
        ss = np.array(sigma_s, dtype=np.float64, copy=True)
        if sa.ndim != 2 or sa.shape[1] != 3 or sa.shape != ss.shape or sa.shape[0] < 1:
            raise ValueError(
                f"sigma_a and sigma_s must have the same shape (K, 3), got "
                f"{sa.shape} and {ss.shape}"
            )
        k = sa.shape[0]
        for name, a in (("sigma_a", sa), ("sigma_s", ss)):
            if not np.all(np.isfinite(a)) or np.any(a < 0):
                raise ValueError(f"{name} must be finite and >= 0 (mm^-1)")
        eta = np.broadcast_to(np.asarray(eta, dtype=np.float64), (k,)).copy()
        unit = np.broadcast_to(np.asarray(unit, dtype=np.float64), (k,)).copy()
        if not np.all(np.isfinite(eta)) or np.any((eta < 1.0) | (eta > 3.0)):
            raise ValueError(f"eta must be in [1, 3], got {eta.tolist()}")
        if not np.all(np.isfinite(unit)) or np.any(unit <= 0):
            raise ValueError(
                f"unit (scene units per mm) must be finite and > 0, got {unit.tolist()}"
            )
        if not 0.5 < cdf_truncate < 1.0:
            raise ValueError(f"cdf_truncate must be in (0.5, 1), got {cdf_truncate}")
        sa[0] = 0.0
        ss[0] = 0.0
        self.sigma_a, self.sigma_s, self.eta, self.unit = sa, ss, eta, unit
        self.single_scattering = bool(single_scattering)
        self.cdf_truncate = float(cdf_truncate)
        active = np.all(ss > 0, axis=1)
        active[0] = False
        self._active = active
        self.tables: dict[int, DipoleTable] = {}
        # Flat per-sample tables in scene units: pdf (3, K·GRID), inverse ((K·3)·(M+1)).
        pdf = np.zeros((3, k, GRID), np.float32)
        inv = np.zeros((k, 3, INVERSE + 1), np.float32)
        log_r0 = np.zeros(k, np.float32)
        inv_step = np.ones(k, np.float32)
        rmax = np.zeros((3, k), np.float32)
        for s in np.flatnonzero(active):
            t = DipoleTable(sa[s], ss[s], float(eta[s]), self.single_scattering, self.cdf_truncate)
            self.tables[int(s)] = t
            pdf[:, s] = t.pdf / unit[s]
            inv[s] = t.inverse * unit[s]
            log_r0[s] = t.log_r0 + math.log(unit[s])
            inv_step[s] = t.inv_step
            rmax[:, s] = t.rmax * unit[s]
        self._pdf = np.ascontiguousarray(pdf.reshape(3, -1))
        self._inv = np.ascontiguousarray(inv.reshape(-1))
        self._log_r0, self._inv_step, self._rmax = log_r0, inv_step, rmax

    @property
    def n_slots(self) -> int:
        return self.sigma_a.shape[0]

    def scatters(self):
        return self._active.copy()

    def chromatic(self):
        return self._active & (
            np.any(self.sigma_a[:, 1:] != self.sigma_a[:, :1], axis=1)
            | np.any(self.sigma_s[:, 1:] != self.sigma_s[:, :1], axis=1)
        )

    def support(self, slot: int) -> np.ndarray:
        """(3,) truncation radius per channel, scene units (0 if the slot does not scatter)."""
        t = self.tables.get(int(slot))
        return np.zeros(3) if t is None else t.rmax * self.unit[slot]

    def radial_cdf(self, r: np.ndarray, slot: int) -> np.ndarray:
        """(3, N) normalised CDF at radii r (N,) scene units."""
        t = self.tables.get(int(slot))
        r = np.asarray(r, dtype=np.float64)
        if t is None:
            return np.ones((3, r.size))
        return t.cdf_at(r.reshape(-1) / self.unit[slot])

    def radial_pdf(self, r: np.ndarray, slot: int) -> np.ndarray:
        """(3, N) normalised radial pdf (per scene unit) at radii r (N,) scene units."""
        t = self.tables.get(int(slot))
        r = np.asarray(r, dtype=np.float64)
        if t is None:
            return np.zeros((3, r.size))
        return t.pdf_at(r.reshape(-1) / self.unit[slot]) / self.unit[slot]

    def region(self, r0, mat, backend="numpy"):
        r0 = np.asarray(r0, dtype=np.float64)
        mat = np.asarray(mat)
        xi0 = np.ones((r0.size, 3))
        for s, t in self.tables.items():
            sel = mat == s
            if np.any(sel):
                xi0[sel] = t.cdf_at(r0[sel] / self.unit[s]).T
        gamma = np.clip(1.0 - xi0, 0.0, 1.0)
        scale = np.where(gamma > 0, 1.0, 0.0)
        return Region(
            gamma=gamma, weight_scale=scale, lo=np.minimum(xi0, 1.0), hi=np.ones_like(xi0)
        )

    def sample(self, u, lo, hi, mat, channel):
        m = INVERSE
        t = (lo + u * (hi - lo)).astype(np.float32, copy=False)
        t = np.clip(t * np.float32(m), 0.0, np.float32(m))
        i = np.minimum(t.astype(np.intp), m - 1)
        f = t - i
        base = (np.asarray(mat, dtype=np.intp) * 3 + channel) * (m + 1) + i
        a = np.take(self._inv, base)
        b = np.take(self._inv, base + 1)
        b -= a
        b *= f
        b += a
        return b

    def pdf(self, r, mat):
        return self.pdf_channels(r, mat).T

    def pdf_channels(self, r, mat):
        r = np.asarray(r, dtype=np.float32)
        mat = np.asarray(mat, dtype=np.intp)
        f = np.log(np.fmax(r, np.float32(1e-30)))  # fmax: NaN → smallest radius
        f -= np.take(self._log_r0, mat)
        f *= np.take(self._inv_step, mat)
        np.clip(f, 0.0, np.float32(GRID - 1.001), out=f)
        i = f.astype(np.intp)
        f -= i
        i += mat * GRID
        a = np.take(self._pdf, i, axis=1)
        b = np.take(self._pdf, i + 1, axis=1)
        b -= a
        b *= f
        b += a
        np.copyto(b, 0.0, where=r > np.take(self._rmax, mat, axis=1))
        return b

    def describe(self, slot):
        slot = int(slot)
        return {
            "profile": self.name,
            "slot": slot,
            "sigma_a": self.sigma_a[slot].tolist(),
            "sigma_s": self.sigma_s[slot].tolist(),
            "eta": float(self.eta[slot]),
            "unit": float(self.unit[slot]),
            "single_scattering": self.single_scattering,
            "rmax": self.support(slot).tolist(),
        }

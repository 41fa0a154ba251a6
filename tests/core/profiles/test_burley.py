"""Burley profile: normalisation, inverse, sampler (chi-square), Blender mapping."""

import math

import numpy as np
import pytest

from cvsss.core.profiles import BurleyProfile, blender_shape, burley

from helpers import chi2_limit


@pytest.mark.parametrize("d", [1e-3, 0.37, 1.0, 250.0])
def test_pdf_integrates_to_one(d):
    # Integrate in the variable s = r/d on a fine grid out to 60d (tail < 1e-8).
    s = np.linspace(0.0, 60.0, 600_001)
    y = burley.pdf(s * d, d) * d
    integral = float(np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(s)))
    assert abs(integral - 1.0) < 1e-6


def test_cdf_matches_pdf_integral():
    r = np.linspace(0, 10, 100_001)
    num = np.concatenate(
        [[0], np.cumsum(0.5 * (burley.pdf(r[1:], 1.0) + burley.pdf(r[:-1], 1.0)) * np.diff(r))]
    )
    assert np.max(np.abs(num - burley.cdf(r, 1.0))) < 1e-8


def test_exact_inverse_round_trips():
    xi = np.concatenate([np.linspace(0.0, 0.999999, 10_001), 1.0 - np.logspace(-6, -12, 7)])
    for d in (1e-4, 1.0, 37.0):
        r = burley.inverse_cdf(xi, d)
        back = burley.cdf(r, d)
        assert np.all(np.abs(back - xi) <= 1e-9 * np.maximum(xi, 1e-300) + 1e-15)
    # In the tail variable the round trip is relative to the tail itself.
    t = np.logspace(-12, 0, 1001)
    r = burley.radius_from_tail(t, 2.0)
    assert np.max(np.abs(burley.tail(r, 2.0) / t - 1.0)) <= 1e-9


def test_fast_inverse_error_is_measured_and_small():
    err = burley.fast_inverse_error()
    # The approximation of the defense slides is a few 1e-3 off in CDF.
    assert 1e-4 < err["max_abs"] < 0.02
    assert err["mean_abs"] < err["max_abs"]


def test_sampler_chi_square():
    """Chi-square test of the profile's distant sampler against its pdf (fixed seed)."""
    d = np.array([[0, 0, 0], [0.5, 0.5, 0.5]], float)
    prof = BurleyProfile(d)
    rng = np.random.default_rng(7)
    n = 200_000
    r0 = 0.3
    mat = np.ones(1, np.int32)
    region = prof.region(np.array([r0]), mat)
    u = rng.random(n)
    ch = np.zeros(n, np.int64)
    r = prof.sample(
        u, np.full(n, region.lo[0, 0]), np.full(n, region.hi[0, 0]), np.ones(n, np.int32), ch
    )
    rmax = 16 * 0.5
    assert r.min() >= r0 - 1e-12 and r.max() <= rmax + 1e-12
    edges = np.concatenate([np.linspace(r0, 3.0, 40), np.linspace(3.0, rmax, 11)[1:]])
    counts, _ = np.histogram(r, bins=edges)
    cdf = burley.cdf(edges, 0.5)
    expected = n * np.diff(cdf) / (cdf[-1] - cdf[0])
    chi2 = float(np.sum((counts - expected) ** 2 / expected))
    assert chi2 < chi2_limit(len(counts) - 1), chi2


def test_gamma_limits():
    prof = BurleyProfile(np.array([[0, 0, 0], [1.0, 0.1, 0.0]]))
    g = prof.region(np.array([0.0, 1e-9, 1e3]), np.ones(3, np.int32)).gamma
    assert np.allclose(g[0, :2], 1.0)
    assert g[0, 2] == 0.0  # d = 0: no scattering at all
    assert np.all(g[2] == 0.0)  # r0 beyond the truncation radius
    assert np.all((g >= 0) & (g <= 1))


def test_blender_mapping_matches_cycles():
    d = blender_shape([1.0, 1.0, 1.0], 0.1)
    assert np.allclose(d, 0.1 * 0.25 / math.pi)
    with pytest.raises(ValueError, match="radius must have 3 components"):
        blender_shape([1.0, 2.0], 1.0)
    with pytest.raises(ValueError, match="scale must be finite"):
        blender_shape([1.0, 1.0, 1.0], float("nan"))


@pytest.mark.parametrize("inverse", ["exact", "fast"])
@pytest.mark.parametrize("truncate", [16.0, 1.0, 64.0])
def test_radius_table_follows_its_inverse(inverse, truncate):
    """The sampler reads radii from a table over √t: its CDF stays within 5e-7 of the
    formula it tabulates (float32 rounding of t is most of it), at any truncation."""
    err = burley.table_error(truncate, inverse)
    assert err["max_abs"] < 5e-7, err
    assert err["mean_abs"] < 1e-7, err
    # The exact table's own radii: within 2e-4·d of Golubev's inverse over the region.
    t = np.linspace(float(burley.tail(truncate, 1.0)), 1.0, 10_001)
    table = burley.tail_inverse_table(truncate, inverse)
    rho = burley.radius_from_table(t, table, truncate)
    ref = burley.radius_from_tail(t, 1.0) if inverse == "exact" else None
    if ref is not None:
        assert np.max(np.abs(rho - np.minimum(ref, truncate))) < 2e-4
    assert rho.dtype == np.float32 and rho.max() <= truncate and rho.min() >= 0.0


def test_pdf_table_matches_the_pdf():
    table = burley.pdf_table(16.0)
    columns = (np.ascontiguousarray(table[:, 0]), np.ascontiguousarray(table[:, 1]))
    for d in (1e-3, 0.5, 40.0):
        r = np.linspace(0.0, 16.0 * d * (1 - 1e-6), 200_001)
        ours = burley.pdf_from_table(
            r, np.float32(burley.TABLE_SIZE / (16.0 * d)), np.float32(1 / d), columns
        )
        np.testing.assert_allclose(ours, burley.pdf(r, d), rtol=1.5e-6, atol=0)
        beyond = burley.pdf_from_table(
            np.array([16.0 * d * 1.001, 1e30]),
            np.float32(burley.TABLE_SIZE / (16.0 * d)),
            np.float32(1 / d),
            columns,
        )
        assert np.all(beyond == 0.0)
    # d = 0 (scale and 1/d both 0): no density anywhere, no NaN.
    zero = burley.pdf_from_table(np.array([0.0, 1.0]), np.float32(0), np.float32(0), columns)
    assert np.all(zero == 0.0)


def _mixture(rho, d, ch, truncate):
    """Σ_c pdf_c(r)·d_ch at r = ρ·d_ch, each channel cut at truncate·d_c (float64)."""
    out = np.zeros_like(rho)
    for c in range(3):
        if d[c] > 0:
            a = d[ch] / d[c]
            x = rho * a
            out += np.where(x <= truncate, a * 0.25 * (np.exp(-x) + np.exp(-x / 3.0)), 0.0)
    return out


@pytest.mark.parametrize(
    "d", [(1.0, 1.0, 1.0), (1.0, 0.5, 0.25), (0.3, 1.0, 0.03), (1.0, 0.1, 0.01), (1.0, 0.5, 0.5)]
)
def test_norm_table_is_the_mixture_density(d):
    """The per-slot table of the channel mixture's density at the sampled radius, read
    like the estimators read it, against the exact truncated mixture — including the
    rows where another channel's truncation cuts the density (the jump rows)."""
    truncate = 16.0
    d = np.array(d)
    table = burley.norm_table(np.array([[0.0, 0.0, 0.0], d]), truncate)
    size = burley.TABLE_SIZE
    rtab = burley.tail_inverse_table(truncate)
    rng = np.random.default_rng(3)
    t = rng.uniform(float(burley.tail(truncate, 1.0)), 1.0, 400_000).astype(np.float32)
    s = np.sqrt(t) * np.float32(size)
    i = s.astype(np.int64)
    f = np.subtract(s, i, dtype=np.float32)
    rho = np.minimum(f * rtab[i, 1] + rtab[i, 0], np.float32(truncate)).astype(np.float64)
    for ch in range(3):
        rows = table[(3 + ch) * (size + 1) + i]
        ours = rows[:, 0] + f * rows[:, 1] - (s < rows[:, 2]) * rows[:, 3]
        exact = _mixture(rho, d, ch, truncate)
        rel = ours / exact - 1.0
        assert abs(rel.mean()) < 1e-5, (ch, rel.mean())
        # Linear interpolation in √t: ~1e-6 where the channels are alike, up to a few
        # 1e-4 in the interval of a cut when d differs 100-fold (0.05 at worst, 1 sample
        # in 1e5).
        assert np.quantile(np.abs(rel), 0.9999) < 1e-3, ch
        assert np.abs(rel).max() < 0.06, ch
    jumps = table[table[:, 2] >= 0]
    distinct = len(set(d))
    assert len(jumps) == (0 if distinct == 1 else (1 if distinct == 2 else 3))

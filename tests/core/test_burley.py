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

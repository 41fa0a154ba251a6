"""SPVG counts: clamp, ε_u, no-history rule, convergence to σ0²."""

import numpy as np
import pytest

from cvsss.core import SSSParams, make_processor
from cvsss.core.mc import adaptive
from cvsss.core.synthetic import scene_frame


def test_counts_clamped_and_zero_below_eps_u():
    p = SSSParams()
    var = np.array([0.0, 1e-6, 1e-4, 1e-2, 1e3, np.nan, np.inf, 1e-4])
    mbar = np.array([8, 8, 8, 64, 64, 8, np.nan, 8.0])
    gmax = np.array([0.5] * 7 + [0.001])
    m = adaptive.sample_counts(var, mbar, np.ones(8, bool), gmax, p)
    assert m[-1] == 0
    assert np.all((m[:-1] >= p.beta_min) & (m[:-1] <= p.beta_max))
    assert m[4] == p.beta_max and m[0] == p.beta_min


def test_no_history_uses_target_and_n_init():
    p = SSSParams(n_init=12)
    m = adaptive.sample_counts(
        np.array([5.0]), np.array([64.0]), np.array([False]), np.array([0.5]), p
    )
    assert m[0] == 12
    mu, var, mbar, valid = adaptive.update_history(
        np.array([9.0]),
        np.array([9.0]),
        np.array([9.0]),
        np.array([False]),
        np.array([0.25]),
        np.array([12]),
        p,
    )
    assert mu[0] == 0.25 and var[0] == pytest.approx(p.target_variance)
    assert mbar[0] == pytest.approx(12) and valid[0]


def test_update_equations():
    p = SSSParams(eta=0.25)
    mu, var, mbar, valid = adaptive.update_history(
        np.array([1.0]),
        np.array([0.5]),
        np.array([10.0]),
        np.array([True]),
        np.array([3.0]),
        np.array([0]),
        p,
    )
    assert mu[0] == pytest.approx(0.75 * 1 + 0.25 * 3)
    assert var[0] == pytest.approx(0.75 * 0.5 + 0.25 * 0.75 * 4.0)
    assert mbar[0] == pytest.approx(7.5)
    assert not valid[0]  # a pixel that took no samples has no history next frame


def test_static_scene_settles_near_target():
    """On a static scene, where counts are not clamped, σ² settles near σ0²."""
    p = SSSParams(target_variance=2e-5, beta_min=1, beta_max=1024, kappa=0.2)
    proc = make_processor("as", p)
    for n in range(1, 61):
        res = proc.process(scene_frame("static", n, 96, 54))
    c = res.counts[res.mask]
    var = res.variance[res.mask]
    free = (c > p.beta_min) & (c < p.beta_max)
    assert free.sum() > 100
    ratio = np.median(var[free]) / p.target_variance
    assert 0.5 < ratio < 2.0, ratio


def test_counts_always_in_range_over_a_flashing_sequence():
    p = SSSParams()
    proc = make_processor("as_ocv", p)
    for n in range(1, 25):
        res = proc.process(scene_frame("flash", n, 64, 36))
        c = res.counts[res.mask]
        g = res.gamma[res.mask].max(axis=1)
        assert np.all((c == 0) | ((c >= p.beta_min) & (c <= p.beta_max)))
        assert np.all(c[g < p.eps_u] == 0)
        assert np.all(c[g >= p.eps_u] >= p.beta_min)

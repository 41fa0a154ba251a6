"""EMC/EMCM against brute force, EWMA difference, the coefficient bound D."""

import numpy as np
import pytest

from cvsss.core.mc import control_variates as cv


@pytest.mark.parametrize("eta", [1e-6, 0.05, 0.2, 0.999])
def test_emcm_equals_weighted_covariance(eta, rng):
    z = rng.normal(size=(60, 2)) @ np.array([[1.0, 0.6], [0.0, 0.8]]) + [3.0, -1.0]
    sigmas, zetas = cv.emcm_run(z, eta)
    for n in (2, 5, 17, 60):
        brute = cv.weighted_covariance(z[:n], eta)
        assert np.allclose(sigmas[n - 1], brute, rtol=1e-9, atol=1e-300)
        # ζ is the weighted mean with the same weights.
        w = eta * (1 - eta) ** (n - 1 - np.arange(n))
        w[0] = (1 - eta) ** (n - 1)
        assert np.allclose(zetas[n - 1], w @ z[:n], rtol=1e-12)


def test_emcm_symmetric_psd(rng):
    z = rng.normal(size=(200, 3))
    sigmas, _ = cv.emcm_run(z, 0.1)
    assert np.allclose(sigmas, np.swapaxes(sigmas, 1, 2))
    assert np.min(np.linalg.eigvalsh(sigmas)) >= -1e-12


def test_ewma_differs_by_prediction(rng):
    """EWMA (Eq. 34) predicts about the previous mean: larger by 1/(1−η)."""
    z = rng.normal(size=(400, 2))
    eta = 0.2
    s_emcm, _ = cv.emcm_run(z, eta, "emcm")
    s_ewma, _ = cv.emcm_run(z, eta, "ewma")
    assert np.allclose(s_ewma, s_emcm / (1 - eta), rtol=1e-12)


def test_coefficient_reduces_to_one_and_is_bounded():
    a = cv.cv_coefficient(np.zeros(3), np.zeros(3), np.ones(3), np.ones(3), 1e-6)
    assert np.allclose(a, 1.0)
    # Huge covariance ratio is clamped to (f + g)/g.
    a = cv.cv_coefficient(np.array([1e6]), np.array([1.0]), np.array([0.3]), np.array([0.1]), 0.0)
    assert a[0] == pytest.approx(4.0)
    res = cv.residual(np.array([0.3]), np.array([0.1]), a)
    assert -0.1 - 1e-12 <= res[0] <= 0.3
    # Negative covariance clamps at 0; g = 0 gives a finite α and Res = f.
    assert cv.cv_coefficient(np.array([-5.0]), np.array([1.0]), np.ones(1), np.ones(1), 0.0)[0] == 0
    a0 = cv.cv_coefficient(np.array([1.0]), np.array([0.0]), np.ones(1), np.zeros(1), 0.0)
    assert np.isfinite(a0[0]) and cv.residual(np.ones(1), np.zeros(1), a0)[0] == 1.0
    # NaN/inf history never leaks.
    a = cv.cv_coefficient(
        np.array([np.nan, np.inf]), np.array([np.inf, np.nan]), np.ones(2), np.ones(2), 1e-6
    )
    assert np.all(np.isfinite(a)) and np.all((a >= 0) & (a <= 2))

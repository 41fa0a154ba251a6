"""Control variates in the sample domain (P Sec. 6).

The exponential moving covariance matrix (EMCM, P Eq. 33)

    Σ_t = (1−η)Σ_{t−1} + η(1−η)(Z_t − ζ_{t−1})(Z_t − ζ_{t−1})ᵀ,
    ζ_t = (1−η)ζ_{t−1} + η·Z_t,

with Σ_0 = 0 and ζ initialised to the first observation, equals the weighted
covariance with weights ``w_{n,i} = η(1−η)^{n−i}`` (the first observation
carries the remaining weight ``(1−η)^{n}``) taken about the *current*
weighted means; the EWMA estimator of finance (P Eq. 34) uses η instead of
η(1−η) and so predicts about the previous mean.

The CV coefficient (Alg. 2) ``α = (Σ_xy + ε_α)/(Σ_yy + ε_α)`` is clamped to
``D = [0, (f̄ + ḡ)/ḡ]``, which keeps the residual ``Res = f̄ − α·G(t)`` within
``[−ḡ, f̄]``. Only the tracked value S changes; the shaded image never does.
"""

from __future__ import annotations

import numpy as np


def emcm_step(
    sigma: np.ndarray, zeta: np.ndarray, z: np.ndarray, eta: float
) -> tuple[np.ndarray, np.ndarray]:
    """One EMCM update (P Eq. 33) in matrix form.

    Parameters
    ----------
    sigma : (..., n, n) float, Σ_{t−1}
    zeta : (..., n) float, ζ_{t−1}
    z : (..., n) float, Z_t
    eta : float in (0, 1]

    Returns
    -------
    sigma, zeta : Σ_t and ζ_t, float64.
    """
    dz = np.asarray(z, dtype=np.float64) - zeta
    sigma = (1.0 - eta) * sigma + eta * (1.0 - eta) * dz[..., :, None] * dz[..., None, :]
    zeta = (1.0 - eta) * zeta + eta * np.asarray(z, dtype=np.float64)
    return sigma, zeta


def ewma_step(
    sigma: np.ndarray, zeta: np.ndarray, z: np.ndarray, eta: float
) -> tuple[np.ndarray, np.ndarray]:
    """One EWMA covariance update (P Eq. 34), for comparison with EMCM."""
    dz = np.asarray(z, dtype=np.float64) - zeta
    sigma = (1.0 - eta) * sigma + eta * dz[..., :, None] * dz[..., None, :]
    zeta = (1.0 - eta) * zeta + eta * np.asarray(z, dtype=np.float64)
    return sigma, zeta


def emcm_run(z: np.ndarray, eta: float, estimator: str = "emcm") -> tuple[np.ndarray, np.ndarray]:
    """Run EMCM (or EWMA) over a series, ζ initialised to the first observation.

    Parameters
    ----------
    z : (T, n) float, observations Z_1..Z_T
    eta : float in (0, 1]
    estimator : {"emcm", "ewma"}

    Returns
    -------
    sigma : (T, n, n) covariance after each observation (Σ after Z_1 is 0)
    zeta : (T, n) moving mean after each observation
    """
    step = {"emcm": emcm_step, "ewma": ewma_step}[estimator]
    z = np.asarray(z, dtype=np.float64)
    t, n = z.shape
    sigmas = np.zeros((t, n, n))
    zetas = np.zeros((t, n))
    sigma = np.zeros((n, n))
    zeta = z[0].copy()
    zetas[0] = zeta
    for i in range(1, t):
        sigma, zeta = step(sigma, zeta, z[i], eta)
        sigmas[i] = sigma
        zetas[i] = zeta
    return sigmas, zetas


def weighted_covariance(z: np.ndarray, eta: float) -> np.ndarray:
    """Brute-force exponentially weighted covariance about the current weighted means.

    Weights ``w_i = η(1−η)^{n−i}`` for observations i = 1..n (0-based index
    ≥ 1) and ``(1−η)^n`` for the first one, so they sum to 1.

    Parameters
    ----------
    z : (T, n) observations
    eta : float

    Returns
    -------
    (n, n) covariance after all T observations.
    """
    z = np.asarray(z, dtype=np.float64)
    t = z.shape[0]
    last = t - 1
    powers = (1.0 - eta) ** (last - np.arange(t))
    w = eta * powers
    w[0] = (1.0 - eta) ** last
    mean = w @ z
    dz = z - mean
    return (w[:, None] * dz).T @ dz


def cv_coefficient(
    s_xy: np.ndarray,
    s_yy: np.ndarray,
    f_bar: np.ndarray,
    g_bar: np.ndarray,
    eps_alpha: float,
) -> np.ndarray:
    """CV coefficient of Alg. 2, clamped to D = [0, (f̄ + ḡ)/ḡ].

    Parameters
    ----------
    s_xy, s_yy : (P,) float, Cov(f̄, ḡ) and Var(ḡ) of the history (t−1)
    f_bar, g_bar : (P,) float, current f̄ and ḡ = G(t) (the bound D)
    eps_alpha : float >= 0

    Returns
    -------
    (P,) float64 α. Where ḡ <= 0 the bound is taken as [0, 1] (α then does
    not matter: Res = f̄). A negative f̄ (the estimator's centre control lets
    Î dip below 0) narrows D to [0, (f̄ + ḡ)/ḡ] as docs/explanation/design.md §8 states; when
    f̄ < −ḡ the bound is empty and α = 0 (Res = f̄).
    """
    s_xy = np.asarray(s_xy, dtype=np.float64)
    s_yy = np.asarray(s_yy, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        num = s_xy + eps_alpha
        den = s_yy + eps_alpha
        alpha = np.where(den > 0, num / den, 1.0)
        upper = np.where(g_bar > 0, np.maximum((f_bar + g_bar) / g_bar, 0.0), 1.0)
    # A bound or ratio that overflowed (ḡ subnormal, Σ_yy tiny) is capped at
    # the largest float so α stays finite (and Res = f̄ − α·G with it).
    big = np.finfo(np.float64).max
    upper = np.nan_to_num(upper, nan=1.0, posinf=big)
    alpha = np.nan_to_num(alpha, nan=1.0, posinf=big, neginf=0.0)
    return np.clip(alpha, 0.0, upper)


def residual(f_bar: np.ndarray, g_known: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Res(t) = f̄ − α_{t−1}·G(t) (P Eq. 38), the value S the history tracks."""
    return np.asarray(f_bar, dtype=np.float64) - alpha * g_known

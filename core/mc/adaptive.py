"""SPVG adaptive sample counts from an O(1) per-pixel history (P Eq. 5–10, Alg. 1).

The history ``H = (μ, σ², m̄)`` is an exponential moving mean and variance of
the tracked value S (luminance; see core.params for units) and the moving
mean of the counts. The count for the next frame aims the tracked variance at
σ0²:

    Δ   = (σ²_{t−1} − σ0²)/σ0² · m̄_{t−1} · (2/η − 2)
    m̂_t = κ·Δ + σ²_{t−1}/σ0² · m̄_{t−1}
    m_t = 0 if max_c γ_c < ε_u else clamp(round(m̂_t), β_min, β_max)

Where there is no valid history (first frame, disocclusion, a pixel that took
no samples) the defense slides' rule applies (D, slides 80–82): assume
σ² = σ0² and m̄ = n_init (default β_max, a generous cold start; the slides use
β_min) for the count, then take the new value with weight
1 (μ = S) and keep σ² = σ0² until a second observation gives a deviation.
"""

from __future__ import annotations

import numpy as np

from ..backends.twins import compiled_module, compiled_side, numpy_side
from ..params import SSSParams


@numpy_side("spvg_counts")
def sample_counts(
    var_prev: np.ndarray,
    mbar_prev: np.ndarray,
    valid: np.ndarray,
    gamma_max: np.ndarray,
    params: SSSParams,
) -> np.ndarray:
    """Per-pixel sample counts for this frame (Alg. 1).

    Parameters
    ----------
    var_prev, mbar_prev : (P,) float, σ²_{t−1} and m̄_{t−1} (any float dtype)
    valid : (P,) bool, history is valid for the pixel
    gamma_max : (P,) float, max_c γ_c
    params : SSSParams

    Returns
    -------
    (P,) int32 counts in {0} ∪ [β_min, β_max].
    """
    s0 = params.target_variance
    var = np.where(valid, np.asarray(var_prev, dtype=np.float64), s0)
    mbar = np.where(valid, np.asarray(mbar_prev, dtype=np.float64), params.initial_count)
    var = np.nan_to_num(var, nan=s0, posinf=np.finfo(np.float64).max)
    mbar = np.nan_to_num(mbar, nan=params.initial_count, posinf=params.beta_max)
    with np.errstate(over="ignore", invalid="ignore"):
        ratio = var / s0
        delta = (ratio - 1.0) * mbar * (2.0 / params.eta - 2.0)
        m_hat = params.kappa * delta + ratio * mbar
    m_hat = np.nan_to_num(
        m_hat, nan=params.beta_max, posinf=params.beta_max, neginf=params.beta_min
    )
    m = np.clip(np.rint(m_hat), params.beta_min, params.beta_max).astype(np.int32)
    m[np.asarray(gamma_max) < params.eps_u] = 0
    return m


@numpy_side("spvg_update")
def update_history(
    mu: np.ndarray,
    var: np.ndarray,
    mbar: np.ndarray,
    valid: np.ndarray,
    tracked: np.ndarray,
    counts: np.ndarray,
    params: SSSParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Eq. 5–7 after sampling, with the no-history rule.

    Parameters
    ----------
    mu, var, mbar : (P,) float, history at t−1
    valid : (P,) bool, history valid at t−1
    tracked : (P,) float, S(t): Res(t) with control variates, f̄ without
    counts : (P,) int, m_t
    params : SSSParams

    Returns
    -------
    mu, var, mbar : (P,) float64, history at t
    valid : (P,) bool, history valid at t (false where m_t = 0)
    """
    eta = params.eta
    s = np.asarray(tracked, dtype=np.float64)
    mu_prev = np.where(valid, np.asarray(mu, dtype=np.float64), s)
    var_prev = np.where(valid, np.asarray(var, dtype=np.float64), params.target_variance)
    mbar_prev = np.where(valid, np.asarray(mbar, dtype=np.float64), params.initial_count)
    # Overflow (HDR, huge exposure) saturates instead of leaking inf/NaN into
    # the history; see tests/core/test_stability.py.
    with np.errstate(over="ignore", invalid="ignore"):
        dev = s - mu_prev
        var_new = (1.0 - eta) * var_prev + eta * (1.0 - eta) * dev * dev
        mu_new = np.where(valid, (1.0 - eta) * mu_prev + eta * s, s)
        mbar_new = (1.0 - eta) * mbar_prev + eta * np.asarray(counts, dtype=np.float64)
    var_new = np.where(valid, var_new, params.target_variance)
    big = np.finfo(np.float64).max
    var_new = np.maximum(np.nan_to_num(var_new, nan=params.target_variance, posinf=big), 0.0)
    mu_new = np.nan_to_num(mu_new, nan=0.0, posinf=big, neginf=-big)
    mbar_new = np.nan_to_num(mbar_new, nan=params.initial_count, posinf=big, neginf=0.0)
    return mu_new, var_new, mbar_new, np.asarray(counts) > 0


@compiled_side("spvg_counts")
def _sample_counts_compiled(var_prev, mbar_prev, valid, gamma_max, params: SSSParams):
    """:func:`sample_counts` in one compiled pass: the same counts."""
    p = params
    return compiled_module("adaptive").spvg_counts(
        var_prev, mbar_prev, valid, gamma_max, p.target_variance, p.initial_count, p.eta,
        p.kappa, p.beta_min, p.beta_max, p.eps_u,
    )  # fmt: skip


@compiled_side("spvg_update")
def _update_history_compiled(mu, var, mbar, valid, tracked, counts, params: SSSParams):
    """:func:`update_history` in one compiled pass: the same bits."""
    return compiled_module("adaptive").spvg_update(
        mu, var, mbar, valid, tracked, counts, params.eta, params.target_variance,
        params.initial_count,
    )  # fmt: skip

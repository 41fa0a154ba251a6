"""The SPVG counts and history update as compiled passes (the numba sides of the
``spvg_counts`` and ``spvg_update`` twins, :mod:`core.mc.adaptive`).
"""

from __future__ import annotations

import numba
import numpy as np

from .common import _F64_MAX, _finite, _flat


def spvg_counts(
    var_prev, mbar_prev, valid, gamma_max, s0, n_init, eta, kappa, beta_min, beta_max, eps_u
) -> np.ndarray:
    """:func:`core.mc.adaptive.sample_counts` in one parallel pass (the same float64
    operations in the same order, so the same counts).

    Parameters
    ----------
    var_prev, mbar_prev : (P,) float, σ²_{t−1} and m̄_{t−1}; valid : (P,) bool
    gamma_max : (P,) float, max_c γ_c
    s0, n_init, eta, kappa, beta_min, beta_max, eps_u : float, σ0², the no-history count,
        η, κ, β range and ε_u (core.params.SSSParams)

    Returns
    -------
    int32 counts in the inputs' broadcast shape
    """
    shape = np.broadcast_shapes(*(np.shape(x) for x in (var_prev, mbar_prev, valid, gamma_max)))
    out = np.empty(shape, np.int32)
    _counts_pass(
        _flat(var_prev, shape, np.float64),
        _flat(mbar_prev, shape, np.float64),
        _flat(valid, shape, np.bool_),
        _flat(gamma_max, shape, np.float64),
        float(s0),
        float(n_init),
        2.0 / eta - 2.0,
        float(kappa),
        float(beta_min),
        float(beta_max),
        float(eps_u),
        out.reshape(-1),
    )
    return out


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _counts_pass(
    var_prev, mbar_prev, valid, gamma_max, s0, n_init, gain, kappa, lo, hi, eps_u, out
):
    for i in numba.prange(out.shape[0]):
        var = var_prev[i] if valid[i] else s0
        mbar = mbar_prev[i] if valid[i] else n_init
        var = _finite(var, s0, _F64_MAX, -_F64_MAX)
        mbar = _finite(mbar, n_init, hi, -_F64_MAX)
        ratio = var / s0
        delta = (ratio - 1.0) * mbar * gain
        m_hat = _finite(kappa * delta + ratio * mbar, hi, hi, lo)
        m = min(max(np.rint(m_hat), lo), hi)
        out[i] = 0 if gamma_max[i] < eps_u else np.int32(m)


def spvg_update(mu, var, mbar, valid, tracked, counts, eta, s0, n_init):
    """:func:`core.mc.adaptive.update_history` in one parallel pass (the same float64
    operations in the same order: the same bits).

    ``eta``, ``s0``, ``n_init``: η, σ0² and the no-history count. Returns mu, var, mbar
    ((P,) float64) and the new valid flags ((P,) bool).
    """
    shape = np.broadcast_shapes(*(np.shape(x) for x in (mu, var, mbar, valid, tracked, counts)))
    out = np.empty((3, *shape))
    _update_pass(
        _flat(mu, shape, np.float64),
        _flat(var, shape, np.float64),
        _flat(mbar, shape, np.float64),
        _flat(valid, shape, np.bool_),
        _flat(tracked, shape, np.float64),
        _flat(counts, shape, np.float64),
        *_spvg_constants(eta, s0, n_init),
        out.reshape(3, -1),
    )
    return out[0], out[1], out[2], np.asarray(counts) > 0


def _spvg_constants(eta, s0, n_init) -> tuple[float, float, float, float, float]:
    """(keep, spread, η, σ0², n_init) of Eq. 5–7 as :func:`_spvg_step` takes them:
    keep = 1 − η, spread = η(1 − η)."""
    eta = float(eta)
    return (
        1.0 - eta,
        eta * (1.0 - eta),
        eta,
        float(s0),
        float(n_init),
    )


@numba.njit(inline="always", error_model="numpy")
def _spvg_step(s, ok, mu, var, mbar, count, keep, spread, eta, s0, n_init):
    """One pixel's Eq. 5–7 with the no-history rule (core.mc.adaptive.update_history):
    μ, σ², m̄ at t from those at t−1, the tracked value s and the count (float64)."""
    big = _F64_MAX
    mu_prev = mu if ok else s
    var_prev = var if ok else s0
    mbar_prev = mbar if ok else n_init
    dev = s - mu_prev
    var_new = keep * var_prev + spread * dev * dev
    mu_new = keep * mu_prev + eta * s if ok else s
    mbar_new = keep * mbar_prev + eta * count
    var_new = var_new if ok else s0
    var_new = _finite(var_new, s0, big, -big)
    return (
        _finite(mu_new, 0.0, big, -big),
        var_new if var_new > 0.0 else 0.0,
        _finite(mbar_new, n_init, big, 0.0),
    )


@numba.njit(parallel=True, cache=True, nogil=True, error_model="numpy")
def _update_pass(mu, var, mbar, valid, tracked, counts, keep, spread, eta, s0, n_init, out):
    for i in numba.prange(out.shape[1]):
        out[0, i], out[1, i], out[2, i] = _spvg_step(
            tracked[i], valid[i], mu[i], var[i], mbar[i], counts[i], keep, spread, eta, s0, n_init
        )


#: Control variates of the compiled history step (:func:`history_step`): none (track

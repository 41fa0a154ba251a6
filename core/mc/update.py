"""The history step after sampling: the tracked value, the control variate and SPVG.

After the sampling step of an adaptive method, per SSS pixel:

1. the tracked luminances ``f̄ = Y(Î)`` and ``G = Y(γ·B)`` (Rec. 709, exposure-scaled,
   times the Subsurface Weight: what the image shows of the estimate), bounded to
   ±:data:`TRACK_LIMIT` so their squares stay finite in float64;
2. the control variate (P Alg. 2, Eq. 33): none (S = f̄), constant (α = 1) or online
   (α from the covariance history J, then one EMCM step of Z = (f̄, G)), giving the
   residual ``S = f̄ − α·G``;
3. SPVG's history update (P Eq. 5–7) of S, stored into the history's buffers.

:func:`update` is the NumPy side of the ``history_step`` twin
(:mod:`core.backends.twins`); on float32 histories the compiled side does all three
in one pass over the pixels, with the same float64 operations and float32 stores.
"""

from __future__ import annotations

import numpy as np

from ..backends.twins import compiled_module, compiled_side, numpy_side
from ..color import REC709
from ..geometry import Geometry
from ..params import SSSParams
from . import adaptive, control_variates
from .history import H_FIELDS, J_FIELDS, History

#: Bound on the tracked luminances f̄, G (their squares stay finite in float64).
TRACK_LIMIT = 1e150


def _luminance(rgb: np.ndarray) -> np.ndarray:
    """(P,) Rec.709 luminance of (P, 3) float64 ``rgb``, summed in channel order (the
    compiled history step's order; a matrix product's depends on the BLAS)."""
    r, g, b = REC709
    return rgb[:, 0] * r + rgb[:, 1] * g + rgb[:, 2] * b


def _bounded(values: np.ndarray) -> np.ndarray:
    """``values`` clipped to ±TRACK_LIMIT, NaN -> 0."""
    out = np.clip(values, -TRACK_LIMIT, TRACK_LIMIT)
    nan = np.isnan(out)
    if nan.any():
        out[nan] = 0.0
    return out


@numpy_side("history_step")
def update(
    hist: History,
    geom: Geometry,
    m: np.ndarray,
    valid: np.ndarray,
    distant: np.ndarray,
    b: np.ndarray,
    cv: str,
    params: SSSParams,
) -> tuple[np.ndarray, np.ndarray]:
    """The history (and control variate) update after sampling, in place on ``hist``.

    Parameters
    ----------
    hist : History reprojected onto this frame (H and, for ``cv="online"``, J)
    geom : Geometry of the frame's P SSS pixels (γ, Subsurface Weight)
    m : (P,) int, the counts m_t; valid : (P,) bool, the history was valid
    distant : (P, 3) float64, Î_t (linear); b : (P, 3) float64, B at the pixels
    cv : {"none", "constant", "online"}, the method's control variate
    params : SSSParams (exposure, η, σ0², n_init, ε_α, η_cv; ``backend`` picks the side)

    Returns
    -------
    alpha : (P,) float64, α where m_t > 0 (0 without a control variate), else 0
    variance : (P,) float64, σ² at t where m_t > 0, else 0
    """
    p = params
    idx = geom.index
    # What the image shows of the distant estimate is w·Î (Subsurface Weight w),
    # so that is what is tracked: a half-weight material needs fewer samples.
    with np.errstate(over="ignore", invalid="ignore"):
        f_bar = _luminance(distant * p.exposure)
        g_known = _luminance((geom.gamma * b) * p.exposure)
        if not np.all(geom.weight == 1.0):
            f_bar *= geom.weight
            g_known *= geom.weight
    f_bar = _bounded(f_bar)
    g_known = _bounded(g_known)
    alpha = np.zeros(geom.size)
    if cv == "online":
        alpha = _online_cv(hist, idx, valid, m, f_bar, g_known, p)
        tracked = control_variates.residual(f_bar, g_known, alpha)
    elif cv == "constant":
        alpha = np.ones(geom.size)
        tracked = control_variates.residual(f_bar, g_known, alpha)
    else:
        tracked = f_bar
    mu, var, mbar, new_valid = adaptive.update_history(
        hist.read("mu", idx),
        hist.read("var", idx),
        hist.read("mbar", idx),
        valid,
        tracked,
        m,
        p,
    )
    hist.write("mu", idx, mu)
    hist.write("var", idx, var)
    hist.write("mbar", idx, mbar)
    hist.valid = hist.mask_of(idx, new_valid)
    alpha = np.where(m > 0, alpha, 0.0)
    return alpha, np.where(m > 0, var, 0.0)


def _online_cv(hist, idx, valid, m, f_bar, g_known, params: SSSParams) -> np.ndarray:
    """α from the covariance history of Z = [f̄, ḡ] (Alg. 2), then one EMCM step (Eq. 33)."""
    p = params
    jv = hist.cv_valid.reshape(-1)[idx] & valid
    sxx, sxy, syy = (np.where(jv, hist.read(k, idx), 0.0) for k in ("sxx", "sxy", "syy"))
    z = np.stack([f_bar, g_known], axis=-1)
    # ζ starts at the first observation (and again after a disocclusion), Σ at 0.
    zeta = np.where(jv[:, None], hist.read_columns(("zf", "zg"), idx), z)
    alpha = control_variates.cv_coefficient(sxy, syy, f_bar, g_known, p.eps_alpha)
    sigma = np.stack([np.stack([sxx, sxy], -1), np.stack([sxy, syy], -1)], -2)
    sigma, zeta = control_variates.emcm_step(sigma, zeta, z, p.eta_cv)
    hist.write("sxx", idx, np.where(jv, sigma[:, 0, 0], 0.0))
    hist.write("sxy", idx, np.where(jv, sigma[:, 0, 1], 0.0))
    hist.write("syy", idx, np.where(jv, sigma[:, 1, 1], 0.0))
    hist.write("zf", idx, np.where(jv, zeta[:, 0], f_bar))
    hist.write("zg", idx, np.where(jv, zeta[:, 1], g_known))
    hist.cv_valid = hist.mask_of(idx, m > 0)
    return alpha


def _float32_history(hist: History, geom: Geometry, m, valid, distant, b, cv, params) -> bool:
    """The compiled step writes the history's buffers in place: float32, stored unscaled
    (:meth:`History.compiled_io`), the online control variate's J included."""
    fields = (*H_FIELDS, *(J_FIELDS if cv == "online" else ()))
    return hist.compiled_io(geom.index, fields)


@compiled_side("history_step", supports=_float32_history)
def _update_compiled(
    hist: History,
    geom: Geometry,
    m: np.ndarray,
    valid: np.ndarray,
    distant: np.ndarray,
    b: np.ndarray,
    cv: str,
    params: SSSParams,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`update` in one compiled pass over the pixels: the same operations and
    float32 stores."""
    p = params
    online = cv == "online"
    var, hist.valid, alpha = compiled_module("history").history_step(
        tuple(hist.buffers[k] for k in H_FIELDS),
        geom.index,
        valid,
        distant,
        geom.gamma,
        b,
        geom.weight,
        m,
        cv,
        (p.exposure, p.eta, p.target_variance, p.initial_count, TRACK_LIMIT, p.eps_alpha,
         p.eta_cv),
        (tuple(hist.buffers[k] for k in J_FIELDS), hist.cv_valid) if online else None,
    )  # fmt: skip
    if online:  # J is valid where samples were taken, as the history
        hist.cv_valid = hist.valid.copy()
    return alpha, var

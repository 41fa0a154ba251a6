"""Temporal reuse of the distant estimate, guided by the control variate (beyond the paper).

Every frame's distant estimate Î_t carries the Monte Carlo noise of its own
samples. Reusing earlier frames' estimates along the motion vectors removes
much of it, but plain accumulation lags and ghosts exactly when lights flash,
switch or shadows move. Following docs/explanation/design.md §10, with ``λ = max(λ_min, 1/(n+1))``
(n frames accumulated, reset on disocclusion or a material change) and
``Â_{t−1}`` the reprojected accumulation clamped to the current
neighbourhood (TAA-style variance clipping, in the accumulated domain):

``plain`` (``as_t``, the ghosting baseline)
    ``A_t = (1−λ)·Â_{t−1} + λ·Î_t``; output ``A_t``.
``subtractive``
    ``A_t = (1−λ)·Â_{t−1} + λ·(Î_t − α_t·G_t)``; output ``α_t·G_t + A_t``,
    with ``G_t = γ·B_t(p)`` the in-frame control known exactly and α_t the
    control variate's coefficient: the part of Î that G predicts is never lagged.
``multiplicative``
    ``A_t = (1−λ)·Â_{t−1} + λ·Î_t/(P_t + ε)``; output ``(P_t + ε)·A_t``, with
    ``P_t`` a noise-free proxy of the same distant integral computed every
    frame: the separable (pre-integrated, 17 taps, linear reads) estimate of it. A flash
    that scales all lighting leaves the accumulated ratio unchanged.

History rectification: the known, noise-free quantities tell where the
accumulated value has gone stale. Per pixel and channel,
``δ = |Δln(P + ε) − Δln(G + ε)| + ρ·|Δln(G + ε)|`` (multiplicative: the
proxy's change that a change of the centre's own lighting does not explain —
a shadow or a switched light in the neighbourhood; a global flash gives
δ ≈ ρ·|Δln G|, small; ρ = :data:`SWITCH_WEIGHT` makes a light switched off
still count) or ``δ = |Δln(G + ε)|`` (subtractive: the residual scales with
the lighting), and the frame count is cut to ``n·exp(−(δ/τ)²)`` before λ is
taken, τ = ``temporal_tolerance``.

A second, statistical rectification: the history's prediction for this
frame is compared with the new estimate in units of the estimate's own noise
(the spread of its samples, pooled over the 3×3 neighbourhood); beyond
:data:`NOISE_SIGMAS` standard deviations
the history is cut further. Measured on the synthetic sequences at 128×72
(1024-spp reference, frames 9–30): multiplicative as_ccv_t gains +3.4 dB
over as_ccv under the 5 Hz flash, +4.2 dB across the light switch of
``regular`` and +2.6 dB behind a moving shadow edge (never below as_ccv
there); its worst frames are the near-black ones (−1.2 dB on a 69 dB frame of
the flash, −4.3 dB on a 91 dB frame after the switch: absolute errors below
1e-4 of the range). Subtractive lags under the flash; plain accumulation
(as_t) falls up to 15 dB behind after the switch.
"""

from __future__ import annotations

import numpy as np

from ..backends.twins import compiled_module, compiled_side, numpy_side
from ..geometry import Geometry
from .history import History

TEMPORAL_MODES = ("multiplicative", "subtractive")

#: Share of the control's own log change added to the multiplicative mode's δ:
#: a light switched off (Δln G ≈ −3) still cuts the history even where the
#: proxy follows it, a flash's frame-to-frame change (0.1–1) barely does.
SWITCH_WEIGHT = 0.2

#: Standard deviations of the estimate's noise a history's prediction may miss by
#: before it is cut (smoothly: by exp(−(z − NOISE_SIGMAS)²/2)).
NOISE_SIGMAS = 2.0

_Y = np.array([0.2126, 0.7152, 0.0722])

_ACC = ("acc_r", "acc_g", "acc_b")
_PROX = ("prox_r", "prox_g", "prox_b")
_CTL = ("ctl_r", "ctl_g", "ctl_b")


@numpy_side("neighbourhood")
def neighbourhood(
    geom: Geometry, values: np.ndarray, active: np.ndarray, backend: str = "numpy"
) -> tuple:
    """Mean and standard deviation of ``values`` over each pixel's 3×3 neighbours.

    Only active SSS pixels of the same material count (the pixel itself
    included).

    Parameters
    ----------
    geom : Geometry (P SSS pixels)
    values : (P, 3) float
    active : (P,) bool, pixels that hold a value this frame
    backend : one of core.params.BACKENDS; where it resolves to numba this is one
        compiled pass (:func:`_neighbourhood_compiled`, the same float64 operations in
        the same order: the same bits)

    Returns
    -------
    mean, std : (P, 3) float64
    """
    h, w = geom.shape
    img = np.full((h * w, 3), np.nan)
    img[geom.index[active]] = values[active]
    mat = np.zeros(h * w, np.int32)
    mat[geom.index] = geom.mat
    total = np.zeros((geom.size, 3))
    square = np.zeros((geom.size, 3))
    count = np.zeros(geom.size)
    # Coordinates in the frame's own arrays (a tile's x, y are the whole image's).
    py, px = np.divmod(geom.index, w)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            x, y = px + dx, py + dy
            inside = (x >= 0) & (x < w) & (y >= 0) & (y < h)
            q = np.where(inside, y * w + x, geom.index)
            v = img[q]
            ok = inside & (mat[q] == geom.mat) & ~np.isnan(v[:, 0])
            v = np.where(ok[:, None], v, 0.0)
            total += v
            square += v * v
            count += ok
    n = np.maximum(count, 1.0)[:, None]
    mean = total / n
    var = np.maximum(square / n - mean * mean, 0.0)
    return mean, np.sqrt(var)


def _pixel_at(geom: Geometry) -> np.ndarray:
    """(H·W,) int64: the Geometry pixel at each pixel of the frame's arrays (−1: none)."""
    at = np.full(geom.shape[0] * geom.shape[1], -1, np.int64)
    at[geom.index] = np.arange(geom.size)
    return at


@compiled_side("neighbourhood")
def _neighbourhood_compiled(
    geom: Geometry, values: np.ndarray, active: np.ndarray, backend: str = "numpy"
) -> tuple:
    """:func:`neighbourhood` in one compiled pass: the same bits."""
    mean = np.empty((geom.size, 3))
    std = np.empty((geom.size, 3))
    compiled_module("temporal").neighbourhood_pass(
        np.ascontiguousarray(values, np.float64),
        np.ascontiguousarray(active, bool),
        _neighbour_table(geom),
        mean,
        std,
    )
    return mean, std


def _neighbour_table(geom: Geometry) -> np.ndarray:
    """(P, 9) int32: each pixel's 3×3 neighbours of its slot, for the compiled passes
    (core.backends.numba.temporal.neighbour_table)."""
    h, w = geom.shape
    # Which neighbours share the pixel's slot depends on the Geometry alone: made
    # once, kept with it (a still scene's next frames reuse it).
    return geom.memo(
        "neighbours",
        lambda: compiled_module("temporal").neighbour_table(
            np.ascontiguousarray(geom.index, np.int64),
            np.ascontiguousarray(geom.mat, np.int32),
            _pixel_at(geom),
            int(w),
            int(h),
        ),
    )


def reuse(
    hist: History,
    geom: Geometry,
    distant: np.ndarray,
    control: np.ndarray,
    alpha: np.ndarray,
    proxy: np.ndarray | None,
    active: np.ndarray,
    *,
    mode: str,
    min_weight: float,
    clamp: float,
    tolerance: float,
    noise: np.ndarray | None = None,
    scale: np.ndarray | None = None,
    backend: str = "numpy",
) -> tuple[np.ndarray, np.ndarray]:
    """One temporal-reuse step (see the module doc); updates ``hist`` in place.

    Parameters
    ----------
    hist : History holding :data:`~.history.T_FIELDS`, reprojected onto this frame
    geom : Geometry (P SSS pixels)
    distant : (P, 3) float, Î_t (linear)
    control : (P, 3) float, G_t = γ·B(p) per channel (linear)
    alpha : (P,) float, the CV coefficient α_t (1 for a constant control)
    proxy : (P, 3) float or None, P_t (multiplicative mode)
    active : (P,) bool, pixels that took samples this frame (the others reset)
    mode : {"plain", "subtractive", "multiplicative"}
    min_weight : λ_min in (0, 1]
    clamp : k of the neighbourhood clip ``mean ± k·std`` (inf: no clamp)
    tolerance : τ of the rectification (> 0; plain mode has none)
    noise : (P,) float, optional
        Standard deviation of this frame's estimate's luminance (linear), from
        the spread of its own samples; a prediction from the history more than
        :data:`NOISE_SIGMAS` of them away from the new estimate cuts the
        history (guided modes).
    scale : (3,) float, optional
        The frame's lighting scale (linear, :func:`core.geometry.light_scale`):
        ε = 1e-3·scale keeps the logarithms and ratios finite on black pixels.
        Default: the mean of ``control`` over these pixels (a tile must pass
        its whole image's).
    backend : one of core.params.BACKENDS; where it resolves to numba the per-pixel
        arithmetic and the neighbourhood statistics are compiled passes (the ``reuse``
        twin: on a float32 history two passes that also read and store the history,
        :func:`_reuse_compiled`; else the ``reuse_step`` twin, :func:`_step_compiled`
        between the history's reads and writes; the same values within an ulp of
        ``log``/``exp``)

    Returns
    -------
    distant : (P, 3) float64, the estimate after reuse
    frames : (P,) float64, the frame count n after this frame (0 where inactive)
    """
    distant = np.asarray(distant, dtype=np.float64)
    control = np.asarray(control, dtype=np.float64)
    if scale is None:
        scale = control.mean(axis=0) if control.size else np.zeros(3)
    scale = np.maximum(np.asarray(scale, dtype=np.float64), 1e-12)
    eps = 1e-3 * scale  # per channel, relative to the frame's lighting
    return _reuse(
        hist, geom, distant, control, alpha, proxy, active, eps, mode=mode,
        min_weight=min_weight, clamp=clamp, tolerance=tolerance, noise=noise,
        floor=1e-12 * scale @ _Y, backend=backend,
    )  # fmt: skip


def _fields(mode: str) -> tuple[str, ...]:
    """The history buffers the reuse reads and writes in ``mode``."""
    guided = mode != "plain"
    return (*_ACC, "acc_n", *(_CTL if guided else ()), *(_PROX if mode == "multiplicative" else ()))


@numpy_side("reuse")
def _reuse(
    hist, geom, distant, control, alpha, proxy, active, eps, *, mode, min_weight, clamp,
    tolerance, noise, floor, backend,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`reuse` from ``eps`` (ε per channel) and ``floor`` (the noise yardstick's
    lower bound) on: the history's reads, :func:`_step` and its writes."""
    idx = geom.index
    n = hist.read("acc_n", idx, backend)
    prev = hist.read_columns(_ACC, idx, backend)
    ctl_prev = hist.read_columns(_CTL, idx, backend) if mode != "plain" else None
    prox_prev = hist.read_columns(_PROX, idx, backend) if mode == "multiplicative" else None
    acc, out, n_new = _step(
        geom, distant, control, alpha, proxy, active, n, prev, ctl_prev, prox_prev, eps,
        mode=mode, min_weight=min_weight, clamp=clamp, tolerance=tolerance, noise=noise,
        floor=floor, backend=backend,
    )  # fmt: skip
    hist.write_columns(_ACC, idx, acc, backend)
    hist.write("acc_n", idx, n_new, backend)
    if mode != "plain":
        hist.write_columns(_CTL, idx, control, backend)
    if mode == "multiplicative":
        hist.write_columns(_PROX, idx, np.maximum(proxy, 0.0), backend)
    return out, n_new


def _mode_code(passes, mode: str) -> int:
    """The compiled passes' code of a ``temporal_mode`` (plain, subtractive, multiplicative)."""
    return {
        "plain": passes.PLAIN,
        "subtractive": passes.SUBTRACTIVE,
        "multiplicative": passes.MULTIPLICATIVE,
    }[mode]


def _history_in_place(hist, geom, *_args, mode, **_kwargs) -> bool:
    """``supports`` of :func:`_reuse_compiled`: the buffers of ``mode`` are float32, stored
    unscaled, and compiled passes can read and write them in place
    (:meth:`History.compiled_io`)."""
    names = _fields(mode)
    return hist.compiled_io(geom.index, names) and all(hist.scale(n) == 1.0 for n in names)


@compiled_side("reuse", supports=_history_in_place)
def _reuse_compiled(
    hist, geom, distant, control, alpha, proxy, active, eps, *, mode, min_weight, clamp,
    tolerance, noise, floor, backend,
) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`_reuse` in two compiled passes over the pixels that read and store the
    history's buffers themselves (:func:`core.backends.numba.temporal.reuse_start_history`,
    ``reuse_finish_history``): the reads, :func:`_step_compiled`'s arithmetic and the
    writes of :func:`_reuse`, with the pooled noise and the neighbourhood statistics
    taken per pixel in them (the same float64 operations in the same order: the
    same values as the ``reuse_step`` twin's compiled side between the reads and writes)."""
    passes = compiled_module("temporal")
    p = geom.size
    f64 = np.float64
    code = _mode_code(passes, mode)
    none3 = np.zeros((0, 3))
    idx = np.ascontiguousarray(geom.index)
    table = _neighbour_table(geom)
    active = np.ascontiguousarray(active, bool)
    distant = np.ascontiguousarray(distant, f64)

    def flat(names):  # flat views of the buffers: the passes' stores land in them
        if names[0] not in _fields(mode):
            return (np.zeros(0, np.float32),) * 3
        return tuple(hist.buffers[name].reshape(-1) for name in names)

    use_noise = mode != "plain" and noise is not None
    shift, value = np.empty((p, 3)), np.empty((p, 3))
    n_cut = np.empty(p)
    sigma = np.empty(p if use_noise else 0)
    acc_n = hist.buffers["acc_n"].reshape(-1)
    passes.reuse_start_history(
        distant, np.ascontiguousarray(control, f64), np.ascontiguousarray(alpha, f64),
        none3 if proxy is None else np.ascontiguousarray(proxy, f64), active, idx, acc_n,
        flat(_CTL), flat(_PROX), np.ascontiguousarray(eps, f64), code, float(SWITCH_WEIGHT),
        float(tolerance), np.ascontiguousarray(noise, f64) if use_noise else np.zeros(0),
        table, shift, value, n_cut, sigma,
    )  # fmt: skip
    out, n_new = np.empty((p, 3)), np.empty(p)
    passes.reuse_finish_history(
        distant, value, shift, n_cut, active, idx, flat(_ACC), acc_n, table, float(clamp),
        sigma, float(floor), code, float(NOISE_SIGMAS), float(min_weight), out, n_new,
    )  # fmt: skip
    return out, n_new


def _pooled_sigma(
    geom: Geometry, noise: np.ndarray, active: np.ndarray, backend: str
) -> np.ndarray:
    """(P,) the estimate's noise (standard deviation of its luminance) pooled over the
    3×3 neighbourhood (same material) as variance; inf where not finite."""
    # The spread of a handful of samples is itself noisy: pool it before using it as
    # the yardstick.
    var = np.nan_to_num(np.asarray(noise, dtype=np.float64) ** 2, posinf=np.inf)
    finite = np.isfinite(var)
    pooled, _ = neighbourhood(
        geom, np.repeat(np.where(finite, var, 0.0)[:, None], 3, 1), active & finite, backend
    )
    return np.where(finite, np.sqrt(pooled[:, 0]), np.inf)


@numpy_side("reuse_step")
def _step(
    geom, distant, control, alpha, proxy, active, n, prev, ctl_prev, prox_prev, eps, *,
    mode, min_weight, clamp, tolerance, noise, floor, backend,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """The reuse's arithmetic on arrays: (acc, out, n_new), see :func:`reuse`.

    ``n``, ``prev``, ``ctl_prev``, ``prox_prev``: the history's frame count (P,),
    accumulation, control and proxy (P, 3) (None where the mode has none); ``floor``:
    the noise yardstick's lower bound, 1e-12 of the scale's luminance.
    """
    if mode == "multiplicative":
        shift = np.maximum(proxy, 0.0) + eps
        value = distant / shift
    elif mode == "subtractive":
        shift = alpha[:, None] * control
        value = distant - shift
    else:
        shift = None
        value = distant
    n = np.where(active, n, 0.0)
    if mode != "plain":
        # Each change of a logarithm as the logarithm of a ratio: half the calls of log,
        # which were most of the compiled step's time (the factors are ≥ ε > 0 and at
        # most float32's largest, so the ratios stay finite in float64).
        with np.errstate(divide="ignore", invalid="ignore"):
            ctl_ratio = (control + eps) / (np.maximum(ctl_prev, 0.0) + eps)
            d_ctl = np.log(ctl_ratio)
            if mode == "multiplicative":
                prox_ratio = shift / (np.maximum(prox_prev, 0.0) + eps)
                delta = np.abs(np.log(prox_ratio / ctl_ratio)) + SWITCH_WEIGHT * np.abs(d_ctl)
            else:
                delta = np.abs(d_ctl)
        delta = np.nan_to_num(delta.max(axis=1), nan=np.inf)
        n = n * np.exp(-((delta / tolerance) ** 2))
    if np.isfinite(clamp):
        mean, std = neighbourhood(geom, value, active, backend)
        prev = np.clip(prev, mean - clamp * std, mean + clamp * std)
    if mode != "plain" and noise is not None:
        # What the history predicts for this frame against what it measured, in
        # units of the estimate's own noise: a change the control did not predict
        # (a shadow passing, a light switched) shows as many sigmas.
        predicted = prev * shift if mode == "multiplicative" else prev + shift
        gap = np.abs((predicted - distant) @ _Y)
        sigma = _pooled_sigma(geom, noise, active, backend)
        with np.errstate(divide="ignore", invalid="ignore"):
            z = gap / np.maximum(sigma, floor)
        n = n * np.exp(-0.5 * np.maximum(np.nan_to_num(z, nan=np.inf) - NOISE_SIGMAS, 0.0) ** 2)
    lam = np.maximum(min_weight, 1.0 / (n + 1.0))
    acc = (1.0 - lam)[:, None] * prev + lam[:, None] * value
    acc = np.where(active[:, None], acc, value)
    n_new = np.where(active, n + 1.0, 0.0)
    if mode == "multiplicative":
        out = acc * shift
    elif mode == "subtractive":
        out = acc + shift
    else:
        out = acc
    return acc, np.where(active[:, None], out, distant), n_new


@compiled_side("reuse_step")
def _step_compiled(
    geom, distant, control, alpha, proxy, active, n, prev, ctl_prev, prox_prev, eps, *,
    mode, min_weight, clamp, tolerance, noise, floor, backend,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
    """:func:`_step` as two compiled per-pixel passes around the neighbourhoods
    (:func:`core.backends.numba.temporal.reuse_start`, ``reuse_finish``): the same float64
    operations, with libm's ``log`` and ``exp`` (an ulp from NumPy's) and the
    luminance summed in channel order (a matrix product's order is the BLAS's)."""
    passes = compiled_module("temporal")
    p = geom.size
    f64 = np.float64
    code = _mode_code(passes, mode)
    none3 = np.zeros((0, 3))
    shift, value = np.empty((p, 3)), np.empty((p, 3))
    n_cut = np.empty(p)
    active = np.ascontiguousarray(active, bool)
    distant = np.ascontiguousarray(distant, f64)
    passes.reuse_start(
        distant, np.ascontiguousarray(control, f64), np.ascontiguousarray(alpha, f64),
        none3 if proxy is None else np.ascontiguousarray(proxy, f64),
        np.ascontiguousarray(n, f64), active,
        none3 if ctl_prev is None else np.ascontiguousarray(ctl_prev, f64),
        none3 if prox_prev is None else np.ascontiguousarray(prox_prev, f64),
        np.ascontiguousarray(eps, f64), code, float(SWITCH_WEIGHT), float(tolerance),
        shift, value, n_cut,
    )  # fmt: skip
    mean = std = none3
    if np.isfinite(clamp):
        mean, std = neighbourhood(geom, value, active, backend)
    use_noise = mode != "plain" and noise is not None
    sigma = _pooled_sigma(geom, noise, active, backend) if use_noise else np.zeros(0)
    acc, out, n_new = np.empty((p, 3)), np.empty((p, 3)), np.empty(p)
    passes.reuse_finish(
        distant, np.ascontiguousarray(prev, f64), value, shift, n_cut, active, mean, std,
        float(clamp), sigma, float(floor), code, use_noise, float(NOISE_SIGMAS),
        float(min_weight), acc, out, n_new,
    )  # fmt: skip
    return acc, out, n_new

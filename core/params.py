"""The one parameters object of the algorithm.

The Blender panel, the command line and the tests all build a
:class:`SSSParams`; every check on a parameter lives in ``__post_init__`` so an
invalid value is refused once, at the boundary, with a message that names the
argument and its allowed range.

Units
-----
The adaptive sampler tracks *luminance* (Rec. 709 weights) of linear,
scene-referred values multiplied by ``exposure``. ``target_variance`` (σ0²) is
therefore a variance of that luminance: with ``exposure = 1`` and lighting
around 1 (a white diffuse surface lit by a 1 W/m² sun-like light gives
values ~0.3), σ0² = 1e-4 means a per-frame standard deviation of 0.01 in the
tracked distant-scattering luminance.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any

#: Defaults of the paper's evaluation (Xie & Olano 2021, Sec. 7).
PAPER_DEFAULTS = {
    "target_variance": 1e-4,
    "eta": 0.2,
    "eta_cv": 1e-6,
    "kappa": 0.2,
    "eps_u": 0.01,
    "eps_alpha": 1e-6,
    "beta_min": 8,
    "beta_max": 64,
}

HISTORY_PRECISIONS = ("float32", "float16")
BURLEY_INVERSES = ("exact", "fast")
MAX_SPP = 4096


class ParameterError(ValueError):
    """An invalid parameter value; the message names the argument and range."""


def _check_range(
    name: str,
    value: float,
    lo: float,
    hi: float,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be finite, got {value}")
    too_low = value <= lo if lo_open else value < lo
    too_high = value >= hi if hi_open else value > hi
    if too_low or too_high:
        left = "(" if lo_open else "["
        right = ")" if hi_open or math.isinf(hi) else "]"
        hi_text = "inf" if math.isinf(hi) else f"{hi:g}"
        raise ParameterError(f"{name} must be in {left}{lo:g}, {hi_text}{right}, got {value:g}")


def _check_int(name: str, value: int, lo: int, hi: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ParameterError(f"{name} must be an integer, got {value!r}")
    if not lo <= value <= hi:
        raise ParameterError(f"{name} must be in [{lo}, {hi}], got {value}")


@dataclass(frozen=True)
class SSSParams:
    """Parameters of adaptive control-variate subsurface scattering.

    Attributes
    ----------
    eta : float
        η, exponential moving coefficient of the sample-count history
        (P Eq. 5–7), in (0, 1]. Larger reacts faster, smaller smooths more.
    target_variance : float
        σ0², target variance of the tracked luminance (see module doc for
        units), in (0, inf).
    eps_u : float
        ε_u, pixels whose largest distant-scattering energy ratio γ is below
        this get zero samples (P Eq. 18), in [0, 1].
    eps_alpha : float
        ε_α, suppressing constant of the CV coefficient (P Sec. 6.2.3),
        in [0, inf); makes α = 1 when both moments vanish.
    kappa : float
        κ, weight of the SPVG correction term (P Eq. 8), in [0, 1].
    beta_min, beta_max : int
        β range, clamp of the adaptive sample count, 1 ≤ β_min ≤ β_max ≤ 4096.
    eta_cv : float
        η_cv, exponential moving coefficient of the CV covariance history
        (P Eq. 33), in (0, 1].
    n_init : int or None
        Mean sample count assumed where there is no valid history
        (D, slides 80–82); ``None`` means ``beta_min``.
    fixed_spp : int
        Samples per pixel of the ``fixed`` method, in [1, 4096].
    reference_spp : int
        Samples per pixel of the ``reference`` method, in [1, 4096].
    seed : int
        Seed of the per-pixel, per-frame hash, in [0, 2**32 - 1]. Same seed ⇒
        bit-identical output.
    history_precision : {"float32", "float16"}
        Storage of the per-pixel history; float16 mimics GPU RGBA16F targets.
    exposure : float
        Scale applied to linear values before tracking and PSNR, in (0, inf).
    burley_inverse : {"exact", "fast"}
        Radius sampler of the Burley profile: Golubev's exact inverse or the
        fast approximation of the defense slides (biased, error reported).
    depth_slope : float
        Bilateral "follow surface" rule: a sample at planar radius r (scene
        units) is rejected (falls back to the centre value) when the depth
        difference to the centre exceeds ``depth_slope * r``; 2 follows
        surfaces tilted up to ~63° from the view plane. In [0, inf).
    truncate : float
        Profile truncation radius in units of the profile's shape ``d``
        (Cycles uses 16 for Burley), in (0, 64].
    chunk_samples : int
        Upper bound of samples processed in one vectorised batch (memory
        bound: ~60 bytes per sample), in [1024, 2**26].
    """

    eta: float = PAPER_DEFAULTS["eta"]
    target_variance: float = PAPER_DEFAULTS["target_variance"]
    eps_u: float = PAPER_DEFAULTS["eps_u"]
    eps_alpha: float = PAPER_DEFAULTS["eps_alpha"]
    kappa: float = PAPER_DEFAULTS["kappa"]
    beta_min: int = PAPER_DEFAULTS["beta_min"]
    beta_max: int = PAPER_DEFAULTS["beta_max"]
    eta_cv: float = PAPER_DEFAULTS["eta_cv"]
    n_init: int | None = None
    fixed_spp: int = 64
    reference_spp: int = 1024
    seed: int = 0
    history_precision: str = "float32"
    exposure: float = 1.0
    burley_inverse: str = "exact"
    depth_slope: float = 2.0
    truncate: float = 16.0
    chunk_samples: int = 1 << 20

    def __post_init__(self) -> None:
        _check_range("eta", self.eta, 0.0, 1.0, lo_open=True)
        _check_range("target_variance", self.target_variance, 0.0, math.inf, lo_open=True)
        _check_range("eps_u", self.eps_u, 0.0, 1.0)
        _check_range("eps_alpha", self.eps_alpha, 0.0, math.inf)
        _check_range("kappa", self.kappa, 0.0, 1.0)
        _check_int("beta_min", self.beta_min, 1, MAX_SPP)
        _check_int("beta_max", self.beta_max, 1, MAX_SPP)
        if self.beta_min > self.beta_max:
            raise ParameterError(
                f"beta_min must be <= beta_max, got beta_min={self.beta_min}, "
                f"beta_max={self.beta_max}"
            )
        _check_range("eta_cv", self.eta_cv, 0.0, 1.0, lo_open=True)
        if self.n_init is not None:
            _check_int("n_init", self.n_init, 1, MAX_SPP)
        _check_int("fixed_spp", self.fixed_spp, 1, MAX_SPP)
        _check_int("reference_spp", self.reference_spp, 1, MAX_SPP)
        _check_int("seed", self.seed, 0, 2**32 - 1)
        if self.history_precision not in HISTORY_PRECISIONS:
            raise ParameterError(
                f"history_precision must be one of {HISTORY_PRECISIONS}, "
                f"got {self.history_precision!r}"
            )
        _check_range("exposure", self.exposure, 0.0, math.inf, lo_open=True)
        if self.burley_inverse not in BURLEY_INVERSES:
            raise ParameterError(
                f"burley_inverse must be one of {BURLEY_INVERSES}, got {self.burley_inverse!r}"
            )
        _check_range("depth_slope", self.depth_slope, 0.0, math.inf)
        _check_range("truncate", self.truncate, 0.0, 64.0, lo_open=True)
        _check_int("chunk_samples", self.chunk_samples, 1024, 1 << 26)

    @property
    def initial_count(self) -> int:
        """n_init, the mean count assumed without history (default β_min)."""
        return self.beta_min if self.n_init is None else self.n_init

    def replace(self, **changes: Any) -> SSSParams:
        """Return a copy with ``changes`` applied (and validated)."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary of the parameters (for JSON sidecars and reports)."""
        return asdict(self)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of the user-facing parameters, in declaration order."""
        return tuple(f.name for f in fields(cls))

"""The parameters of the algorithm, in one place.

Every user-facing parameter is a field of a frozen dataclass whose metadata
(:class:`Spec`, attached with :func:`param`) holds its range, unit, help text
and UI label next to its default. The command line (``sss_addon.cli``) and the
Blender properties (``sss_addon.blender.properties``) are generated from these
specs, and ``__post_init__`` validates every field against them, so a value is
refused once, at the boundary, with a message that names the argument and its
allowed range.

Units
-----
The adaptive sampler tracks *luminance* (Rec. 709 weights) of linear,
scene-referred values multiplied by ``exposure``. ``target_variance`` (σ0²) is
therefore a variance of that luminance: with ``exposure = 1`` and lighting
around 1 (a white diffuse surface lit by a 1 W/m² sun-like light gives
values ~0.3), σ0² = 1e-4 means a per-frame standard deviation of 0.01 in the
tracked distant-scattering luminance. Distances are in scene units.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Iterator
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
DISTANCES = ("surface", "cycles", "planar")
TEMPORAL_MODES = ("multiplicative", "subtractive")
#: Implementations of the Monte Carlo sampling step (core.backends.select).
BACKENDS = ("auto", "numpy", "numba")
MAX_SPP = 4096
#: ``contact``: another object hides the surface a sample's centre stands on when it faces
#: the camera this many times more squarely (|n·v|) than the centre does: a block seen
#: head-on on a table top seen at a slant. Above 1, so that two surfaces that face the
#: camera alike (whose |n·v| differs only by where they are on the image) never do
#: (docs/explanation/design.md §5.6).
CONTACT_FACING = 1.5
#: ``contact``: where a pixel's surface ends on another object (a slab's front face on
#: the floor), the share of a sample's light it loses on that object within
#: CONTACT_FOOT·contact·d of it, fading to none at contact·d: fitted to Cycles'
#: Christensen-Burley at the foot of the demo's slab, 26 % darker in its lowest row
#: and fading within about a d (docs/explanation/accuracy.md §2.2).
CONTACT_LOSS = 0.7
CONTACT_FOOT = 0.25

#: Separable SSS (Jimenez et al. 2015): kernels, taps per 1D pass, surface rules, tap reads.
KERNELS = ("pre_integrated", "svd1", "svd2", "svd3", "svd4", "gaussians", "artist")
TAP_COUNTS = (11, 17, 25)
FOLLOW_RULES = ("slope", "exponential")
FILTERS = ("nearest", "linear")
#: Taps within this share of the kernel range are jittered (Jimenez et al.'s 33 %).
JITTER_THRESHOLD = 0.33
#: Cells per side of the discrete 2D profile the separable kernels are fitted to.
PROFILE_GRID = 129


class ParameterError(ValueError):
    """An invalid parameter value; the message names the argument and range."""


@dataclass(frozen=True)
class Spec:
    """What a parameter means and which values it takes (field metadata).

    Attributes
    ----------
    help : str
        One sentence for tooltips and ``--help``.
    label : str
        Name in the Blender panel (defaults to the field name, title-cased).
    unit : str
        Unit of the value (``""``: unitless).
    lo, hi : float or None
        Allowed range; ``None`` is unbounded.
    lo_open, hi_open : bool
        Whether the range excludes its ends.
    choices : tuple or None
        The allowed values (strings or integers).
    flag : str or None
        Command-line flag without ``--`` (default: the field name with ``-``);
        ``""`` keeps the field off the command line.
    ui : bool
        Shown as a Blender property.
    advanced : bool
        Drawn in the panel's *Advanced* sub-panel.
    soft : (float, float) or None
        Slider range in the panel.
    ui_lo, ui_hi : float or None
        Hard limits of the Blender property where they differ from the range
        (open ends, or Blender's 32-bit integers).
    precision : int
        Digits shown by the panel.
    """

    help: str
    label: str = ""
    unit: str = ""
    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False
    choices: tuple | None = None
    flag: str | None = None
    ui: bool = True
    advanced: bool = False
    soft: tuple[float, float] | None = None
    ui_lo: float | None = None
    ui_hi: float | None = None
    precision: int = 3

    def describe(self) -> str:
        """Help text with the range and unit, as the CLI and the UI print it."""
        text = self.help
        if self.choices is None and (self.lo is not None or self.hi is not None):
            lo = "-inf" if self.lo is None else f"{self.lo:g}"
            hi = "inf" if self.hi is None else f"{self.hi:g}"
            left = "(" if self.lo_open or self.lo is None else "["
            right = ")" if self.hi_open or self.hi is None else "]"
            text += f" {left}{lo}, {hi}{right}"
        if self.unit:
            text += f", {self.unit}"
        return text


def param(default: Any, **spec: Any) -> Any:
    """A dataclass field with a :class:`Spec` (see there for the keywords)."""
    return dataclasses.field(default=default, metadata={"spec": Spec(**spec)})


def specs(cls_or_obj: Any) -> Iterator[tuple[dataclasses.Field, Spec]]:
    """(field, spec) of every field of a parameters dataclass that has a spec."""
    for f in fields(cls_or_obj):
        spec = f.metadata.get("spec")
        if spec is not None:
            yield f, spec


def flag_of(f: dataclasses.Field, spec: Spec) -> str:
    """The command-line flag (without ``--``) of a field, ``""`` when it has none."""
    return f.name.replace("_", "-") if spec.flag is None else spec.flag


def _check_range(name: str, value: Any, spec: Spec) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ParameterError(f"{name} must be finite, got {value}")
    lo = -math.inf if spec.lo is None else spec.lo
    hi = math.inf if spec.hi is None else spec.hi
    too_low = value <= lo if spec.lo_open else value < lo
    too_high = value >= hi if spec.hi_open else value > hi
    if too_low or too_high:
        left = "(" if spec.lo_open else "["
        right = ")" if spec.hi_open or math.isinf(hi) else "]"
        hi_text = "inf" if math.isinf(hi) else f"{hi:g}"
        got = f"{value:g}"
        if got in (f"{lo:g}", hi_text):  # 1.0000001 is not "1": all its digits
            got = repr(float(value))
        raise ParameterError(f"{name} must be in {left}{lo:g}, {hi_text}{right}, got {got}")


def _check_int(name: str, value: Any, spec: Spec) -> None:
    if isinstance(value, bool) or not isinstance(value, int):
        raise ParameterError(f"{name} must be an integer, got {value!r}")
    if not spec.lo <= value <= spec.hi:
        raise ParameterError(f"{name} must be in [{int(spec.lo)}, {int(spec.hi)}], got {value}")


def validate(obj: Any) -> None:
    """Check every field of a parameters dataclass against its spec.

    Raises
    ------
    ParameterError
        Naming the field and its allowed values or range.
    """
    for f, spec in specs(obj):
        value = getattr(obj, f.name)
        if value is None and f.default is None:
            continue  # optional
        if spec.choices is not None:
            if isinstance(value, bool) or value not in spec.choices:
                listing = ", ".join(map(str, spec.choices))
                what = f"{spec.choices!r}" if isinstance(spec.choices[0], int) else listing
                raise ParameterError(f"{f.name} must be one of {what}, got {value!r}")
        elif f.type in ("bool", bool):
            if not isinstance(value, bool):
                raise ParameterError(f"{f.name} must be a bool, got {value!r}")
        elif f.type in ("str", str, "str | None"):
            if not isinstance(value, str):
                raise ParameterError(f"{f.name} must be a string, got {value!r}")
        elif f.type in ("int", int, "int | None"):
            _check_int(f.name, value, spec)
        else:
            _check_range(f.name, value, spec)


class _Params:
    """Shared helpers of the parameters dataclasses."""

    def replace(self, **changes: Any):
        """Return a copy with ``changes`` applied (and validated)."""
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Plain dictionary of the parameters (for JSON sidecars, checkpoints and reports)."""
        return asdict(self)

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """Names of the parameters, in declaration order."""
        return tuple(f.name for f in fields(cls))


@dataclass(frozen=True)
class SSSParams(_Params):
    """Parameters of adaptive control-variate subsurface scattering.

    Each field's :class:`Spec` (``dataclasses.fields(SSSParams)[i].metadata``)
    states its meaning, range and unit; the highlights:

    eta, eta_cv : η and η_cv, exponential moving coefficients of the
        sample-count history (P Eq. 5–7) and of the CV covariance (P Eq. 33).
    target_variance : σ0², target variance of the tracked luminance
        (luminance², see module doc).
    eps_u, eps_alpha, kappa : ε_u (P Eq. 18), ε_α (P Sec. 6.2.3), κ (P Eq. 8).
    beta_min, beta_max : the β clamp of the adaptive count.
    n_init : mean count assumed without valid history (D, slides 80–82);
        ``None`` means β_max (a cold start samples generously: measured
        against Cycles, a first frame at β_min was worse than no subsurface
        at all; see README *Defaults*). Not a user setting.
    chunk_samples : samples per vectorised batch of the NumPy backend: small
        enough that a batch's arrays (~120 bytes a sample) stay in the CPU's
        cache. Not a user setting.
    """

    eta: float = param(
        PAPER_DEFAULTS["eta"],
        label="η (History Rate)",
        help="Exponential moving coefficient of the per-pixel sample-count history; "
        "larger reacts faster to change, smaller smooths more",
        lo=0.0,
        hi=1.0,
        lo_open=True,
        ui_lo=1e-6,
        soft=(0.01, 1.0),
    )
    target_variance: float = param(
        PAPER_DEFAULTS["target_variance"],
        label="σ0² (Target Variance)",
        help="Target variance of the tracked distant-scattering luminance (exposure-scaled, "
        "linear); smaller means more samples and higher quality",
        unit="luminance²",
        lo=0.0,
        lo_open=True,
        ui_lo=1e-12,
        ui_hi=1e6,
        soft=(1e-6, 1e-2),
        precision=6,
    )
    eps_u: float = param(
        PAPER_DEFAULTS["eps_u"],
        label="ε_u (Distant Cutoff)",
        help="Pixels whose largest distant-scattering energy ratio γ is below this get no samples",
        lo=0.0,
        hi=1.0,
        soft=(0.0, 0.2),
        precision=4,
    )
    eps_alpha: float = param(
        PAPER_DEFAULTS["eps_alpha"],
        label="ε_α (CV Suppression)",
        help="Suppressing constant of the control-variate coefficient; damps jitter-driven "
        "overestimates and gives α = 1 when both moments vanish",
        unit="luminance²",
        lo=0.0,
        ui_hi=1e6,
        soft=(0.0, 1e-2),
        precision=6,
    )
    kappa: float = param(
        PAPER_DEFAULTS["kappa"],
        label="κ (Correction Weight)",
        help="Weight of the SPVG correction term",
        lo=0.0,
        hi=1.0,
    )
    beta_min: int = param(
        PAPER_DEFAULTS["beta_min"],
        label="β min",
        help="Smallest adaptive sample count per SSS pixel",
        unit="samples",
        lo=1,
        hi=MAX_SPP,
        soft=(1, 256),
    )
    beta_max: int = param(
        PAPER_DEFAULTS["beta_max"],
        label="β max",
        help="Largest adaptive sample count per SSS pixel",
        unit="samples",
        lo=1,
        hi=MAX_SPP,
        soft=(1, 1024),
    )
    eta_cv: float = param(
        PAPER_DEFAULTS["eta_cv"],
        label="η_cv (Covariance Rate)",
        help="Exponential moving coefficient of the control-variate covariance history "
        "(the paper's 1e-6 is a very long memory)",
        lo=0.0,
        hi=1.0,
        lo_open=True,
        ui_lo=1e-9,
        soft=(1e-6, 0.5),
        precision=6,
    )
    n_init: int | None = param(
        None,
        help="Mean sample count assumed without valid history (None: β max)",
        unit="samples",
        lo=1,
        hi=MAX_SPP,
        flag="",
        ui=False,
    )
    fixed_spp: int = param(
        64,
        label="Fixed Samples",
        help="Samples per pixel of the Fixed N method",
        unit="samples",
        lo=1,
        hi=MAX_SPP,
        soft=(1, 1024),
    )
    reference_spp: int = param(
        1024,
        label="Reference Samples",
        help="Samples per pixel of the reference the PSNR is measured against",
        unit="samples",
        lo=1,
        hi=MAX_SPP,
        soft=(16, MAX_SPP),
    )
    seed: int = param(
        0,
        label="Seed",
        help="Seed of the per-pixel random sequence; the same seed gives identical output",
        lo=0,
        hi=2**32 - 1,
        ui_hi=2**31 - 1,
    )
    history_precision: str = param(
        "float32",
        label="History Precision",
        help="Storage of the per-pixel history (float16 mimics the paper's RGBA16F targets)",
        choices=HISTORY_PRECISIONS,
    )
    exposure: float = param(
        1.0,
        label="Exposure",
        help="Linear scale applied before tracking luminance and computing PSNR",
        lo=0.0,
        lo_open=True,
        ui_lo=1e-6,
        ui_hi=1e6,
        soft=(0.01, 100.0),
    )
    burley_inverse: str = param(
        "exact",
        label="Burley Sampler",
        help="Radius sampler of the Burley profile: Golubev's exact inverse or the fast "
        "approximation of the defense slides (biased; its CDF error is reported)",
        choices=BURLEY_INVERSES,
        advanced=True,
    )
    depth_slope: float = param(
        2.5,
        label="Depth Slope",
        help="Follow-surface rule: a sample at planar radius r falls back to the centre when "
        "its depth differs by more than depth_slope·r (2.5 follows surfaces tilted up to ~68°)",
        unit="scene units of depth per scene unit of radius",
        lo=0.0,
        ui_hi=1e6,
        soft=(0.0, 10.0),
        advanced=True,
    )
    distance: str = param(
        "cycles",
        label="Sample Kernel",
        help="How a sample is weighted: with the kernel Cycles' Christensen-Burley disk "
        "sampling integrates, which gains energy on curved and folded surfaces as Cycles does "
        "(cycles, default: closest to Cycles renders); with the Burley profile at the distance "
        "between the two points on the depth-buffer surface, energy-conserving (surface); both "
        "with the area Jacobian of the screen to surface mapping; or with the profile at the "
        "sampled planar radius (planar, the paper's)",
        choices=DISTANCES,
        advanced=True,
    )
    hidden_light: float = param(
        1.0,
        label="Hidden Light",
        help="Share of a pixel's direct light assumed on the surface the camera does not see "
        "(behind its silhouettes, under objects resting on it), where the profile's samples "
        "land on the background or another material or object and Mirror Hidden Light does "
        "not apply: 1 takes the pixel's own light (no assumption); below 1 darkens it, as "
        "where the back of an object or the ground under it lies in its shadow (front or "
        "top light: 0.75 brought the demo's flash rims from +7 % to ±1 % of Cycles)",
        lo=0.0,
        hi=1.0,
        advanced=True,
    )
    hidden_mirror: bool = param(
        True,
        label="Mirror Hidden Light",
        help="Where a sample lands beyond a silhouette (on the background or another "
        "material or object), read the pixel opposite it through the shaded pixel when "
        "that pixel is on the same surface: the hidden side is taken to continue as the "
        "visible one, so a rim lit harder than the surface below it loses light into it "
        "as in Cycles (the top edge of a candle under its flame). Christensen-Burley "
        "materials only: Cycles' random walk leaves through the hidden side instead. Off, "
        "for Random Walk materials, or where the opposite pixel is not on the surface, "
        "Hidden Light applies",
        advanced=True,
    )
    contact: float = param(
        1.4,
        label="Contact Height",
        help="With the Object Index pass: a sample never takes light from another object "
        "(Cycles does not scatter between objects). One that lands on another object that "
        "continues the pixel's surface in depth, not below its tangent plane, stands for "
        "the pixel's surface where it meets that object. If that object faces the camera "
        "more squarely than the pixel (a block standing on a table top seen at a slant), "
        "it hides the surface, which runs on under it unlit. Otherwise the pixel's surface "
        "ends on it (a slab's front face on the floor) and, where the pixel lies within "
        "contact·d of that object's surface (d the material's scattering length), loses a "
        "share of the sample's light: 70 % up to a quarter of that height, fading to none "
        "at it, as Cycles' Christensen-Burley loses light at a slab's foot. 0 leaves such "
        "samples to the hidden-surface rules (Mirror Hidden Light, Hidden Light)",
        unit="multiple of the scattering length d",
        lo=0.0,
        ui_hi=1e6,
        soft=(0.0, 4.0),
        advanced=True,
    )
    temporal_mode: str = param(
        "multiplicative",
        label="Temporal Mode",
        help="How the temporal methods (as_ccv_t, as_ocv_t) follow lighting change: divide by a "
        "noise-free separable proxy and accumulate the ratio (multiplicative), or accumulate "
        "the residual after the control and add the current control back (subtractive)",
        choices=TEMPORAL_MODES,
    )
    temporal_min_weight: float = param(
        0.1,
        label="λ min (Temporal)",
        help="Smallest weight of the current frame in the temporal accumulation; 1/λ min is "
        "the longest memory in frames",
        lo=0.0,
        hi=1.0,
        lo_open=True,
        ui_lo=1e-3,
        advanced=True,
    )
    temporal_clamp: float = param(
        2.0,
        label="Temporal Clamp",
        help="Accumulated values are clipped to mean ± k·std of the current 3×3 neighbourhood "
        "(TAA variance clipping) against trails",
        unit="standard deviations",
        lo=0.0,
        ui_hi=1e3,
        advanced=True,
    )
    temporal_tolerance: float = param(
        0.3,
        label="Temporal Tolerance",
        help="τ of the history rectification: a change of ln(proxy) not explained by the "
        "change of ln(control) of δ cuts the accumulated frames by exp(-(δ/τ)²)",
        lo=0.0,
        lo_open=True,
        ui_lo=1e-4,
        ui_hi=1e3,
        advanced=True,
    )
    truncate: float = param(
        16.0,
        label="Truncation",
        help="Profile truncation radius in units of the profile's shape d (Cycles: 16)",
        unit="× d",
        lo=0.0,
        hi=64.0,
        lo_open=True,
        ui_lo=1e-3,
        advanced=True,
    )
    backend: str = param(
        "auto",
        label="Backend",
        help="Implementation of the Monte Carlo sampling step: the compiled numba passes when "
        "numba imports, else NumPy (auto); NumPy; or numba (falls back to NumPy with a warning "
        "where numba is missing). Both take the same samples and agree to float32 rounding",
        choices=BACKENDS,
        advanced=True,
    )
    chunk_samples: int = param(
        1 << 16,
        help="Samples processed in one vectorised batch of the NumPy backend (cache-sized)",
        unit="samples",
        lo=1024,
        hi=1 << 26,
        flag="",
        ui=False,
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.beta_min > self.beta_max:
            raise ParameterError(
                f"beta_min must be <= beta_max, got beta_min={self.beta_min}, "
                f"beta_max={self.beta_max}"
            )

    @property
    def initial_count(self) -> int:
        """n_init, the mean count assumed without history (default β_max: a warm start)."""
        return self.beta_max if self.n_init is None else self.n_init


@dataclass(frozen=True)
class SeparableParams(_Params):
    """Parameters of separable SSS (Jimenez et al. 2015; see core.separable).

    ``terms`` is J, the separable terms of the kernel: the method runs 2J
    one-dimensional passes of ``taps`` taps.
    """

    kernel: str = param(
        "pre_integrated",
        label="Separable Kernel",
        help="Kernel of the separable method: pre-integrated, SVD rank 1–4, sum of Gaussians "
        "or the artist production kernel",
        choices=KERNELS,
    )
    taps: int = param(
        17,
        label="Taps",
        help="Taps per 1D pass of the separable method",
        choices=TAP_COUNTS,
    )
    jitter: bool = param(
        False,
        label="Jitter Taps",
        help="Jitter the taps within the jitter threshold of the kernel's range per pixel "
        "(against banding)",
    )
    jitter_threshold: float = param(
        JITTER_THRESHOLD,
        label="Jitter Threshold",
        help="Share of the kernel range within which taps are jittered (1: all taps)",
        lo=0.0,
        hi=1.0,
        advanced=True,
    )
    gaussians: int = param(
        4,
        label="Gaussians",
        help="N of the sum-of-Gaussians kernel (2N one-dimensional passes)",
        lo=1,
        hi=6,
        advanced=True,
    )
    grid: int = param(
        PROFILE_GRID,
        label="Kernel Grid",
        help="Cells per side (odd) of the discrete 2D profile the kernels are fitted to",
        lo=33,
        hi=513,
        advanced=True,
    )
    follow: str = param(
        "slope",
        label="Follow Surface",
        help="Separable follow-surface rule: the Monte Carlo estimator's depth slope, or the "
        "supplementary's exponential depth correction",
        choices=FOLLOW_RULES,
        advanced=True,
    )
    filter: str = param(
        "nearest",
        label="Tap Filter",
        help="How a separable tap reads the image: the nearest pixel, or linear between two",
        choices=FILTERS,
        advanced=True,
    )

    def __post_init__(self) -> None:
        validate(self)
        if self.grid % 2 == 0:
            raise ParameterError(f"grid must be an odd integer in [33, 513], got {self.grid!r}")

    @property
    def terms(self) -> int:
        """J, separable terms (the method runs 2J one-dimensional passes)."""
        if self.kernel.startswith("svd"):
            return int(self.kernel[3:])
        return self.gaussians if self.kernel == "gaussians" else 1

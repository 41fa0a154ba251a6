"""Scene and material settings of the add-on, and their one mapping to SSSParams.

``scene.sss_settings`` holds the algorithm parameters (defaults: the paper's,
from :data:`core.params.PAPER_DEFAULTS` and :class:`core.params.SSSParams`),
the run settings (method, engine, output folder, frame range) and the
statistics of the last processed frame. ``material.sss_material`` says whether
a material takes part and how its Burley shape ``d`` is obtained.

Every limit below mirrors the check in ``SSSParams.__post_init__`` so the UI
cannot produce a value the core refuses; ``settings_to_params`` builds the
object the operators and the command line pass to the core.
"""

import math

import bpy
import numpy as np
from bpy.props import (
    BoolProperty,
    EnumProperty,
    FloatProperty,
    FloatVectorProperty,
    IntProperty,
    PointerProperty,
    StringProperty,
)
from bpy.types import PropertyGroup

from ...core.methods import METHODS, enum_items
from ...core.params import MAX_SPP, PAPER_DEFAULTS, ParameterError, SSSParams
from ...core.profiles import presets

_DEFAULTS = SSSParams()

#: Measured materials of the separable-SSS supplementary (seeds/004 section G).
PRESET_NAMES = presets.names()

#: Control-variate modes, named as in ``core.methods.Method.cv``.
CV_MODES = (
    ("none", "None", "Track the distant-scattering estimate itself (plain AS)"),
    ("online", "Online", "Online control variate: α from the exponential moving covariance (EMCM)"),
    ("constant", "Constant", "Constant control variate, α = 1 (no extra history)"),
)
_CV_INDEX = {name: i for i, (name, _, _) in enumerate(CV_MODES)}

ENGINES = (
    ("CYCLES", "Cycles", "Render the passes with Cycles"),
    ("EEVEE", "EEVEE", "Render the passes with EEVEE (fewer passes: no Diffuse Indirect)"),
)

# Blender stores IntProperty as a signed 32-bit integer.
_INT_MAX = 2**31 - 1


# -- method and control-variate mode -----------------------------------------------
def _adaptive_method_for(cv: str) -> str:
    """The adaptive method of the table whose control variate is ``cv``."""
    for method in METHODS.values():
        if method.adaptive and method.cv == cv:
            return method.name
    raise ValueError(f"no adaptive method with control variate {cv!r}")


def _get_cv_mode(self) -> int:
    method = METHODS.get(self.method)
    return _CV_INDEX.get(method.cv if method is not None and method.adaptive else "none", 0)


def _set_cv_mode(self, value: int) -> None:
    # The method table pairs each CV mode with one adaptive method: pick it.
    self.method = _adaptive_method_for(CV_MODES[value][0])


# -- keeping ranges ordered ---------------------------------------------------------
def _beta_min_changed(self, _context) -> None:
    if self.beta_max < self.beta_min:
        self.beta_max = self.beta_min


def _beta_max_changed(self, _context) -> None:
    if self.beta_min > self.beta_max:
        self.beta_min = self.beta_max


def _start_changed(self, _context) -> None:
    if self.frame_end < self.frame_start:
        self.frame_end = self.frame_start


def _end_changed(self, _context) -> None:
    if self.frame_start > self.frame_end:
        self.frame_start = self.frame_end


class SSSSettings(PropertyGroup):
    """Parameters and run settings of screen-space subsurface scattering (per scene)."""

    # -- method ----------------------------------------------------------------------
    method: EnumProperty(
        name="Method",
        description="Post-processing method (one table feeds the core, this menu and the CLI)",
        items=enum_items(),
        default="as_ccv",
    )
    cv_mode: EnumProperty(
        name="Control Variate",
        description=(
            "Control variate of the adaptive sampler. Derived from the method: "
            "choosing a mode switches to the adaptive method that uses it"
        ),
        items=CV_MODES,
        get=_get_cv_mode,
        set=_set_cv_mode,
    )

    # -- adaptive sampling (SPVG) ------------------------------------------------------
    eta: FloatProperty(
        name="η (History Rate)",
        description=(
            "Exponential moving coefficient of the per-pixel sample-count history, in (0, 1]. "
            "Larger reacts faster to change, smaller smooths more"
        ),
        default=PAPER_DEFAULTS["eta"],
        min=1e-6,
        max=1.0,
        soft_min=0.01,
        soft_max=1.0,
        step=1,
        precision=3,
    )
    target_variance: FloatProperty(
        name="σ0² (Target Variance)",
        description=(
            "Target variance of the tracked distant-scattering luminance (exposure-scaled, "
            "linear; units of luminance²). Smaller means more samples and higher quality"
        ),
        default=PAPER_DEFAULTS["target_variance"],
        min=1e-12,
        max=1e6,
        soft_min=1e-6,
        soft_max=1e-2,
        step=0.001,
        precision=6,
    )
    eps_u: FloatProperty(
        name="ε_u (Distant Cutoff)",
        description=(
            "Pixels whose largest distant-scattering energy ratio γ is below this get no "
            "samples (unitless, in [0, 1])"
        ),
        default=PAPER_DEFAULTS["eps_u"],
        min=0.0,
        max=1.0,
        soft_max=0.2,
        step=0.1,
        precision=4,
    )
    eps_alpha: FloatProperty(
        name="ε_α (CV Suppression)",
        description=(
            "Suppressing constant of the control-variate coefficient, >= 0 (luminance²); "
            "damps jitter-driven overestimates and gives α = 1 when both moments vanish"
        ),
        default=PAPER_DEFAULTS["eps_alpha"],
        min=0.0,
        max=1e6,
        soft_max=1e-2,
        step=0.001,
        precision=6,
    )
    kappa: FloatProperty(
        name="κ (Correction Weight)",
        description="Weight of the SPVG correction term, in [0, 1] (unitless)",
        default=PAPER_DEFAULTS["kappa"],
        min=0.0,
        max=1.0,
        step=1,
        precision=3,
    )
    beta_min: IntProperty(
        name="β min",
        description="Smallest adaptive sample count per SSS pixel (samples, 1 to 4096)",
        default=PAPER_DEFAULTS["beta_min"],
        min=1,
        max=MAX_SPP,
        soft_max=256,
        update=_beta_min_changed,
    )
    beta_max: IntProperty(
        name="β max",
        description="Largest adaptive sample count per SSS pixel (samples, 1 to 4096)",
        default=PAPER_DEFAULTS["beta_max"],
        min=1,
        max=MAX_SPP,
        soft_max=1024,
        update=_beta_max_changed,
    )
    eta_cv: FloatProperty(
        name="η_cv (Covariance Rate)",
        description=(
            "Exponential moving coefficient of the control-variate covariance history, "
            "in (0, 1]. The paper uses 1e-6 (a very long memory)"
        ),
        default=PAPER_DEFAULTS["eta_cv"],
        min=1e-9,
        max=1.0,
        soft_min=1e-6,
        soft_max=0.5,
        step=0.001,
        precision=6,
    )

    # -- other methods -------------------------------------------------------------------
    fixed_spp: IntProperty(
        name="Fixed Samples",
        description="Samples per pixel of the Fixed N method (1 to 4096)",
        default=_DEFAULTS.fixed_spp,
        min=1,
        max=MAX_SPP,
        soft_max=1024,
    )
    reference_spp: IntProperty(
        name="Reference Samples",
        description="Samples per pixel of the reference used for PSNR (1 to 4096)",
        default=_DEFAULTS.reference_spp,
        min=1,
        max=MAX_SPP,
        soft_min=16,
    )
    use_reference: BoolProperty(
        name="Compute PSNR",
        description=(
            "Also compute the reference (Reference Samples per pixel) each frame and report "
            "the luminance PSNR of the method against it"
        ),
        default=True,
    )
    seed: IntProperty(
        name="Seed",
        description="Seed of the per-pixel random sequence; the same seed gives identical output",
        default=_DEFAULTS.seed,
        min=0,
        max=_INT_MAX,
    )
    history_precision: EnumProperty(
        name="History Precision",
        description="Storage of the per-pixel history",
        items=(
            ("float32", "Float32", "32-bit floats (default)"),
            ("float16", "Float16", "16-bit floats, like the paper's RGBA16F render targets"),
        ),
        default=_DEFAULTS.history_precision,
    )
    exposure: FloatProperty(
        name="Exposure",
        description="Linear scale applied before tracking luminance and computing PSNR (> 0)",
        default=_DEFAULTS.exposure,
        min=1e-6,
        max=1e6,
        soft_min=0.01,
        soft_max=100.0,
        precision=3,
    )
    quality: EnumProperty(
        name="Quality",
        description=(
            "Pick σ0² (and β_min, or N for Fixed) from the calibration that `make bench` "
            "measures and ships, instead of setting them by hand"
        ),
        items=(
            ("MANUAL", "Manual", "Use σ0², β_min and N as set below"),
            ("PSNR", "Target PSNR", "Aim at a mean PSNR in dB against the reference"),
            ("SPP", "Sample Budget", "Aim at a mean number of distant samples per SSS pixel"),
        ),
        default="MANUAL",
    )
    quality_psnr: FloatProperty(
        name="Target PSNR",
        description="Mean luminance PSNR over SSS pixels to aim at, in dB (display-referred)",
        default=45.0,
        min=10.0,
        max=99.0,
        soft_min=30.0,
        soft_max=60.0,
        precision=1,
    )
    quality_spp: FloatProperty(
        name="Sample Budget",
        description="Mean distant samples per SSS pixel to aim at (samples per pixel)",
        default=24.0,
        min=1.0,
        max=float(MAX_SPP),
        soft_min=1.0,
        soft_max=128.0,
        precision=1,
    )

    # -- run settings ------------------------------------------------------------------------
    engine: EnumProperty(
        name="Engine",
        description="Render engine for the passes",
        items=ENGINES,
        default="CYCLES",
    )
    use_normal_pass: BoolProperty(
        name="Normal Pass",
        description="Also render the Normal pass (for bilateral weights; not needed by default)",
        default=False,
    )
    output_dir: StringProperty(
        name="Output",
        description=(
            "Folder for passes/####.exr, <method>/####.exr and metrics.csv; "
            "'//' is relative to the .blend file"
        ),
        default="//cvsss/",
        subtype="DIR_PATH",
    )
    overwrite: BoolProperty(
        name="Overwrite Passes",
        description="Render pass frames again even if their files exist (otherwise they are reused)",
        default=False,
    )
    use_frame_range: BoolProperty(
        name="Custom Range",
        description="Use the frame range below instead of the scene's",
        default=False,
    )
    frame_start: IntProperty(
        name="Start",
        description="First frame to process (frames >= 0)",
        default=1,
        min=0,
        max=_INT_MAX,
        update=_start_changed,
    )
    frame_end: IntProperty(
        name="End",
        description="Last frame to process (inclusive)",
        default=250,
        min=0,
        max=_INT_MAX,
        update=_end_changed,
    )

    # -- statistics of the last processed frame (written by the operators) --------------------
    has_stats: BoolProperty(name="Has Statistics", default=False)
    last_frame: IntProperty(name="Frame", description="Last processed frame", default=0)
    last_method: StringProperty(name="Method", description="Method of the statistics", default="")
    last_spp: FloatProperty(
        name="Mean spp",
        description="Mean distant samples per SSS pixel of the last processed frame",
        default=0.0,
        min=0.0,
    )
    last_pass_ms: FloatProperty(
        name="Pass Time",
        description="Wall time of the Monte Carlo sampling step of the last frame (ms)",
        default=0.0,
        min=0.0,
        unit="NONE",
    )
    last_psnr: FloatProperty(
        name="PSNR",
        description="Luminance PSNR over SSS pixels against the reference (dB); 0 = not computed",
        default=0.0,
    )


class SSSMaterialSettings(PropertyGroup):
    """Whether and how a material takes part in screen-space subsurface scattering."""

    mode: EnumProperty(
        name="Subsurface",
        description="Whether this material takes part in screen-space subsurface scattering",
        items=(
            ("AUTO", "Auto", "Take part when a Principled BSDF has Subsurface Weight > 0"),
            ("ON", "On", "Always take part"),
            ("OFF", "Off", "Never take part (Cycles renders its subsurface as usual)"),
        ),
        default="AUTO",
    )
    participates: BoolProperty(
        name="Takes Part",
        description="This material takes part (from the mode and its Principled BSDF)",
        get=lambda self: _material_participates(self.id_data),
    )
    use_override: BoolProperty(
        name="Override d",
        description="Use the Burley shape below instead of the Principled BSDF's",
        default=False,
    )
    d_override: FloatVectorProperty(
        name="d",
        description="Burley shape d per channel (R, G, B), scene units",
        size=3,
        default=(0.00398, 0.000796, 0.000398),
        min=0.0,
        soft_max=1.0,
        precision=5,
        step=0.01,
        subtype="NONE",
        unit="LENGTH",
    )
    preset: EnumProperty(
        name="Measured Preset",
        description=(
            "Measured material (Jensen et al. 2001): its Burley shape d = ℓ/s(A) replaces the "
            "Principled BSDF's, and the choice travels with the passes"
        ),
        items=[("NONE", "None", "Use the Principled BSDF or the override")]
        + [(name.upper(), name, f"Measured material '{name}'") for name in PRESET_NAMES],
        default="NONE",
    )
    preset_scale: FloatProperty(
        name="Preset Scale",
        description=(
            "Artist multiplier of the measured scattering distances (1 = real size for a "
            "scene modelled at real size; unitless)"
        ),
        default=1.0,
        min=1e-6,
        soft_min=0.01,
        soft_max=1000.0,
        precision=3,
    )


def _material_participates(material) -> bool:
    from .materials import participates

    return participates(material)


#: Methods the Quality setting applies to (those with σ0² or N in the calibration).
QUALITY_METHODS = ("fixed", "as", "as_ocv", "as_ccv")


def settings_to_params(settings: SSSSettings, method: str | None = None) -> SSSParams:
    """Build the core's parameter object from ``scene.sss_settings``.

    Parameters
    ----------
    settings : SSSSettings
    method : str, optional
        The method the parameters are for (default ``settings.method``).

    Returns
    -------
    SSSParams

    Raises
    ------
    core.params.ParameterError
        ``quality`` set but the shipped calibration cannot be read.

    With ``quality`` other than MANUAL and a method of :data:`QUALITY_METHODS`,
    σ0² and β_min (``fixed``: N) come from :func:`core.quality.apply` on the
    shipped calibration; other methods have neither and ignore it.
    """
    params = SSSParams(
        eta=_decimal(settings.eta),
        target_variance=_decimal(settings.target_variance),
        eps_u=_decimal(settings.eps_u),
        eps_alpha=_decimal(settings.eps_alpha),
        kappa=_decimal(settings.kappa),
        beta_min=int(settings.beta_min),
        beta_max=int(settings.beta_max),
        eta_cv=_decimal(settings.eta_cv),
        fixed_spp=int(settings.fixed_spp),
        reference_spp=int(settings.reference_spp),
        seed=int(settings.seed),
        history_precision=str(settings.history_precision),
        exposure=_decimal(settings.exposure),
    )
    quality = getattr(settings, "quality", "MANUAL")
    method = settings.method if method is None else method
    if quality == "MANUAL" or method not in QUALITY_METHODS:
        return params
    from ...core.eval import quality as calibrated

    target = f"{settings.quality_psnr:g}dB" if quality == "PSNR" else f"{settings.quality_spp:g}spp"
    try:
        return calibrated.apply(params, target, method)[0]
    except (OSError, ValueError) as exc:  # a missing or unreadable calibration file
        raise ParameterError(f"quality: {exc}") from None


def _decimal(value: float) -> float:
    """The shortest decimal that rounds to Blender's float32 value (0.2, not 0.2000000029…),
    so the UI's defaults give exactly the paper's parameters."""
    return float(str(np.float32(value)))


def frame_range(scene) -> tuple[int, int]:
    """Inclusive frame range to process: the override or the scene's."""
    s = scene.sss_settings
    if s.use_frame_range:
        return int(s.frame_start), int(s.frame_end)
    return int(scene.frame_start), int(scene.frame_end)


def store_stats(
    settings: SSSSettings,
    frame: int,
    method: str,
    spp: float,
    pass_ms: float,
    psnr_db: float | None,
) -> None:
    """Record the statistics of the last processed frame on the settings."""
    settings.last_frame = int(frame)
    settings.last_method = method
    settings.last_spp = float(spp)
    settings.last_pass_ms = float(pass_ms)
    settings.last_psnr = 0.0 if psnr_db is None or not math.isfinite(psnr_db) else float(psnr_db)
    settings.has_stats = True


classes = (SSSSettings, SSSMaterialSettings)
_register_classes, _unregister_classes = bpy.utils.register_classes_factory(classes)


def register() -> None:
    _register_classes()
    bpy.types.Scene.sss_settings = PointerProperty(type=SSSSettings)
    bpy.types.Material.sss_material = PointerProperty(type=SSSMaterialSettings)


def unregister() -> None:
    del bpy.types.Material.sss_material
    del bpy.types.Scene.sss_settings
    _unregister_classes()

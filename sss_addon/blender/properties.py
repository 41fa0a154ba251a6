"""Scene and material settings of the add-on, and their one mapping to SSSParams.

``scene.sss_settings`` holds the algorithm parameters, the run settings
(method, engine, output folder, frame range) and the statistics of the last
processed frame. ``material.sss_material`` says whether a material takes part
and how its Burley shape ``d`` is obtained.

The parameter properties are generated from the specs of core.params
(SSSParams, ProfileChoice, SeparableParams: label, help, unit, range and
default live with each field), so the UI cannot produce a value the core
refuses and shows every parameter the command line takes;
``settings_to_params`` and ``settings_to_options`` build the objects the
operators pass to the core.
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

from ...core.eval import quality as calibrated
from ...core.method import MethodOptions
from ...core.methods import METHODS, enum_items
from ...core.params import MAX_SPP, ParameterError, SeparableParams, SSSParams, specs
from ...core.profiles import presets
from ...core.profiles.factory import ProfileChoice
from . import materials as sss_materials
from .whole_parts import whole_parts_text

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

#: Cycles subsurface methods of the ground truth (Blender identifiers, sss_addon.blender.ground_truth).
# Numbered: a .blend stores the number, and BURLEY and RANDOM_WALK keep theirs.
GROUND_TRUTH_METHODS = (
    (
        "MATERIAL",
        "Each Material's Own",
        "Each material's own Subsurface Method (Christensen-Burley, Random Walk or Random "
        "Walk (Skin)): what the post models per material",
        2,
    ),
    (
        "BURLEY",
        "Christensen-Burley",
        "Every material with Cycles' Christensen-Burley subsurface",
        0,
    ),
    (
        "RANDOM_WALK",
        "Random Walk",
        "Every material with Cycles' random-walk subsurface",
        1,
    ),
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


# -- properties generated from the parameter specs of core.params ---------------------
#: (dataclass, property prefix): every field with ``Spec.ui`` becomes ``prefix + name``.
PARAM_GROUPS = ((SSSParams, ""), (ProfileChoice, ""), (SeparableParams, "separable_"))

#: Enum identifier standing for ``None`` (ProfileChoice.profile: each material's own).
PER_MATERIAL = "MATERIAL"

#: Extra keywords of generated properties (update callbacks keeping ranges ordered).
_EXTRA = {
    "beta_min": {"update": _beta_min_changed},
    "beta_max": {"update": _beta_max_changed},
}


def _limit(value, fallback):
    return fallback if value is None else value


def _param_property(f, spec):
    """The bpy property of one parameter field, from its Spec."""
    name = spec.label or f.name.replace("_", " ").title()
    description = spec.describe()
    default = f.default
    extra = _EXTRA.get(f.name, {})
    if spec.choices is not None:
        items = [(str(c), str(c).replace("_", " ").title(), f"{name}: {c}") for c in spec.choices]
        if default is None:
            items.insert(0, (PER_MATERIAL, "Per Material", "Each material's own (Principled BSDF)"))
        return EnumProperty(
            name=name,
            description=description,
            items=items,
            default=PER_MATERIAL if default is None else str(default),
            **extra,
        )
    if f.type in ("bool", bool):
        return BoolProperty(name=name, description=description, default=default, **extra)
    soft = spec.soft or (None, None)
    if f.type in ("int", "int | None"):
        lo = int(_limit(spec.ui_lo, _limit(spec.lo, -_INT_MAX)))
        hi = int(min(_limit(spec.ui_hi, _limit(spec.hi, _INT_MAX)), _INT_MAX))
        return IntProperty(
            name=name,
            description=description,
            default=default,
            min=lo,
            max=hi,
            soft_min=int(_limit(soft[0], lo)),
            soft_max=int(_limit(soft[1], hi)),
            **extra,
        )
    lo = float(_limit(spec.ui_lo, _limit(spec.lo, -1e30)))
    hi = float(_limit(spec.ui_hi, _limit(spec.hi, 1e30)))
    return FloatProperty(
        name=name,
        description=description,
        default=default,
        min=lo,
        max=hi,
        soft_min=float(_limit(soft[0], lo)),
        soft_max=float(_limit(soft[1], hi)),
        precision=spec.precision,
        step=1,
        **extra,
    )


def param_properties() -> dict[str, tuple]:
    """``{property name: (dataclass, field, spec)}`` of every generated property."""
    out = {}
    for cls, prefix in PARAM_GROUPS:
        for f, spec in specs(cls):
            if spec.ui:
                out[prefix + f.name] = (cls, f, spec)
    return out


#: ``thin_walks``: who renders the subsurface of thin parts (sss_addon/blender/thin_parts.py).
THIN_WALKS = (
    (
        "CYCLES",
        "Cycles",
        f"Cycles renders the subsurface of objects {whole_parts_text()}, and of "
        "points near their own far side or an edge (ears, fins, rims) of both, as in a plain "
        "render: its walk and its disk probes reach surface screen space cannot see. Cycles "
        "passes only",
    ),
    (
        "POST",
        "Post-Process",
        "The post-process renders them like every other object: faster, further from Cycles",
    ),
)


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
    use_reference: BoolProperty(
        name="Compute PSNR",
        description=(
            "Also compute the reference (Reference Samples per pixel) each frame and report "
            "the luminance PSNR of the method against it"
        ),
        default=True,
    )

    # -- quality knob --------------------------------------------------------------------
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

    # -- Blender's own render (apply_on_render/) --------------------------------------------
    apply_on_render: BoolProperty(
        name="Apply on Render",
        description=(
            "Every normal render of this scene (F12, Ctrl-F12, blender -b -f/-a) renders the "
            "passes with the scene's engine (Cycles or EEVEE), runs the method and writes the "
            "finished frames to the scene's output path and format; materials, passes and "
            "output settings are restored afterwards"
        ),
        default=False,
    )
    warmup_frames: IntProperty(
        name="Warm-up Frames",
        description=(
            "Apply on Render: render and process this many frames before the first frame of "
            "an animation, without writing them, so the first delivered frame has a history "
            "and is as steady as the rest (each costs a pass render plus its post-process). "
            "Only for the temporal methods, which reuse their history's estimates; a still "
            "renders none"
        ),
        default=8,
        min=0,
        max=10_000,
        soft_max=64,
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
    use_denoise_passes: BoolProperty(
        name="Denoise Passes",
        description=(
            "Denoise Combined and the Diffuse passes with Blender's OpenImageDenoise (guided by "
            "Cycles' Denoising Albedo and Normal) before the post-process reads them, instead "
            "of denoising the finished frame as the scene's denoiser asks. Cycles passes "
            "only; pass files made with the other setting are rendered again"
        ),
        default=False,
    )
    thin_walks: EnumProperty(
        name="Thin Parts",
        description=(
            f"Who renders the subsurface of objects {whole_parts_text()}, and of points near "
            "their far side or an edge (Cycles reaches surface the camera does not see there)"
        ),
        items=THIN_WALKS,
        default="CYCLES",
    )
    use_denoise_subsurface: BoolProperty(
        name="Denoise Subsurface",
        description=(
            "EEVEE passes: denoise the post's light on the subsurface pixels with Blender's "
            "OpenImageDenoise, before the surface colour multiplies it. EEVEE's passes carry "
            "no noise, the post's samples do; every other pixel stays EEVEE's"
        ),
        default=True,
    )
    use_ground_truth: BoolProperty(
        name="Ground Truth",
        description=(
            "Also render the frames with Cycles' own subsurface on (always Cycles, also when "
            "the passes use EEVEE; denoising off, fixed seed) into ground_truth/####.exr, and "
            "report the PSNR of the result against it"
        ),
        default=False,
    )
    ground_truth_samples: IntProperty(
        name="Samples",
        description="Samples per pixel of the ground-truth render (at least 1024 for a reference)",
        default=1024,
        min=1,
        max=2**24,
        soft_min=16,
        soft_max=16384,
    )
    ground_truth_every: IntProperty(
        name="Every",
        description=(
            "Render the ground truth on every k-th frame of the range only (the 1st, the "
            "(k+1)-th, …)"
        ),
        default=1,
        min=1,
        max=_INT_MAX,
        soft_max=100,
    )
    ground_truth_method: EnumProperty(
        name="Method",
        description="Cycles' subsurface method in the ground-truth render",
        items=GROUND_TRUTH_METHODS,
        default="MATERIAL",
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
        name="Overwrite",
        description=(
            "Render pass frames again even if their files exist and start the post-process "
            "over (otherwise passes are reused and the post-process resumes where a run with "
            "the same settings stopped; passes made with another camera, resolution or "
            "material stop the run with a message). Needed after changing lights or geometry"
        ),
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
    last_sampling_ms: FloatProperty(
        name="Sampling Time",
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
    last_psnr_gt: FloatProperty(
        name="PSNR vs Cycles",
        description=(
            "RGB PSNR over SSS pixels against the Cycles ground truth (dB, display-referred); "
            "0 = no ground truth on that frame"
        ),
        default=0.0,
    )


SSSSettings.__annotations__.update(
    {name: _param_property(f, spec) for name, (_, f, spec) in param_properties().items()}
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
        get=lambda self: sss_materials.participates(self.id_data),
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


#: Methods the Quality setting applies to (those with σ0² or N in the calibration).
QUALITY_METHODS = ("fixed", "as", "as_ocv", "as_ccv")


def _group_values(settings, cls, prefix: str) -> dict:
    """Values of a parameters dataclass's generated properties, as the core takes them."""
    values = {}
    for f, spec in specs(cls):
        if not spec.ui:
            continue
        value = getattr(settings, prefix + f.name)
        if spec.choices is not None:
            if value == PER_MATERIAL:
                value = None
            elif isinstance(spec.choices[0], int):
                value = int(value)
        elif isinstance(value, float):
            value = _decimal(value)
        values[f.name] = value
    return values


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
    σ0² and β_min (``fixed``: N) come from :func:`core.eval.quality.apply` on the
    shipped calibration; other methods have neither and ignore it.
    """
    params = SSSParams(**_group_values(settings, SSSParams, ""))
    quality = getattr(settings, "quality", "MANUAL")
    method = settings.method if method is None else method
    if quality == "MANUAL" or method not in QUALITY_METHODS:
        return params
    target = f"{settings.quality_psnr:g}dB" if quality == "PSNR" else f"{settings.quality_spp:g}spp"
    try:
        return calibrated.apply(params, target, method)[0]
    except (OSError, ValueError) as exc:  # a missing or unreadable calibration file
        raise ParameterError(f"quality: {exc}") from None


def settings_to_options(settings: SSSSettings) -> MethodOptions:
    """The profile choice and separable kernel of ``scene.sss_settings``.

    Measured presets are per material (their Subsurface (cvsss) panel) and
    travel with the passes; the scene setting picks the profile kind.
    """
    choice = ProfileChoice(**_group_values(settings, ProfileChoice, ""))
    return MethodOptions(
        profile=None if choice.is_default else choice,
        separable=SeparableParams(**_group_values(settings, SeparableParams, "separable_")),
    )


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
    sampling_ms: float,
    psnr_db: float | None,
    psnr_gt_db: float | None = None,
) -> None:
    """Record the statistics of the last processed frame on the settings.

    ``psnr_db`` is against the reference, ``psnr_gt_db`` against the Cycles
    ground truth; None (not computed) is stored as 0.
    """
    settings.last_frame = int(frame)
    settings.last_method = method
    settings.last_spp = float(spp)
    settings.last_sampling_ms = float(sampling_ms)
    settings.last_psnr = _stat(psnr_db)
    settings.last_psnr_gt = _stat(psnr_gt_db)
    settings.has_stats = True


def _stat(value: float | None) -> float:
    return 0.0 if value is None or not math.isfinite(value) else float(value)


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

"""The user's renders and Cycles' ground truth of a scene, for ``cvsss compare``.

Issue 44 measures every change by the user's frame against what they had.
This module renders a scene's frames the ways a user does, through Blender's
own render operator:

*plain*
    the scene's engine as set (Cycles with its own subsurface and denoiser, or
    EEVEE), ``bpy.ops.render.render(animation=True)`` over the frames;
*Apply on Render*
    the same render with ``sss_settings.apply_on_render`` ticked and the
    scene's add-on settings (the defaults unless the user changed them): the
    frames it delivers, its set-up, warm-up frames and the numba kernels'
    loading included in the time;
*without subsurface*
    the plain render with every Subsurface Weight at 0 (the effect's
    ``frame_off``);

and Cycles' ground truth with and without subsurface (:class:`TruthSetup`:
the scene as set up, each material's own subsurface method, denoising and
adaptive sampling off, a fixed seed), and which object each pixel shows
(:func:`render_objects`: Cycles' Object Index pass, one sample, every object
numbered for it and its Pass Index put back afterwards). A :class:`Setting` chooses the engine,
its samples and Cycles' denoiser; a method *variant* switches every
Principled BSDF of the scene to ``RANDOM_WALK`` or ``BURLEY`` for all the
renders of that variant, ground truth included (``material`` keeps the
materials' own).

Frames are written as 32-bit OpenEXR (linear) into a folder of the caller;
the output path, format, frame range, engine settings, subsurface methods
and weights and the add-on's switch are the user's again after every render,
also on error (:class:`UserRender`, :class:`MethodSwitch` and
:class:`.materials.SSSDisabled`). Only the whole frame is compared, so the
render border is off in every render, as Apply on Render's is.

:mod:`.compare` runs them all for ``cvsss compare`` and measures the frames.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import bpy

from ...core.io.atomic import write_text
from . import materials as sss_materials
from .apply_on_render.session import forget_history
from .errors import RenderError
from .passes import (
    SceneSetup,
    engine_identifier,
    fresh_cycles_state,
    number_objects,
    pass_indices,
    put_back_pass_indices,
    read_record,
    render_to,
)

#: Method variants: the materials' own, or every Principled BSDF switched to one.
VARIANTS = ("material", "RANDOM_WALK", "BURLEY")

#: Cycles seed of the ground truth.
SEED = 0

#: Value of the ``format`` field of a ground-truth frame's record.
TRUTH_FORMAT = "cvsss-users-frame-truth/1"


@dataclass(frozen=True)
class Setting:
    """How the user renders: the engine, its samples, Cycles' denoiser.

    Attributes
    ----------
    engine : {"CYCLES", "EEVEE"}
    samples : int or None
        Cycles' samples per pixel or EEVEE's render samples; None keeps the scene's.
    denoise : bool
        Cycles' own denoiser on (the scene's denoiser, OpenImageDenoise by
        default); EEVEE has none.
    """

    engine: str
    samples: int | None = None
    denoise: bool = True

    def __post_init__(self) -> None:
        if self.engine not in ("CYCLES", "EEVEE"):
            raise ValueError(f"engine must be CYCLES or EEVEE, got {self.engine!r}")
        if self.samples is not None and self.samples < 1:
            raise ValueError(f"samples must be >= 1, got {self.samples}")

    def resolved(self, scene) -> Setting:
        """This setting with the scene's samples filled in (and no denoiser for EEVEE)."""
        samples = self.samples
        if samples is None:
            samples = scene.cycles.samples if self.engine == "CYCLES" else _eevee_samples(scene)
        return Setting(self.engine, int(samples), self.denoise and self.engine == "CYCLES")

    @property
    def folder(self) -> str:
        """``cycles_16_denoised``, ``eevee_64``: the folder name of its renders."""
        name = f"{self.engine.lower()}_{self.samples}"
        return name + ("_denoised" if self.denoise else "")


def _eevee_samples(scene) -> int:
    return int(scene.eevee.taa_render_samples)


# -- what the user's scene holds ------------------------------------------------------------
def principled_in(materials) -> list:
    """Every Principled BSDF of ``materials`` (node groups once)."""
    seen, out = set(), []
    for material in materials:
        for _, node in sss_materials.principled_nodes(getattr(material, "node_tree", None)):
            if node.as_pointer() not in seen:
                seen.add(node.as_pointer())
                out.append(node)
    return out


def materials_method(materials) -> str:
    """The subsurface method the participating materials use: one of Blender's
    identifiers, or ``"mixed"``; ``"none"`` without one."""
    methods = set()
    for node in principled_in(materials):
        socket = node.inputs.get(sss_materials.WEIGHT)
        if socket is not None and (sss_materials.live_links(socket) or socket.default_value > 0.0):
            methods.add(node.subsurface_method)
    if not methods:
        return "none"
    return methods.pop() if len(methods) == 1 else "mixed"


def resolve_variants(variants: Sequence[str], own: str) -> list[tuple[str, str]]:
    """(variant, method) pairs to render: ``material`` with the materials' own method
    ``own``, and each switched method that is not the same as ``own`` (rendered once)."""
    out = []
    for variant in dict.fromkeys(variants):
        if variant not in VARIANTS:
            raise RenderError(
                f"method variant must be one of {', '.join(VARIANTS)}, got {variant!r}"
            )
        method = own if variant == "material" else variant
        if variant != "material" and "material" in variants and method == own:
            continue
        out.append((variant, method))
    return out


class MethodSwitch(contextlib.AbstractContextManager):
    """Every Principled BSDF of ``materials`` uses ``method`` inside the block (None: as
    they are); the methods are put back on exit, also on error."""

    def __init__(self, materials, method: str | None) -> None:
        self.nodes = principled_in(materials) if method else []
        self.method = method
        self.saved: list[tuple[object, str]] = []

    def __enter__(self) -> MethodSwitch:
        try:
            for node in self.nodes:
                self.saved.append((node, node.subsurface_method))
                if node.subsurface_method != self.method:
                    node.subsurface_method = self.method
        except BaseException:
            self.restore()
            raise
        return self

    def restore(self) -> None:
        for node, method in reversed(self.saved):
            if node.subsurface_method != method:
                node.subsurface_method = method
        self.saved = []

    def __exit__(self, *exc) -> None:
        self.restore()


class _SceneExtras(SceneSetup):
    """:class:`.passes.SceneSetup` plus what it does not record: the frame range and
    current frame, and the add-on's Apply on Render switch."""

    def _record_extras(self) -> None:
        scene = self.scene
        self._extras = (
            scene.frame_start,
            scene.frame_end,
            scene.frame_step,
            scene.frame_current,
            scene.frame_subframe,
            scene.sss_settings.apply_on_render,
        )

    def __enter__(self):
        self._record_extras()
        return super().__enter__()

    def restore(self) -> None:
        extras = getattr(self, "_extras", None)
        if extras is not None:
            scene = self.scene
            start, end, step, current, subframe, apply = extras
            scene.frame_start, scene.frame_end, scene.frame_step = start, end, step
            scene.sss_settings.apply_on_render = apply
            scene.frame_set(current, subframe=subframe)
            self._extras = None
        super().restore()


class UserRender(_SceneExtras):
    """The scene rendering as the user renders it, with ``setting``; restored on exit.

    Only what the comparison needs changes: the engine, its samples and
    denoiser (:class:`Setting`), the frame range, the whole frame (border
    off), Apply on Render on or off, and the output: 32-bit RGBA OpenEXR
    (linear) at ``<folder>/<prefix>####.exr``, overwriting.
    """

    def __init__(
        self,
        scene,
        view_layer,
        setting: Setting,
        frames: tuple[int, int],
        path_prefix: Path,
        apply_on_render: bool,
    ) -> None:
        super().__init__(scene, view_layer)
        self.setting = setting
        self.frames = frames
        self.path_prefix = Path(path_prefix)
        self.apply_on_render = apply_on_render

    def _apply(self) -> None:
        scene, setting = self.scene, self.setting
        r = scene.render
        wanted = engine_identifier(scene, setting.engine)
        if r.engine != wanted:
            r.engine = wanted
        if setting.engine == "CYCLES":
            scene.cycles.samples = setting.samples
            scene.cycles.use_denoising = setting.denoise
            layer_cycles = getattr(self.view_layer, "cycles", None)
            if setting.denoise and layer_cycles is not None:
                layer_cycles.use_denoising = True
        else:
            scene.eevee.taa_render_samples = setting.samples
        r.use_border = False
        r.filepath = str(self.path_prefix)
        r.use_file_extension = True
        r.use_overwrite = True
        r.use_placeholder = False
        s = r.image_settings
        if hasattr(s, "media_type"):
            s.media_type = "IMAGE"
        s.file_format = "OPEN_EXR"
        s.color_mode = "RGBA"
        s.color_depth = "32"
        s.exr_codec = "ZIP"
        scene.frame_start, scene.frame_end = self.frames
        scene.frame_step = 1
        scene.sss_settings.apply_on_render = self.apply_on_render


class TruthSetup(_SceneExtras):
    """Cycles' ground truth of the scene as set up: each material's own subsurface method
    (or the variant's, switched by :class:`MethodSwitch` around it), ``samples`` per
    pixel, denoising, adaptive sampling and the time limit off, Cycles' ``seed``
    (:data:`SEED`; another gives an independent ground truth, to measure its own
    noise), Combined only, 32-bit multilayer EXR; restored on exit."""

    def __init__(self, scene, view_layer, samples: int, seed: int = SEED) -> None:
        super().__init__(scene, view_layer)
        self.samples = int(samples)
        self.seed = int(seed)

    def _apply(self) -> None:
        scene = self.scene
        scene.render.engine = "CYCLES"
        self._output_exr()
        c = scene.cycles
        c.samples = self.samples
        c.use_adaptive_sampling = False
        c.time_limit = 0.0
        c.seed = self.seed
        c.use_animated_seed = False
        c.use_denoising = False
        self._only_layer(lambda ident: ident == "use_pass_combined")


# -- rendering -----------------------------------------------------------------------------
@dataclass
class Timing:
    """Wall time of one animation render.

    Attributes
    ----------
    total : seconds from the call to the operator's return
    setup : seconds before the first frame began (``render_pre`` of the user's scene;
        Apply on Render warms up before it)
    frames : the frames Blender began, in order
    """

    total: float
    setup: float
    frames: list[int]

    def to_dict(self) -> dict:
        n = max(1, len(self.frames))
        return {
            "total_seconds": self.total,
            "setup_seconds": self.setup,
            "seconds_per_frame": self.total / n,
            "steady_seconds_per_frame": (self.total - self.setup) / n,
        }


def render_animation(scene) -> Timing:
    """``bpy.ops.render.render(animation=True)`` of ``scene`` as set up, timed."""
    starts: list[tuple[int, float]] = []
    name = scene.name

    def mark(rendered, *_args) -> None:
        # Apply on Render's warm-up and delivery renders are of scenes of their own.
        if rendered.name == name:
            starts.append((int(rendered.frame_current), time.perf_counter()))

    fresh_cycles_state(scene)
    bpy.app.handlers.render_pre.append(mark)
    began = time.perf_counter()
    try:
        with bpy.context.temp_override(scene=scene):
            result = bpy.ops.render.render(animation=True, scene=name)
    finally:
        ended = time.perf_counter()
        bpy.app.handlers.render_pre.remove(mark)
    if "FINISHED" not in result:
        raise RenderError(f"the render of {name!r} was cancelled")
    setup = starts[0][1] - began if starts else ended - began
    return Timing(ended - began, setup, [f for f, _ in starts])


def frame_file(prefix: Path, frame: int) -> Path:
    """Where Blender writes ``frame`` of a render to ``<prefix>`` (OpenEXR)."""
    return Path(f"{prefix}{frame:04d}.exr")


def render_user(
    scene,
    view_layer,
    setting: Setting,
    frames: tuple[int, int],
    prefix: Path,
    *,
    apply_on_render: bool,
    subsurface: bool = True,
    materials=(),
) -> Timing:
    """Render the frames as the user would (module doc) to ``<prefix>####.exr``.

    ``subsurface=False`` renders with every Subsurface Weight of ``materials`` at 0.
    Apply on Render starts from a fresh history, as the first render of a
    session does.

    Raises
    ------
    RenderError
        The render was cancelled or a frame was not written (Apply on Render
        says why on stdout, ``cvsss: error: …``).
    """
    Path(prefix).parent.mkdir(parents=True, exist_ok=True)
    for frame in range(frames[0], frames[1] + 1):
        with contextlib.suppress(FileNotFoundError):
            frame_file(prefix, frame).unlink()
    off = sss_materials.SSSDisabled(materials) if not subsurface else contextlib.nullcontext()
    if apply_on_render:
        forget_history()
    with off, UserRender(scene, view_layer, setting, frames, prefix, apply_on_render):
        timing = render_animation(scene)
    missing = [f for f in range(frames[0], frames[1] + 1) if not frame_file(prefix, f).is_file()]
    if missing:
        what = "Apply on Render delivered" if apply_on_render else "Blender wrote"
        raise RenderError(
            f"{what} no frame {missing[0]} of {frames[0]}-{frames[1]} into {Path(prefix).parent}"
        )
    return timing


def blend_digest(path: str | None) -> str | None:
    """SHA-256 of the .blend file (the ground truth is rendered again when it changes)."""
    if not path:
        return None
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return None


def render_truth(
    scene,
    view_layer,
    frame: int,
    path: Path,
    samples: int,
    *,
    subsurface: bool,
    materials,
    record: dict,
    seed: int = SEED,
) -> bool:
    """Render the ground truth of ``frame`` to ``path`` unless a file with the same
    ``record`` (``<path>.json``) is there; whether it rendered.

    ``record`` says what the frame is of (the .blend's digest, the method, with or
    without subsurface); without a digest (a scene never saved) it is always rendered.
    ``seed``: Cycles' seed (:class:`TruthSetup`).
    """
    record = {"format": TRUTH_FORMAT, "frame": frame, "samples": samples, "seed": seed} | record
    reusable = record.get("blend_sha256") is not None
    if reusable and path.is_file() and read_record(path.with_suffix(".json")) == record:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    off = sss_materials.SSSDisabled(materials) if not subsurface else contextlib.nullcontext()
    with off, TruthSetup(scene, view_layer, samples, seed):
        scene.frame_set(frame)
        render_to(scene, path)
    write_text(path.with_suffix(".json"), json.dumps(record, indent=2) + "\n")
    return True


class ObjectIndexSetup(_SceneExtras):
    """Which object each pixel shows: Cycles at one sample, denoising off, the Object
    Index pass alone, 32-bit multilayer EXR, every object of the scene numbered
    (:func:`.passes.number_objects`, ``materials``' carriers first); the scene and the
    objects' Pass Index restored on exit."""

    def __init__(self, scene, view_layer, materials) -> None:
        super().__init__(scene, view_layer)
        self.materials = list(materials)
        self._indices: dict[str, int] | None = None

    def __enter__(self) -> ObjectIndexSetup:
        # Saved first: a failing set-up restores (SceneSetup) and puts them back.
        self._indices = pass_indices(bpy.data.objects)
        return super().__enter__()

    def _apply(self) -> None:
        scene = self.scene
        scene.render.engine = "CYCLES"
        self._output_exr()
        c = scene.cycles
        c.samples = 1
        c.use_adaptive_sampling = False
        c.time_limit = 0.0
        c.use_denoising = False
        self._only_layer(lambda ident: ident in ("use_pass_combined", "use_pass_object_index"))
        number_objects(scene, self.materials)

    def numbers(self) -> dict[int, str]:
        """Object Index -> object name, as numbered (0, unnumbered objects: left out)."""
        return {o.pass_index: o.name for o in self.scene.objects if o.pass_index > 0}

    def restore(self) -> None:
        try:
            super().restore()
        finally:
            if self._indices is not None:
                put_back_pass_indices(bpy.data.objects, self._indices)
                self._indices = None


def render_objects(scene, view_layer, frame: int, path: Path, materials) -> dict[int, str]:
    """Render which object each pixel of ``frame`` shows to ``path`` (its Object Index
    pass, :class:`ObjectIndexSetup`) and write ``<path>.json``: {number: object name}.

    Returns
    -------
    dict, Object Index -> object name
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    with ObjectIndexSetup(scene, view_layer, materials) as setup:
        scene.frame_set(frame)
        render_to(scene, path)
        names = setup.numbers()
    write_text(path.with_suffix(".json"), json.dumps({str(k): v for k, v in names.items()}) + "\n")
    return names

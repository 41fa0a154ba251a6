"""Render passes and post-process a frame range: the job behind the operators and ``cvsss render``.

Work is a per-frame step generator so the same code runs to the end in
background mode (:func:`render_sequence`) and one frame per timer tick in the
UI (the modal operators), where closing the generator cancels cleanly.

Layout under the output folder::

    passes/####.exr + ####.json   multilayer pass EXR and its sidecar (resumable)
    <method>/####.exr             result layers (core.exr.write_result)
    metrics.csv                   frame,method,spp,pass_ms,psnr_db

The reference (1024 spp) costs as much as all other methods together: with
``reference_every = k`` it is computed on every k-th frame of the range only
(the first, the (k+1)-th, …; it keeps no history, so any subset is exact)
and PSNR is reported on those frames.

Pass frames that exist are reused unless ``overwrite``. The post-process
carries a per-pixel history from frame to frame, so it always runs from the
first frame of the range and rewrites the result files.
"""

from __future__ import annotations

import os
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import bpy

from ...core.eval.metrics import psnr
from ...core.io.exr import read_frame, write_result
from ...core.mc.processor import FrameResult, SequenceProcessor
from ...core.methods import METHODS
from ...core.params import SSSParams
from ..cli.post import format_clock, format_metrics, write_text_atomic
from . import materials as sss_materials
from .passes import (
    PassSetup,
    RenderError,
    engine_identifier,
    frame_done,
    pass_path,
    render_frame,
    render_view_layer,
    scene_camera,
)

__all__ = [
    "Job",
    "RenderError",
    "Step",
    "apply_frame",
    "iter_passes",
    "iter_sequence",
    "job_from_scene",
    "prepare",
    "render_sequence",
    "resolve_output_dir",
]

Log = Callable[[str], None] | None


@dataclass
class Job:
    """Validated inputs of a pass render / sequence run (see :func:`prepare`)."""

    scene: object
    view_layer: object
    frames: list[int]
    out: Path
    methods: list[str]
    params: SSSParams
    engine: str = "CYCLES"
    overwrite: bool = False
    normal: bool = False
    materials: list = field(default_factory=list)
    images: bool = False
    display: str = ""
    log: Log = None
    reference_every: int = 1

    @property
    def passes_dir(self) -> Path:
        return self.out / "passes"


@dataclass
class Step:
    """What one step (one frame) did.

    Attributes
    ----------
    index, total : int
        1-based position of the frame in the range, and the range length.
    frame : int
    path : Path, the pass EXR
    rendered : bool, False when an existing pass file was reused
    seconds : float, wall time of the step
    results : dict method -> FrameResult (empty for a pass-only run)
    rows : list of metric rows of this frame
    post_seconds : float, the post-process's share of ``seconds``
    """

    index: int
    total: int
    frame: int
    path: Path
    rendered: bool
    seconds: float
    results: dict[str, FrameResult] = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)
    post_seconds: float = 0.0


# -- inputs --------------------------------------------------------------------------------
def resolve_output_dir(settings) -> Path:
    """Absolute output folder of ``scene.sss_settings`` ('//' = next to the .blend).

    An unsaved file has no folder: '//' then means the system temporary folder.
    """
    raw = (settings.output_dir or "").strip() or "//cvsss/"
    if raw.startswith("//") and not bpy.data.filepath:
        return Path(tempfile.gettempdir()) / raw[2:]
    return Path(bpy.path.abspath(raw))


def _check_writable(folder: Path) -> None:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        probe = folder / f".cvsss-write-test-{os.getpid()}"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise RenderError(
            f"cannot write to output folder {folder}: {exc.strerror or exc}"
        ) from None


def _check_frames(frames: Sequence[int] | tuple[int, int]) -> list[int]:
    try:
        start, end = (int(v) for v in frames)
    except (TypeError, ValueError):
        raise RenderError(f"frames must be a (start, end) pair, got {frames!r}") from None
    if start < 0 or end < start:
        raise RenderError(f"frame range must satisfy 0 <= start <= end, got {start}-{end}")
    return list(range(start, end + 1))


def _check_methods(methods: Sequence[str]) -> list[str]:
    names = list(dict.fromkeys(methods))
    if not names:
        raise RenderError("at least one method is needed")
    for name in names:
        if name not in METHODS:
            raise RenderError(f"method must be one of {', '.join(METHODS)}, got {name!r}")
    return names


def prepare(
    scene,
    frames: tuple[int, int],
    out: str | os.PathLike,
    methods: Sequence[str] = ("as_ccv",),
    params: SSSParams | None = None,
    *,
    engine: str = "CYCLES",
    overwrite: bool = False,
    reference: bool = False,
    normal: bool = False,
    images: bool = False,
    context=None,
    log: Log = None,
    reference_every: int = 1,
) -> Job:
    """Check everything a run needs before the scene is touched.

    ``reference_every = k`` computes the reference on every k-th frame only.

    Raises
    ------
    RenderError
        Bad frame range or method, no camera, no participating material,
        a material without a Principled BSDF or override, unwritable output.
    """
    frame_list = _check_frames(frames)
    names = _check_methods(methods)
    if (
        isinstance(reference_every, bool)
        or not isinstance(reference_every, int)
        or reference_every < 1
    ):
        raise RenderError(f"reference_every must be an integer >= 1, got {reference_every!r}")
    display = next((n for n in names if n != "reference"), names[0])
    if reference and "reference" not in names:
        names.append("reference")
    # The reference goes first so each method's PSNR is available at once.
    names.sort(key=lambda n: n != "reference")
    engine_identifier(scene, engine)
    scene_camera(scene)
    view_layer = render_view_layer(scene, context)
    mats = sss_materials.participating(scene, view_layer)
    if not mats:
        raise RenderError(
            f"no material in scene {scene.name!r} takes part in subsurface scattering "
            "(give one a Principled BSDF with Subsurface Weight > 0, or set its "
            "Subsurface (cvsss) mode to On)"
        )
    linked = [m.name for m in mats if m.library is not None and m.override_library is None]
    if linked:
        raise RenderError(
            f"material(s) {', '.join(map(repr, linked))} are linked from a library and cannot "
            "get a pass index; make them local or library overrides"
        )
    try:
        sss_materials.material_specs(mats, scene)
    except ValueError as exc:
        raise RenderError(str(exc)) from None
    out = Path(out).expanduser().absolute()
    _check_writable(out / "passes")
    return Job(
        scene=scene,
        view_layer=view_layer,
        frames=frame_list,
        out=out,
        methods=names,
        params=params or SSSParams(),
        engine=engine,
        overwrite=overwrite,
        normal=normal,
        materials=mats,
        images=images,
        display=display,
        log=log,
        reference_every=reference_every,
    )


# -- steps ------------------------------------------------------------------------------------
def iter_passes(job: Job) -> Iterator[Step]:
    """Render (or reuse) the pass file of each frame; one Step per frame.

    The scene is configured and restored around each frame, and the current
    frame is restored when the generator ends, fails or is closed.
    """
    scene = job.scene
    frame_before, subframe_before = scene.frame_current, scene.frame_subframe
    total = len(job.frames)
    began = time.perf_counter()
    try:
        for index, frame in enumerate(job.frames, 1):
            start = time.perf_counter()
            path = pass_path(job.passes_dir, frame)
            rendered = job.overwrite or not frame_done(job.passes_dir, frame)
            if rendered:
                scene.frame_set(frame)
                specs = sss_materials.material_specs(job.materials, scene)
                with PassSetup(scene, job.materials, job.view_layer, job.engine, job.normal):
                    render_frame(scene, frame, job.passes_dir, specs, job.view_layer)
            seconds = time.perf_counter() - start
            if job.log:
                what = "rendered" if rendered else "exists, reused"
                elapsed = time.perf_counter() - began
                job.log(
                    f"frame {index}/{total} ({frame}) passes {what} [{seconds:.2f} s; "
                    f"passes elapsed {format_clock(elapsed)}, eta {format_clock(elapsed / index * (total - index))}]"
                )
            yield Step(index, total, frame, path, rendered, seconds)
    finally:
        scene.frame_set(frame_before, subframe=subframe_before)


def reference_due(job: Job, index: int) -> bool:
    """Whether the reference is computed on the ``index``-th (1-based) frame of the range."""
    return (index - 1) % job.reference_every == 0


def _fmt(value: float | None, digits: int) -> str:
    if value is None or value != value:
        return ""
    return f"{value:.{digits}f}"


def _post_frame(
    job: Job, processors: dict[str, SequenceProcessor], step: Step, write: bool
) -> None:
    """Post-process the pass file of ``step`` with every processor, in order."""
    frame = read_frame(step.path, number=step.frame)
    settings = getattr(job.scene, "sss_settings", None)
    ref = None
    skip_reference = not reference_due(job, step.index)
    for name, processor in processors.items():
        if name == "reference" and skip_reference:
            continue
        result = processor.process(frame)
        if name == "reference":
            ref = result
        # As in `cvsss post`: the reference is listed too (against itself: the 100 dB cap).
        value = (
            psnr(result.composite, ref.composite, result.mask, job.params.exposure)
            if ref is not None
            else None
        )
        if write:
            write_result(
                job.out / name / step.path.name,
                result,
                overwrite=True,
                metadata={"source": step.path.name},
            )
        step.results[name] = result
        step.rows.append(
            {
                "frame": step.frame,
                "method": name,
                "spp": _fmt(result.spp, 4),
                "pass_ms": _fmt(result.pass_ms, 3),
                "psnr_db": _fmt(value, 3),
            }
        )
        if name == job.display:
            if job.images:
                from .images import show_result

                show_result(result)
            if settings is not None:
                from .properties import store_stats

                store_stats(settings, step.frame, name, result.spp, result.pass_ms, value)
        if job.log:
            job.log(
                f"frame {step.index}/{step.total} ({step.frame}) {name:>9}: "
                f"spp {result.spp:7.2f}  pass {result.pass_ms:8.2f} ms  "
                f"psnr {_fmt(value, 2) or '-':>6} dB  distant {result.distant_share:6.1%}"
            )


def iter_sequence(job: Job) -> Iterator[Step]:
    """Passes then post-process, frame by frame, for every method of the job.

    Writes ``<out>/<method>/####.exr`` and rewrites ``<out>/metrics.csv``
    after each frame, so a cancelled run keeps its finished frames.
    """
    processors = {name: SequenceProcessor(name, job.params) for name in job.methods}
    rows: list[dict] = []
    began = time.perf_counter()
    for step in iter_passes(job):
        start = time.perf_counter()
        _post_frame(job, processors, step, write=True)
        rows.extend(step.rows)
        write_text_atomic(job.out / "metrics.csv", format_metrics(rows))
        post = time.perf_counter() - start
        step.seconds += post
        step.post_seconds = post
        if job.log:
            elapsed = time.perf_counter() - began
            eta = elapsed / step.index * (step.total - step.index)
            job.log(
                f"frame {step.index}/{step.total} ({step.frame}) post-process [{post:.2f} s; "
                f"elapsed {format_clock(elapsed)}, eta {format_clock(eta)}]"
            )
        yield step


def apply_frame(job: Job) -> Step:
    """Passes (rendered only when missing or ``overwrite``) and post-process of one frame.

    The job's range must be a single frame. Nothing is written but the pass
    file; adaptive methods start without history, so they use n_init samples.
    """
    if len(job.frames) != 1:
        raise RenderError(f"apply_frame takes one frame, got {len(job.frames)}")
    processors = {name: SequenceProcessor(name, job.params) for name in job.methods}
    step = None
    for step in iter_passes(job):
        _post_frame(job, processors, step, write=False)
    return step


def job_from_scene(
    scene,
    *,
    frames: tuple[int, int] | None = None,
    out: str | os.PathLike | None = None,
    methods: Sequence[str] | None = None,
    params: SSSParams | Mapping | None = None,
    engine: str | None = None,
    overwrite: bool | None = None,
    reference: bool | None = None,
    images: bool = False,
    context=None,
    log: Log = None,
    reference_every: int = 1,
) -> Job:
    """A :class:`Job` from ``scene.sss_settings``; each argument given overrides it.

    ``params`` may be a mapping of SSSParams fields that override the
    settings' values one by one.
    """
    from .properties import frame_range, settings_to_params

    settings = scene.sss_settings
    names = list(methods) if methods else [settings.method]
    if params is None or isinstance(params, Mapping):
        # The quality target calibrates the method shown (the first that is not the reference).
        shown = next((n for n in names if n != "reference"), names[0])
        params = settings_to_params(settings, shown).replace(**dict(params or {}))
    return prepare(
        scene,
        frames if frames is not None else frame_range(scene),
        out if out is not None else resolve_output_dir(settings),
        names,
        params,
        engine=engine or settings.engine,
        overwrite=settings.overwrite if overwrite is None else overwrite,
        reference=settings.use_reference if reference is None else reference,
        normal=settings.use_normal_pass,
        images=images,
        context=context,
        log=log,
        reference_every=reference_every,
    )


# -- the one-call API ---------------------------------------------------------------------------
def _ensure_registered() -> Callable[[], None] | None:
    """Register the add-on's types when run outside an enabled add-on (CLI).

    Returns the matching unregister function, or None when already registered.
    """
    if hasattr(bpy.types.Scene, "sss_settings"):
        return None
    from ... import register, unregister

    register()
    return unregister


def render_sequence(
    source=None,
    frames: tuple[int, int] | None = None,
    out: str | os.PathLike | None = None,
    methods: Sequence[str] | None = None,
    params: SSSParams | Mapping | None = None,
    engine: str | None = None,
    overwrite: bool = False,
    log: Log = print,
    *,
    reference: bool | None = None,
    images: bool = False,
    reference_every: int = 1,
) -> list[dict]:
    """Render passes and post-process a frame range; returns the metric rows.

    Parameters
    ----------
    source : str or PathLike or bpy.types.Scene or None
        A .blend to open (``wm.open_mainfile``; the file is never saved), a
        scene, or None for the context scene.
    frames : (start, end), inclusive, optional
        Defaults to the scene's range (or the add-on's custom range).
    out : folder, optional
        Defaults to the scene's ``sss_settings.output_dir``.
    methods : method names, optional
        Defaults to ``sss_settings.method``.
    params : SSSParams, or a mapping of SSSParams fields, optional
        A mapping overrides the scene's settings field by field; None uses them.
    engine : {"CYCLES", "EEVEE"}, optional
        Defaults to ``sss_settings.engine``.
    overwrite : bool
        Render pass frames again even if their files exist.
    log : callable(str) or None
        Progress printer.
    reference : bool, optional
        Also compute the reference for PSNR; defaults to ``sss_settings.use_reference``.
    images : bool
        Update the image datablocks after each frame.
    reference_every : int
        Compute the reference (and PSNR) on every k-th frame of the range only.

    Returns
    -------
    list of dict
        Metric rows (frame, method, spp, pass_ms, psnr_db) as in metrics.csv.

    Raises
    ------
    RenderError
        A problem with the inputs (missing .blend, bad frame range,
        unwritable output, no subsurface material, …).
    core.exr.PassError, core.exr.OutputError, core.params.ParameterError
    """
    unregister = _ensure_registered()
    try:
        if source is None or isinstance(source, bpy.types.Scene):
            scene = source or bpy.context.scene
        else:
            path = Path(source).expanduser()
            if not path.is_file():
                raise RenderError(f"{path}: no such .blend file")
            try:
                bpy.ops.wm.open_mainfile(filepath=str(path.absolute()), load_ui=False)
            except RuntimeError as exc:
                # Blender's message ends with the cause ("File format is not supported …").
                reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unreadable"
                raise RenderError(f"{path}: not a readable .blend file ({reason})") from None
            scene = bpy.context.scene
        job = job_from_scene(
            scene,
            frames=frames,
            out=out,
            methods=methods,
            params=params,
            engine=engine,
            overwrite=overwrite,
            reference=reference,
            images=images,
            log=log,
            reference_every=reference_every,
        )
        rows: list[dict] = []
        for step in iter_sequence(job):
            rows.extend(step.rows)
        return rows
    finally:
        if unregister is not None:
            unregister()

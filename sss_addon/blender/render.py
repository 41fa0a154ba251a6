"""Render passes and post-process a frame range: the job behind the operators and ``cvsss render``.

Work is a per-frame step generator so the same code runs to the end in
background mode (:func:`.standalone.render_sequence`) and one frame per timer tick in the
UI (the modal operators), where closing the generator cancels cleanly.

Layout under the output folder::

    passes/####.exr + ####.json   multilayer pass EXR and its sidecar
    ground_truth/####.exr + .json Cycles with its own subsurface on (ground_truth.py)
    <method>/####.exr             result layers (core.io.exr.write_result)
    <method>/.checkpoint.npz      history after the last finished frame
    metrics.csv                   one row per frame and method (core.run)

The post-process is the one sequence driver, :class:`core.run.SequenceRun`.
Pass frames that exist are reused unless ``overwrite`` (made with another
camera or materials than the scene has now, they stop the job:
:func:`check_passes`); the post-process
resumes where a run with the same passes, methods and parameters stopped
(``existing="continue"``) and starts over otherwise or with ``overwrite``.
The reference (1024 spp) costs as much as all other methods together: with
``reference_every = k`` it is computed on every k-th frame of the range only
(the first, the (k+1)-th, …; it keeps no history, so any subset is exact)
and PSNR is reported on those frames.

Three options change what the post reads or gives. ``denoise`` denoises
each method's finished frame as the scene's Cycles denoiser would
(denoise_frame.py; the pass files keep the denoiser's guides and their
sidecars record the settings as ``"denoise"``); ``denoise_passes`` denoises
the passes with Blender's OIDN (denoise.py) instead; pass frames made with
the other setting are rendered again, never reused. ``ground_truth``
renders the same frames with Cycles' own subsurface (every
``ground_truth_every``-th frame, the first included) and hands them to the
post, which fills the ground-truth columns of metrics.csv. All are part of
the run's identity, so switching one starts the post-process over (the
passes are kept).
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import bpy

from ...core.io.exr import read_combined, read_frame
from ...core.method import MethodOptions
from ...core.methods import METHODS, make_processor
from ...core.params import SSSParams
from ...core.result import FrameResult
from ...core.run import RunSpec, SequenceRun
from .. import precompile
from ..progress import format_clock, printer
from . import ground_truth as gt
from . import materials as sss_materials
from . import thin_parts
from .denoise_frame import (
    EEVEE_DENOISE,
    DenoiseSettings,
    cycles_denoise,
    denoising,
    eevee_denoise,
    read_guides,
    scene_denoise,
)
from .errors import RenderError
from .images import show_result
from .passes import (
    PassSetup,
    engine_identifier,
    frame_done,
    output_size,
    pass_changes,
    pass_path,
    pass_sidecar,
    render_frame,
    render_view_layer,
    scene_camera,
)
from .properties import frame_range, settings_to_options, settings_to_params, store_stats

__all__ = [
    "Job",
    "RenderError",
    "Step",
    "apply_frame",
    "iter_passes",
    "iter_sequence",
    "job_from_scene",
    "make_job",
    "resolve_output_dir",
    "warmup_frames",
]

Log = Callable[[str], None] | None


@dataclass
class Job:
    """Validated inputs of a pass render / sequence run (see :func:`make_job`)."""

    scene: object
    view_layer: object
    frames: list[int]
    out: Path
    methods: list[str]
    params: SSSParams
    options: MethodOptions = field(default_factory=MethodOptions)
    engine: str = "CYCLES"
    overwrite: bool = False
    normal: bool = False
    materials: list = field(default_factory=list)
    images: bool = False
    display: str = ""
    log: Log = None
    reference_every: int = 1
    denoise_passes: bool = False
    #: The scene's denoiser settings when the finished frames are denoised (the pass
    #: files keep the guides; :mod:`.denoise_frame`), else None.
    denoise: DenoiseSettings | None = None
    ground_truth: bool = False
    ground_truth_samples: int = gt.DEFAULT_SAMPLES
    ground_truth_every: int = 1
    ground_truth_method: str = "MATERIAL"
    warmup_frames: int = 0
    #: First frame of the whole range when this job renders one chunk of it, so the
    #: ground truth falls on the same frames (every k-th of the whole range).
    range_start: int | None = None
    #: False: the passes (and ground truth) were rendered elsewhere (chunks on a
    #: farm); they are read, never rendered, and a missing one is an error.
    render_passes: bool = True
    #: False: the frames are processed elsewhere (tiles on a cluster), so this process
    #: does not compile the numba passes (:mod:`.precompile`).
    processed_here: bool = True
    #: Whether the opened .blend's Python drivers and registered scripts run (True,
    #: False: ``wm.open_mainfile(use_scripts=…)``, Blender's -y / -Y), or None: as
    #: Blender is set; passed on to the processes that render farm chunks.
    autoexec: bool | None = None
    #: Objects thin for their Random Walk material whose subsurface Cycles renders in the
    #: pass render, with those materials (:mod:`.thin_parts`); empty: the post renders all.
    thin: list = field(default_factory=list)
    #: Who renders their subsurface, resolved ("CYCLES" or "POST"; farm chunks get it).
    thin_walks: str = "CYCLES"
    #: Cycles also renders the subsurface of the materials' thin points and rims.
    thin_points: bool = False

    @property
    def thin_record(self) -> dict | None:
        """What the pass sidecar records of the thin parts Cycles renders (None: none)."""
        if not (self.thin or self.thin_points):
            return None
        return thin_parts.record([obj.name for obj, _ in self.thin], self.thin_points)

    @property
    def passes_dir(self) -> Path:
        return self.out / "passes"

    @property
    def ground_truth_dir(self) -> Path:
        return self.out / "ground_truth"

    def ground_truth_due(self, index: int) -> bool:
        """Whether the frame at 0-based ``index`` of the range gets a ground truth."""
        if self.range_start is not None:
            index += self.frames[0] - self.range_start
        return self.ground_truth and index % self.ground_truth_every == 0

    @property
    def warmup(self) -> list[int]:
        """The frames processed before the first one to fill the history (may be < 0)."""
        return warmup_frames(self.frames[0], self.warmup_frames)


def warmup_frames(first: int, count: int, step: int = 1) -> list[int]:
    """The ``count`` frames before ``first``, ``step`` apart, in order (negative ones included).

    >>> warmup_frames(1, 3)
    [-2, -1, 0]
    >>> warmup_frames(10, 2, step=2)
    [6, 8]
    """
    return [first - k * step for k in range(count, 0, -1)]


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
    ground_truth : Path of the ground-truth EXR, or None on frames without one
    ground_truth_rendered : bool, False when an existing ground truth was reused
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
    ground_truth: Path | None = None
    ground_truth_rendered: bool = False


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


def _check_count(name: str, value, hi: int | None = None) -> int:
    if (
        isinstance(value, bool)
        or not isinstance(value, int)
        or value < 1
        or (hi is not None and value > hi)
    ):
        bound = f"between 1 and {hi}" if hi is not None else ">= 1"
        raise RenderError(f"{name} must be an integer {bound}, got {value!r}")
    return value


def _check_methods(methods: Sequence[str]) -> list[str]:
    names = list(dict.fromkeys(methods))
    if not names:
        raise RenderError("at least one method is needed")
    for name in names:
        if name not in METHODS:
            raise RenderError(f"method must be one of {', '.join(METHODS)}, got {name!r}")
    return names


def make_job(
    scene,
    frames: tuple[int, int],
    out: str | os.PathLike,
    methods: Sequence[str] = ("as_ccv",),
    params: SSSParams | None = None,
    *,
    options: MethodOptions | None = None,
    engine: str = "CYCLES",
    overwrite: bool = False,
    reference: bool = False,
    normal: bool = False,
    images: bool = False,
    context=None,
    log: Log = None,
    reference_every: int = 1,
    denoise_passes: bool = False,
    ground_truth: bool = False,
    ground_truth_samples: int = gt.DEFAULT_SAMPLES,
    ground_truth_every: int = 1,
    ground_truth_method: str = "MATERIAL",
    warmup_frames: int = 0,
    denoise: DenoiseSettings | None = None,
) -> Job:
    """Check everything a run needs before the scene is touched.

    ``reference_every = k`` computes the reference on every k-th frame only.
    ``warmup_frames`` frames before the first are rendered and processed
    first, without results, so the first result has a history.
    ``denoise_passes`` denoises the passes, ``denoise`` the finished frames as
    these settings say (Cycles only; not both). ``ground_truth``
    renders every ``ground_truth_every``-th frame with Cycles' own subsurface
    (``ground_truth_method`` MATERIAL: each material's own method, or BURLEY or
    RANDOM_WALK forced on all) at ``ground_truth_samples``
    samples per pixel.

    Raises
    ------
    RenderError
        Bad frame range or method, no camera, no participating material,
        a material without a Principled BSDF or override, unwritable output,
        a bad ground-truth setting, denoising with EEVEE.
    """
    frame_list = _check_frames(frames)
    names = _check_methods(methods)
    _check_count("reference_every", reference_every)
    _check_count("ground_truth_every", ground_truth_every)
    _check_count("ground_truth_samples", ground_truth_samples, gt.MAX_SAMPLES)
    if isinstance(warmup_frames, bool) or not isinstance(warmup_frames, int) or warmup_frames < 0:
        raise RenderError(f"warmup_frames must be an integer >= 0, got {warmup_frames!r}")
    method = str(ground_truth_method).upper()
    if method not in gt.METHODS:
        raise RenderError(
            f"ground_truth_method must be one of {', '.join(gt.METHODS)}, "
            f"got {ground_truth_method!r}"
        )
    if engine != "CYCLES" and (
        denoise_passes or (denoise is not None and not denoise.subsurface_only)
    ):
        what = "the passes" if denoise_passes else "the finished frames as Cycles does"
        raise RenderError(
            f"denoising {what} needs Cycles: {engine} writes no Denoising Albedo and "
            "Normal passes to guide the denoiser (render the passes with Cycles, or turn "
            "denoising off)"
        )
    if denoise_passes and denoise is not None:
        raise RenderError(
            "denoise the finished frames (the scene's denoiser, --denoise) or the passes "
            "(--denoise-passes), not both"
        )
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
    for material in mats:
        for text in sss_materials.unmodelled_inputs(material):
            print(f"warning: {text}", file=sys.stderr)
    out = Path(out).expanduser().absolute()
    _check_writable(out / "passes")
    if ground_truth:
        _check_writable(out / "ground_truth")
    return Job(
        scene=scene,
        view_layer=view_layer,
        frames=frame_list,
        out=out,
        methods=names,
        params=params or SSSParams(),
        options=options or MethodOptions(),
        engine=engine,
        overwrite=overwrite,
        normal=normal,
        materials=mats,
        images=images,
        display=display,
        log=log,
        reference_every=reference_every,
        denoise_passes=bool(denoise_passes),
        denoise=denoise,
        ground_truth=bool(ground_truth),
        ground_truth_samples=ground_truth_samples,
        ground_truth_every=ground_truth_every,
        ground_truth_method=method,
        warmup_frames=warmup_frames,
    )


# -- steps ------------------------------------------------------------------------------------
def check_passes(job: Job, frame: int) -> None:
    """RenderError when ``frame``'s existing passes were made with another camera, another
    material or Subsurface Weight, another resolution… than the scene has now.

    Passes are reused without *Overwrite* (a stopped render resumes); reusing
    them after such a change would give results of the old settings. What the
    sidecar does not record (lights, geometry, Cycles samples) cannot be seen.
    """
    scene = job.scene
    before = scene.frame_current, scene.frame_subframe
    try:
        scene.frame_set(frame)
        specs = sss_materials.material_specs(job.materials, scene)
        now = pass_sidecar(scene, frame, specs, job.view_layer, job.thin_record)
        # The pass render switches the engine to the job's (EEVEE passes of a Cycles scene).
        now["engine"] = engine_identifier(scene, job.engine)
    finally:
        scene.frame_set(before[0], subframe=before[1])
    changed = pass_changes(job.passes_dir, frame, now)
    if changed:
        raise RenderError(
            f"{pass_path(job.passes_dir, frame)} was rendered with another "
            f"{', '.join(c.replace('_', ' ') for c in changed)} than the scene has now: "
            "turn on Overwrite (--overwrite) to render the passes again, or choose another "
            "output folder"
        )


def iter_passes(job: Job, needed: Callable[[int], bool] | None = None) -> Iterator[Step]:
    """Render (or reuse) the pass file of each frame; one Step per frame.

    ``needed(frame)`` false skips rendering a missing pass file (the frame's
    results are already done). A pass file made with the other
    ``denoise_passes`` setting is rendered again. On the frames the job's
    ground truth is due it is rendered (or reused) after the passes. The
    scene is configured and restored around each render, and the current
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
            wanted = needed is None or needed(frame)
            guides = job.denoise is not None
            if not job.render_passes:
                if wanted and not frame_done(job.passes_dir, frame, job.denoise_passes, guides):
                    raise RenderError(
                        f"{path}: pass file missing or made with other settings after the "
                        "pass render (render the frame again)"
                    )
            rendered = (
                wanted
                and job.render_passes
                and (
                    job.overwrite
                    or not frame_done(job.passes_dir, frame, job.denoise_passes, guides)
                )
            )
            if wanted and job.render_passes and not rendered:
                check_passes(job, frame)
            # Made with the other denoise setting: said, never reused silently.
            redo = None
            if rendered and not job.overwrite:
                if frame_done(job.passes_dir, frame, not job.denoise_passes):
                    was = "on" if not job.denoise_passes else "off"
                    redo = f"the existing ones were made with denoising {was}"
                elif guides and frame_done(job.passes_dir, frame, job.denoise_passes):
                    redo = "the existing ones lack the denoiser's guides"
            if rendered:
                scene.frame_set(frame)
                specs = sss_materials.material_specs(job.materials, scene)
                with PassSetup(
                    scene,
                    job.materials,
                    job.view_layer,
                    job.engine,
                    job.normal,
                    job.denoise_passes,
                    guides,
                    job.thin,
                    job.thin_points,
                ):
                    render_frame(
                        scene,
                        frame,
                        job.passes_dir,
                        specs,
                        job.view_layer,
                        job.denoise_passes,
                        job.denoise.to_dict() if guides else None,
                        job.thin_record,
                    )
            step = Step(index, total, frame, path, rendered, 0.0)
            if wanted and job.ground_truth_due(index - 1):
                step.ground_truth = gt.ground_truth_path(job.ground_truth_dir, frame)
                step.ground_truth_rendered = job.overwrite or not gt.ground_truth_done(
                    job.ground_truth_dir,
                    frame,
                    job.ground_truth_samples,
                    job.ground_truth_method,
                    job.materials,
                )
                if not job.render_passes and step.ground_truth_rendered:
                    if job.overwrite and step.ground_truth.exists():
                        step.ground_truth_rendered = False
                    else:
                        raise RenderError(
                            f"{step.ground_truth}: ground truth missing or made with other "
                            "settings after the pass render"
                        )
                if step.ground_truth_rendered:
                    gt.render_ground_truth(
                        scene,
                        frame,
                        job.ground_truth_dir,
                        job.materials,
                        job.view_layer,
                        job.ground_truth_samples,
                        job.ground_truth_method,
                    )
            step.seconds = time.perf_counter() - start
            if job.log:
                what = "rendered" if rendered else "exists, reused"
                if redo:
                    what = f"rendered again ({redo})"
                if step.ground_truth is not None:
                    what += ", ground truth " + (
                        "rendered" if step.ground_truth_rendered else "exists, reused"
                    )
                elapsed = time.perf_counter() - began
                job.log(
                    f"frame {index}/{total} ({frame}) passes {what} [{step.seconds:.2f} s; "
                    f"passes elapsed {format_clock(elapsed)}, eta {format_clock(elapsed / index * (total - index))}]"
                )
            yield step
    finally:
        scene.frame_set(frame_before, subframe=subframe_before)


def run_source(job: Job) -> str:
    """Identity of the post's input: the pass folder, how the passes were made, the ground truth.

    Part of the run's checkpoint signature, so a run resumes only on the
    same input (plain pass folder path without denoising or ground truth).
    """
    source = os.fspath(job.passes_dir.resolve())
    if job.denoise_passes:
        source += " (denoised)"
    if job.denoise is not None:
        source += f"; finished frames denoised ({job.denoise.describe()})"
    if job.ground_truth:
        source += (
            f"; ground truth {os.fspath(job.ground_truth_dir.resolve())} "
            f"({job.ground_truth_method}, {job.ground_truth_samples} spp, "
            f"every {job.ground_truth_every})"
        )
    return source


def run_of(job: Job, write: bool = True, processors=None) -> SequenceRun:
    """The post-process of ``job``: every method over the job's frames (core.run).

    ``processors`` as :class:`core.run.SequenceRun` (tiled processors on a cluster).
    """
    spec = RunSpec(
        tuple(job.methods),
        job.params,
        job.options,
        reference_every=job.reference_every,
        source=run_source(job),
        warmup_frames=job.warmup_frames,
    )
    existing = "overwrite" if job.overwrite else "continue"
    if job.denoise is not None:
        processors = denoising(processors or make_processor, job.denoise, job_guides(job))
    extra = {} if processors is None else {"processors": processors}
    return SequenceRun(
        job.out, spec, job.frames, existing=existing, write=write, log=printer(job.log), **extra
    )


def job_guides(job: Job) -> Callable[[int], tuple | None]:
    """Frame number -> the denoiser's guides in its pass file, for the job's frames
    (warm-up frames are not denoised: nobody sees their results)."""
    frames = set(job.frames)
    layer = job.view_layer.name

    def guides(number: int) -> tuple | None:
        if number not in frames:
            return None
        return read_guides(pass_path(job.passes_dir, number), layer)

    return guides


def _post_frame(job: Job, run: SequenceRun, step: Step) -> None:
    """Post-process the pass file of ``step`` and show the displayed method's maps."""
    if not run.pending(step.frame):
        return
    start = time.perf_counter()
    truth = read_combined(step.ground_truth) if step.ground_truth is not None else None
    frame = read_frame(step.path, number=step.frame)
    if job.processed_here:
        precompile.ensure_compiled(
            job.params.backend, run.spec.order, math.prod(frame.shape), job.log
        )
    done = run.step(frame, source=step.path.name, ground_truth=truth)
    step.results, step.rows = done.results, done.rows
    step.post_seconds = time.perf_counter() - start
    step.seconds += step.post_seconds
    result = done.results.get(job.display)
    if result is None:
        return
    row = next(r for r in done.rows if r["method"] == job.display)
    if job.images:
        show_result(result)
    settings = getattr(job.scene, "sss_settings", None)
    if settings is not None:
        value = float(row["psnr_db"]) if row["psnr_db"] else None
        truth = float(row["psnr_gt_db"]) if row.get("psnr_gt_db") else None
        store_stats(
            settings,
            step.frame,
            job.display,
            result.spp,
            result.sampling_ms,
            value,
            psnr_gt_db=truth,
        )


def iter_sequence(job: Job, run: SequenceRun | None = None) -> Iterator[Step]:
    """Passes then post-process, frame by frame, for every method of the job.

    Writes ``<out>/<method>/####.exr``, a checkpoint per method and
    ``<out>/metrics.csv`` after each frame, so a cancelled run keeps its
    finished frames and the next run continues after them. ``run`` defaults
    to :func:`run_of` the job.
    """
    run = run or run_of(job)
    if job.render_passes and not job.overwrite:
        # Finished frames are not looked at again: their passes are checked on the first.
        guides = job.denoise is not None
        first = next(
            (f for f in job.frames if frame_done(job.passes_dir, f, job.denoise_passes, guides)),
            None,
        )
        if first is not None:
            check_passes(job, first)
    if _renders_first(job, run):
        # A process of its own compiles the numba passes while Blender renders (when
        # they are not cached yet); the first post-process waits for it.
        precompile.start_background(
            job.params.backend, run.spec.order, job.log, math.prod(output_size(job.scene))
        )
    if job.warmup_frames and run.fresh:
        render_warmup_frames(job, run)
    for step in iter_passes(job, needed=run.pending):
        _post_frame(job, run, step)
        yield step
    run.finish()


def _renders_first(job: Job, run: SequenceRun) -> bool:
    """Whether Blender renders passes before the job's first post-process here."""
    first = next((frame for frame in job.frames if run.pending(frame)), None)
    if first is None or not job.processed_here or not job.render_passes:
        return False
    if job.warmup_frames and run.fresh:
        return True
    guides = job.denoise is not None
    return job.overwrite or not frame_done(job.passes_dir, first, job.denoise_passes, guides)


def render_warmup_frames(job: Job, run: SequenceRun) -> None:
    """Render (or reuse) the passes of the job's warm-up frames and feed them to ``run``.

    Their pass files sit beside the others (``passes/-007.exr`` for frame -7);
    no result, metric row or ground truth is made for them.
    """
    log = job.log
    warm = replace(
        job,
        frames=job.warmup,
        ground_truth=False,
        log=(lambda text: log("warm-up " + text)) if log else None,
    )
    for step in iter_passes(warm):
        frame = read_frame(step.path, number=step.frame)
        if job.processed_here:
            precompile.ensure_compiled(
                job.params.backend, run.spec.order, math.prod(frame.shape), log
            )
        run.warm_up(frame)


def apply_frame(job: Job) -> Step:
    """Passes (rendered only when missing or ``overwrite``) and post-process of one frame.

    The job's range must be a single frame. Nothing is written but the pass
    file (and the ground truth, when the job asks for it); adaptive methods
    start without history, so they use n_init samples.
    """
    if len(job.frames) != 1:
        raise RenderError(f"apply_frame takes one frame, got {len(job.frames)}")
    run = run_of(job, write=False)
    step = None
    for step in iter_passes(job):
        _post_frame(job, run, step)
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
    options: MethodOptions | Mapping | None = None,
    denoise_passes: bool | None = None,
    ground_truth: bool | None = None,
    ground_truth_samples: int | None = None,
    ground_truth_every: int | None = None,
    ground_truth_method: str | None = None,
    warmup_frames: int = 0,
    denoise: bool | None = None,
    thin_walks: str | None = None,
) -> Job:
    """A :class:`Job` from ``scene.sss_settings``; each argument given overrides it.

    ``params`` may be a mapping of SSSParams fields that override the
    settings' values one by one; ``options`` a mapping with ``"profile"`` (a
    ProfileChoice replacing the scene's) and ``"separable"`` (SeparableParams
    fields overriding the scene's).

    ``denoise`` (None: as the scene's render does, :func:`.denoise_frame.scene_denoise`,
    unless the passes are denoised instead) denoises the finished frames with the
    scene's Cycles denoiser settings.

    ``thin_walks`` ("CYCLES", "POST"; None: ``thin_walks`` of the settings) says who
    renders the subsurface of parts thin for their Random Walk material on Cycles
    passes (:mod:`.thin_parts`); the job's ``thin`` lists them when Cycles does.
    """
    settings = scene.sss_settings
    names = list(methods) if methods else [settings.method]
    if params is None or isinstance(params, Mapping):
        # The quality target calibrates the method shown (the first that is not the reference).
        shown = next((n for n in names if n != "reference"), names[0])
        params = settings_to_params(settings, shown).replace(**dict(params or {}))
    if options is None or isinstance(options, Mapping):
        given = dict(options or {})
        base = settings_to_options(settings)
        options = MethodOptions(
            profile=given.get("profile", base.profile),
            separable=base.separable.replace(**given.get("separable", {})),
        )
    pass_engine = engine or settings.engine
    denoise_passes = _given(denoise_passes, settings.use_denoise_passes)
    finished = None
    if not (denoise_passes and denoise is None):  # denoised passes instead, as asked
        finished = _finished_denoise(scene, render_view_layer(scene, context), pass_engine, denoise)
    job = make_job(
        scene,
        frames if frames is not None else frame_range(scene),
        out if out is not None else resolve_output_dir(settings),
        names,
        params,
        options=options,
        engine=pass_engine,
        overwrite=settings.overwrite if overwrite is None else overwrite,
        reference=settings.use_reference if reference is None else reference,
        normal=settings.use_normal_pass,
        images=images,
        context=context,
        log=log,
        reference_every=reference_every,
        denoise_passes=denoise_passes,
        ground_truth=_given(ground_truth, settings.use_ground_truth),
        ground_truth_samples=_given(ground_truth_samples, settings.ground_truth_samples),
        ground_truth_every=_given(ground_truth_every, settings.ground_truth_every),
        ground_truth_method=_given(ground_truth_method, settings.ground_truth_method),
        warmup_frames=warmup_frames,
        denoise=finished,
    )
    job.thin_walks = _given(thin_walks, settings.thin_walks)
    if thin_parts.cycles_renders(job.thin_walks, pass_engine):
        job.thin = thin_parts.thin_objects(scene)
        job.thin_points = thin_parts.has_thin_points(job.materials)
    return job


def _finished_denoise(scene, view_layer, engine: str, asked: bool | None):
    """The denoiser settings of the finished frames: None (not denoised) or the scene's.

    ``asked`` None follows the scene's render, and on EEVEE passes the scene's
    *Denoise Subsurface* (:func:`.denoise_frame.eevee_denoise`); True takes the
    scene's Cycles settings even when its render does not denoise, and on EEVEE
    passes denoises their subsurface pixels.
    """
    if asked is False:
        return None
    if engine != "CYCLES":
        return EEVEE_DENOISE if asked else eevee_denoise(scene)
    settings = scene_denoise(scene, view_layer)
    if settings is None and asked:
        settings = cycles_denoise(scene)
    return settings


def _given(value, setting):
    return setting if value is None else value

"""The one-call API for scripts and ``cvsss render``: :func:`render_sequence`.

It opens a .blend (or takes a scene), registers the add-on's render parts for
the call when the add-on is not enabled (:func:`ensure_registered`: ``cvsss
render`` runs the ``bpy`` module, where no add-on is enabled), and runs the
Blender job (:mod:`.render`) to the end. It sits above the registration, which
the job itself (render.py) must not import.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import bpy

from ...core.method import MethodOptions
from ...core.params import SSSParams
from .. import registration
from . import thin_parts
from .autoexec import warning as skipped_python
from .console import StdoutFilter
from .errors import RenderError
from .render import Job, Log, iter_passes, iter_sequence, job_from_scene, run_of


def ensure_registered() -> Callable[[], None] | None:
    """Register the add-on's settings, Apply on Render and panels when run outside an
    enabled add-on (CLI, scripts on the ``bpy`` module).

    The operators are not registered: a headless call runs the job itself, and only
    Blender's UI calls them (the extension's root ``register`` adds them there).
    Returns the matching unregister function, or None when already registered.
    """
    if hasattr(bpy.types.Scene, "sss_settings"):
        return None
    registration.register()
    return registration.unregister


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
    options: MethodOptions | Mapping | None = None,
    denoise_passes: bool | None = None,
    denoise: bool | None = None,
    ground_truth: bool | None = None,
    ground_truth_samples: int | None = None,
    ground_truth_every: int | None = None,
    ground_truth_method: str | None = None,
    warmup_frames: int = 0,
    passes_only: bool = False,
    range_start: int | None = None,
    render_passes: bool = True,
    processors=None,
    on_job: Callable[[Job], None] | None = None,
    autoexec: bool | None = None,
    thin_walks: str | None = None,
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
        Render pass frames again even if their files exist, and start the
        post-process over (otherwise it resumes a run with the same settings).
    log : callable(str) or None
        Progress printer.
    reference : bool, optional
        Also compute the reference for PSNR; defaults to ``sss_settings.use_reference``.
    images : bool
        Update the image datablocks after each frame.
    reference_every : int
        Compute the reference (and PSNR) on every k-th frame of the range only.
    options : MethodOptions, or a mapping of overrides (see :func:`job_from_scene`)
    denoise_passes : bool, optional
        Denoise the passes with Blender's OIDN (Cycles passes only); defaults
        to ``sss_settings.use_denoise_passes`` when the finished frames are not
        denoised.
    denoise : bool, optional
        Denoise each method's finished frame with the scene's Cycles denoiser
        settings (:mod:`.denoise_frame`); None: when the scene's render denoises.
    ground_truth : bool, optional
        Also render the frames with Cycles' own subsurface on (always Cycles)
        into ``<out>/ground_truth`` and fill the ground-truth columns;
        defaults to ``sss_settings.use_ground_truth``.
    ground_truth_samples, ground_truth_every : int, optional
        Its samples per pixel, and every k-th frame only; default: the settings.
    ground_truth_method : {"MATERIAL", "BURLEY", "RANDOM_WALK"}, optional
        Cycles' subsurface method for it; default: the setting.
    warmup_frames : int
        Render and process this many frames before the first one (not
        written), so the first result has a history, as Apply on Render does
        with the scene's ``warmup_frames``. A run that resumes has its
        history and skips them.
    passes_only : bool
        Render the passes (and ground truth) only: no post-process, no metrics.
    range_start : int, optional
        First frame of the whole range when ``frames`` is one chunk of it (the
        ground truth then falls on every k-th frame of the whole range).
    render_passes : bool
        False: read passes rendered elsewhere (chunks on a farm), never render.
    processors : as :class:`core.run.SequenceRun` (the tiled post on a cluster)
    on_job : called with the validated :class:`Job` before any work (e.g. to
        render its passes elsewhere first)
    autoexec : bool, optional
        Run the Python drivers and registered text blocks of the .blend opened
        from ``source`` (True, as ``blender -y`` does) or not (False, ``-Y``);
        None: as Blender is set (its Auto Run Python Scripts preference, off by
        default, or the -y/-Y it was started with). Blender keeps the choice for
        the files it opens later in the process. When Blender skipped some, one
        ``warning:`` line on stderr names them before the render.
    thin_walks : {"CYCLES", "POST"}, optional
        Who renders the subsurface of parts thin for their Random Walk material on
        Cycles passes (:mod:`.thin_parts`); default: the scene's *Thin Random Walk
        Parts*. One ``note:`` line on stderr names such parts.

    Returns
    -------
    list of dict
        Metric rows (frame, method, spp, sampling_ms, psnr_db and, with a ground
        truth, its columns) as in metrics.csv.

    Raises
    ------
    RenderError
        A problem with the inputs (missing .blend, bad frame range,
        unwritable output, no subsurface material, …).
    core.io.errors.PassError, core.io.errors.OutputError, core.params.ParameterError
    """
    unregister_after = ensure_registered()
    try:
        if source is None or isinstance(source, bpy.types.Scene):
            if autoexec is not None:
                raise RenderError(
                    "autoexec applies to a .blend that render_sequence opens; Blender "
                    "opened this one with its own setting (blender -y runs its scripts)"
                )
            scene = source or bpy.context.scene
            # blender -b FILE --python main.py -- render: Blender's -y decided.
            skipped_hint = "run Blender with -y to run them" if bpy.app.background else None
        else:
            path = Path(source).expanduser()
            if not path.is_file():
                raise RenderError(f"{path}: no such .blend file")
            trust = {} if autoexec is None else {"use_scripts": bool(autoexec)}
            skipped_hint = "pass --enable-autoexec to run them"
            try:
                bpy.ops.wm.open_mainfile(filepath=str(path.absolute()), load_ui=False, **trust)
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
            options=options,
            denoise_passes=denoise_passes,
            denoise=denoise,
            ground_truth=ground_truth,
            ground_truth_samples=ground_truth_samples,
            ground_truth_every=ground_truth_every,
            ground_truth_method=ground_truth_method,
            warmup_frames=warmup_frames,
            thin_walks=thin_walks,
        )
        for text in thin_parts.note(scene, job.engine, thin_walks, apply_on_render=False):
            print("note: " + text, file=sys.stderr, flush=True)
        job.range_start = range_start
        job.render_passes = render_passes
        job.processed_here = processors is None
        job.autoexec = autoexec
        if skipped_hint is not None:
            text = skipped_python(skipped_hint)
            if text is not None:
                print(text, file=sys.stderr, flush=True)
        if on_job is not None:
            on_job(job)
        # Blender's "Saved: '…tmp…exr'" lines of the pass files stay out of the progress.
        console = StdoutFilter(os.fspath(job.out)) if bpy.app.background and log else None
        if console is not None:
            console.start()
        try:
            if passes_only:
                for _ in iter_passes(job):
                    if console is not None:
                        console.forward()
                return []
            run = run_of(job, processors=processors)
            for _ in iter_sequence(job, run):
                if console is not None:
                    console.forward()
        finally:
            if console is not None:
                console.stop()
        return run.rows
    finally:
        if unregister_after is not None:
            unregister_after()

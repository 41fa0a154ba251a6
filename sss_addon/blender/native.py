"""Apply on Render: Blender's own F12, Ctrl-F12 and ``blender -b -f/-a`` deliver finished frames.

No Python compositor node runs per pixel, so with ``scene.sss_settings.apply_on_render``
the user's render itself becomes the pass render and an ordered worker
post-processes every frame Blender writes. Handlers (all ``@persistent``):

``render_init``
    The scene switches to the pass configuration for the duration of the
    render (:class:`.passes.PassSetup`: Subsurface Weight 0, pass indices and
    flags, compositor and sequencer off, 32-bit multilayer EXR into a
    temporary folder). Blender copies the render settings right after this
    handler, so its own render now renders passes. Before the switch a
    linked copy of the scene, emptied of everything but the camera, keeps the
    user's output settings: the *output scene*. A problem the user can fix
    (another engine than Cycles or EEVEE, no camera, no subsurface material,
    multi-view) stops the render with a message: the render engine becomes
    :class:`ResultEngine`, which reports the error, so Blender cancels before
    writing anything.
``render_pre``
    The frame's sidecar (camera, materials) is taken. On the first frame of
    a fresh history ``warmup_frames`` frames before it are rendered (nested
    renders of a linked copy of the scene, which has its own Render) and
    processed, their output dropped. Output placeholders and *Overwrite* off
    are honoured here, as Blender does before it renders a frame.
``render_write``
    Blender has written the frame's pass EXR. The worker reads it, runs the
    method (:class:`core.run.FrameStream` owns the history; frames go in
    order, and consecutive renders such as ``-f 1..3`` continue it in
    background mode), updates the SSS image datablocks and delivers the
    finished frame by rendering the output scene with :class:`ResultEngine`:
    Blender's own writer, so the path, frame number and extension rules,
    format, colour management and dither are the user's.
``render_complete`` / ``render_cancel``
    A still render (F12) is rendered once more on the user's scene with
    :class:`ResultEngine`, so the Render Result is the finished frame and a
    ``write_still`` render writes it where Blender would; a movie (FFmpeg)
    is encoded from the finished frames by one animation render of the
    output scene (Blender's own movie writer); then every setting is
    restored and the temporary files removed — also after an error or Esc.

In background mode (``blender -b``, the ``bpy`` module) the handlers run on
the main thread and all of this happens inside them, frame by frame. With
the UI, Blender calls them on its render thread: there ``render_init`` only
switches the settings and the frames are queued; when the render job has
ended, a timer starts the modal ``sss.finish_render`` operator, which warms
up, processes and delivers one frame per tick on the main thread (progress
in the status bar, Esc stops and restores).

Blender's ``Saved: '…'`` lines about the temporary pass files (and the
output of the nested renders) leave stdout in background mode; one line per
frame reports what was delivered where.
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import tempfile
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from pathlib import Path

import bpy
import numpy as np
import OpenEXR
from bpy.app.handlers import persistent

from ...core.io.exr import quiet_native_stderr, read_frame, use_threads
from ...core.io.sidecar import write_sidecar
from ...core.run import FrameStream, RunSpec
from .. import precompile
from . import materials as sss_materials
from .console import StdoutFilter
from .passes import (
    PassSetup,
    RenderError,
    SceneSetup,
    finish_pass_file,
    internal_render,
    output_size,
    pass_sidecar,
    rendering_internally,
)

#: Identifier of :class:`ResultEngine`.
ENGINE = "CVSSS_RESULT"

#: Engines whose renders Apply on Render turns into pass renders (Blender id -> cvsss name).
PASS_ENGINES = {
    "CYCLES": "CYCLES",
    "BLENDER_EEVEE": "EEVEE",
    "BLENDER_EEVEE_NEXT": "EEVEE",
}


def _log(text: str) -> None:
    print(f"cvsss: {text}", flush=True)


# -- the engine that hands finished frames to Blender's writer ------------------------------
#: What :class:`ResultEngine` renders: a function frame -> (H, W, 4) RGBA or None,
#: or a message (the render is stopped with it).
_task: Callable[[int], np.ndarray | None] | str | None = None


class ResultEngine(bpy.types.RenderEngine):
    """Renders finished frames (or stops a render with a message) for Apply on Render.

    Blender then does what it does with any render result: shows it as the
    Render Result and writes it with the scene's output settings. No
    compositor runs on it (``bl_use_postprocess`` off). It is registered for
    as long as the add-on (the render thread of a UI render cannot register
    classes), so it shows in the engine menu; chosen there, it says so.
    """

    bl_idname = ENGINE
    bl_label = "cvsss (internal: Apply on Render)"
    bl_use_postprocess = False
    bl_use_preview = False

    def render(self, depsgraph):
        task = _task
        if not callable(task):
            self.report(
                {"ERROR"},
                task
                or "cvsss: this engine is used by Apply on Render; render with Cycles or EEVEE",
            )
            return
        scene = depsgraph.scene
        rgba = task(int(scene.frame_current))
        if rgba is None:
            self.report({"ERROR"}, f"cvsss: no finished frame {scene.frame_current}")
            return
        height, width = rgba.shape[:2]
        result = self.begin_result(0, 0, width, height, layer=depsgraph.view_layer.name)
        # Render results start at the bottom row; the core's images at the top.
        result.layers[0].passes["Combined"].rect.foreach_set(
            np.ascontiguousarray(rgba[::-1], dtype=np.float32).reshape(-1)
        )
        self.end_result(result)


@contextlib.contextmanager
def _rendering(task) -> Iterator[None]:
    """:class:`ResultEngine` renders ``task`` inside the block (an internal render)."""
    global _task
    before = _task
    _task = task
    try:
        with internal_render():
            yield
    finally:
        _task = before


# -- helpers -----------------------------------------------------------------------------------
def pass_engine(scene) -> str:
    """``CYCLES`` or ``EEVEE`` for the scene's render engine; RenderError for any other."""
    engine = scene.render.engine
    if engine not in PASS_ENGINES:
        raise RenderError(
            f"Apply on Render needs Cycles or EEVEE as the render engine, the scene uses {engine}"
        )
    return PASS_ENGINES[engine]


def _bypassed(scene) -> list[str]:
    """What of the user's render the finished frames leave out."""
    notes = []
    group = getattr(scene, "compositing_node_group", None)
    if scene.render.use_compositing and group is not None and len(group.nodes):
        notes.append("the compositor is bypassed (the finished frame is written as rendered)")
    editor = scene.sequence_editor
    strips = getattr(editor, "strips_all", None) or getattr(editor, "sequences_all", None)
    if scene.render.use_sequencer and editor is not None and strips:
        notes.append("the sequencer's strips are bypassed")
    used = [layer.name for layer in scene.view_layers if layer.use]
    if len(used) > 1:
        notes.append(f"only view layer {used[0]!r} is rendered (of {len(used)})")
    return notes


def native_notes(scene) -> list[str]:
    """Short notes for the panel: what Apply on Render will do differently with this scene."""
    notes = []
    try:
        pass_engine(scene)
    except RenderError:
        notes.append("Needs Cycles or EEVEE as the render engine")
    if scene.render.is_movie_format:
        notes.append("Movie: frames are encoded after the last one")
    return notes + [note[0].upper() + note[1:] for note in _bypassed(scene)]


def scene_copy(scene, role: str):
    """A linked copy of ``scene``, named ``cvsss <role> (<scene name>)``, for the add-on's
    own renders; the add-on removes it when it is done with it.

    Its *Persistent Data* is off, whatever the user's scene says, so that Blender frees
    the render engine after each of its renders. With it on, Blender kept the engine
    of a finished render, and the engine its depsgraph, registered with the blend
    data; removing the copy then left that depsgraph pointing at freed memory, which
    Blender read again whenever a datablock was added or removed later in the session
    (valgrind: invalid reads in ``DEG_relations_tag_update`` after an Apply on Render
    of the demo scene; a segmentation fault in ``bpy.data.images.remove`` in one CI
    run).
    """
    copy = scene.copy()
    copy.name = f"cvsss {role} ({scene.name})"
    copy.render.use_persistent_data = False
    return copy


@contextlib.contextmanager
def frame_of(scene, frame: int) -> Iterator[None]:
    """``scene`` at ``frame`` inside the block (a warm-up frame rendered through a copy
    of it); its frame restored on exit.

    The copy shares the user's objects and data, whose drivers still read the
    user's scene: a driver variable on its Current Frame gave the frame the
    user's render had stopped at, not the warm-up frame that Blender's own
    render of that frame gives. ``frame_set``, as the frame property cannot
    hold a negative frame (without the Allow Negative Frames preference).
    """
    before = scene.frame_current, scene.frame_subframe
    scene.frame_set(frame)
    try:
        yield
    finally:
        scene.frame_set(before[0], subframe=before[1])


def output_scene(scene, layer_name: str):
    """A linked copy of ``scene`` with its output settings and only its camera, for
    :class:`ResultEngine` to write finished frames with Blender's own writer."""
    out = scene_copy(scene, "output")
    for child in list(out.collection.children):
        out.collection.children.unlink(child)
    for obj in list(out.collection.objects):
        out.collection.objects.unlink(obj)
    if scene.camera is not None:
        out.collection.objects.link(scene.camera)
        out.camera = scene.camera
    r = out.render
    r.engine = ENGINE
    r.use_compositing = False
    r.use_sequencer = False
    r.use_border = False
    r.use_multiview = False
    # Existing files and placeholders are handled before each frame renders (as Blender does).
    r.use_overwrite = True
    r.use_placeholder = False
    for layer in out.view_layers:
        layer.use = layer.name == layer_name
    settings = getattr(out, "sss_settings", None)
    if settings is not None:
        settings.apply_on_render = False
    return out


class DisplaySetup(SceneSetup):
    """The user's scene rendering with :class:`ResultEngine` (the Render Result, a still's
    file), only the processed view layer, whole frame; restored on exit."""

    def _apply(self) -> None:
        r = self.scene.render
        r.engine = ENGINE
        r.use_border = False
        for layer in self.scene.view_layers:
            layer.use = layer == self.view_layer


def read_alpha(path: Path, layer: str) -> np.ndarray | None:
    """The Combined alpha of a pass EXR (top row first), or None when it has none."""
    use_threads()
    with quiet_native_stderr():
        exr = OpenEXR.File(str(path), separate_channels=True)
    for part in exr.parts:
        for key, channel in part.channels.items():
            if key in (f"{layer}.Combined.A", "Combined.A"):
                return np.asarray(channel.pixels, dtype=np.float32)
    return None


def _camera_animated(scene, materials) -> bool:
    """Whether the sidecar of a frame needs the scene evaluated at that frame."""
    cam = scene.camera
    ids = [cam.data] if cam is not None else []
    ids += [m.node_tree for m in materials if m.node_tree is not None]
    if any(m.camera is not None for m in scene.timeline_markers):
        return True
    return any(i.animation_data is not None for i in ids)


# -- one render of the user's ---------------------------------------------------------------
#: The history of the last render in background mode, continued by a render of the next frame.
_last_stream: tuple[str, FrameStream] | None = None


class Session:
    """One Blender render of a scene with Apply on Render on: the pass configuration,
    the temporary files, the queue of frames and their delivery.

    Parameters
    ----------
    scene : bpy.types.Scene
    deferred : bool
        The handlers run on Blender's render thread (the UI): everything but
        the settings switch waits for :meth:`finish_steps` on the main thread.
    """

    def __init__(self, scene, deferred: bool) -> None:
        from .render import job_from_scene

        settings = scene.sss_settings
        engine = pass_engine(scene)
        if scene.render.use_multiview:
            raise RenderError("Apply on Render does not support stereoscopy / multi-view")
        self.scene = scene
        self.deferred = deferred
        self.folder = Path(tempfile.mkdtemp(prefix="cvsss-render-"))
        self.passes = self.folder / "passes"
        self.final = self.folder / "final"
        self.final.mkdir()
        try:
            self.job = job_from_scene(
                scene,
                frames=(0, 0),
                out=self.folder,
                methods=[settings.method],
                reference=False,
                engine=engine,
                images=True,
                ground_truth=False,
            )
        except BaseException:
            shutil.rmtree(self.folder, ignore_errors=True)
            raise
        self.method = self.job.methods[0]
        self.warmup = int(settings.warmup_frames)
        self.step = max(1, int(scene.frame_step))
        r = scene.render
        self.movie = bool(r.is_movie_format)
        self.overwrite, self.placeholder = bool(r.use_overwrite), bool(r.use_placeholder)
        self.notes = _bypassed(scene)
        self.setup: PassSetup | None = None
        self.output = None
        self.stream: FrameStream | None = None
        self.sidecars: dict[int, dict] = {}
        self.started: list[int] = []  # frames Blender began (render_pre)
        self.pending: deque[tuple[int, Path]] = deque()  # pass files not processed yet
        self.undelivered: deque[int] = deque()  # finished frames not written yet
        self.processed: list[int] = []
        self.delivered: list[tuple[int, str]] = []
        self.skip: set[int] = set()
        self.placeholders: list[Path] = []
        self.still: bool | None = None
        self.write_still = False
        self.last: np.ndarray | None = None
        self.error: str | None = None
        self.cancelled = False
        self.rendered = False  # Blender's render has ended (complete or cancel)
        self.finishing = False  # sss.finish_render has started (UI)
        self.closed = False
        self.began = time.perf_counter()
        self.filter = (
            StdoutFilter(str(self.folder)) if bpy.app.background and not deferred else None
        )
        self.suspended: tuple[bool, bool] | None = None  # (setup, output) put aside for a save
        try:
            if not deferred:
                self.output = output_scene(scene, self.job.view_layer.name)
            self.setup = self._switch()
        except BaseException:
            self.close()
            raise
        if self.filter is not None:
            self.filter.start()
        what = "movie: frames are encoded after the last one" if self.movie else ""
        _log(
            f"Apply on Render: {self.method} on {engine} passes, warm-up {self.warmup} "
            f"frame(s){'; ' + what if what else ''}"
        )
        for note in self.notes:
            _log("note: " + note)
        from .autoexec import warning  # skipped by Blender's own render as well

        skipped = warning("trust the file (blender -y, or Auto Run Python Scripts) to run them")
        if skipped is not None:
            _log(skipped)
        # The numba kernels compile in a process of their own while Blender renders, when
        # they are not cached yet (the add-on's registration in the UI started it already).
        precompile.start_background(
            self.job.params.backend, self.job.methods, _log, math.prod(output_size(scene))
        )

    def _switch(self) -> PassSetup:
        """The scene in the pass configuration, its passes written into the temporary folder."""
        setup = PassSetup(
            self.scene,
            self.job.materials,
            self.job.view_layer,
            self.job.engine,
            self.job.normal,
            self.job.denoise_passes,
        ).__enter__()
        r = self.scene.render
        r.filepath = str(self.passes / "pass_")
        r.use_overwrite = True
        r.use_placeholder = False
        return setup

    # -- saving while the render is finished (UI) ------------------------------------------
    def suspend(self) -> None:
        """Before a save: the user's settings back and the output scene gone, so the .blend
        holds the user's scene only (:meth:`resume` after the save)."""
        if not self.rendered or self.closed or self.suspended is not None:
            return  # only between Blender's render and the end (the render thread is done)
        self.suspended = (self.setup is not None, self.output is not None)
        self.restore()
        if self.output is not None:
            bpy.data.scenes.remove(self.output)
            self.output = None

    def resume(self) -> None:
        """After a save: what :meth:`suspend` put aside, again."""
        if self.suspended is None:
            return
        setup, output = self.suspended
        self.suspended = None
        if self.closed:
            return
        if setup:
            self.setup = self._switch()
        if output:
            self.output = output_scene(self.scene, self.job.view_layer.name)

    # -- history ---------------------------------------------------------------------------
    def _key(self) -> str:
        job = self.job
        return json.dumps(
            [
                bpy.data.filepath,
                self.scene.name,
                job.view_layer.name,
                self.method,
                job.params.to_dict(),
                job.options.to_dict(),
                job.engine,
                job.denoise_passes,
                self.scene.render.resolution_x,
                self.scene.render.resolution_y,
                self.scene.render.resolution_percentage,
            ],
            sort_keys=True,
            default=str,
        )

    def _open_stream(self, first: int) -> bool:
        """The history for a render starting at ``first``; True when it needs warm-up."""
        global _last_stream
        key = self._key()
        if bpy.app.background and _last_stream is not None and _last_stream[0] == key:
            stream = _last_stream[1]
            if stream.last is not None and first in (stream.last + 1, stream.last + self.step):
                self.stream = stream
                _log(f"continuing the history of frame {stream.last}")
                return False
        self.stream = FrameStream(RunSpec((self.method,), self.job.params, self.job.options))
        _last_stream = (key, self.stream) if bpy.app.background else None
        return self.warmup > 0

    def warm_up_steps(self, first: int) -> Iterator[str]:
        """Render and process the warm-up frames before ``first`` (one step each)."""
        from .passes import render_frame
        from .render import warmup_frames

        frames = warmup_frames(first, self.warmup, self.step)
        for index, frame in enumerate(frames, 1):
            began = time.perf_counter()
            # A scene of its own has its own Render, so this nests inside the user's
            # render. One per frame: between steps (a save in the UI) none exists.
            copy = scene_copy(self.scene, "warm-up")
            try:
                layer = copy.view_layers[self.job.view_layer.name]
                with frame_of(self.scene, frame):
                    copy.frame_set(frame)
                    specs = sss_materials.material_specs(self.job.materials, copy)
                    with self._internal(), bpy.context.temp_override(scene=copy):
                        path = render_frame(
                            copy, frame, self.passes, specs, layer, self.job.denoise_passes
                        )
            finally:
                bpy.data.scenes.remove(copy)
            frame_passes = self._read(frame, path)
            precompile.prepare(
                self.job.params.backend, self.job.methods, math.prod(frame_passes.shape), _log
            )
            self.stream.warm_up(frame_passes)
            text = (
                f"warm-up frame {frame} ({index}/{len(frames)}): passes and post "
                f"{time.perf_counter() - began:.2f} s"
            )
            _log(text)
            yield text

    # -- frames ------------------------------------------------------------------------------
    def _internal(self):
        return self.filter.internal() if self.filter is not None else contextlib.nullcontext()

    def frame_started(self, frame: int) -> None:
        """render_pre: the sidecar, placeholders and existing files of ``frame``."""
        self.started.append(frame)
        scene = self.scene
        if not self.deferred and _camera_animated(scene, self.job.materials):
            scene.frame_set(frame)
        specs = sss_materials.material_specs(self.job.materials, scene)
        self.sidecars[frame] = pass_sidecar(scene, frame, specs, self.job.view_layer)
        if self.output is not None and not self.movie:
            path = Path(self.output.render.frame_path(frame=frame))
            if not self.overwrite and path.exists():
                self.skip.add(frame)
            elif self.placeholder and not path.exists():
                path.parent.mkdir(parents=True, exist_ok=True)
                path.touch()
                self.placeholders.append(path)

    def frame_written(self, frame: int) -> None:
        """render_write: Blender wrote the pass EXR of ``frame``; queue it."""
        path = self.passes / f"pass_{frame:04d}.exr"
        if not path.is_file():
            still = self.passes / "pass_.exr"
            if not still.is_file():
                raise RenderError(f"Blender wrote no pass file for frame {frame}")
            path = still.rename(self.passes / "still.exr")
            self.still, self.write_still = True, True
        else:
            self.still = False
        self._queue(frame, path)

    def _queue(self, frame: int, path: Path) -> None:
        sidecar = self.sidecars.get(frame)
        if sidecar is None:
            raise RenderError(f"frame {frame} was written but never started")
        write_sidecar(path.with_suffix(".json"), sidecar, overwrite=True)
        self.pending.append((frame, path))

    def _read(self, frame: int, path: Path):
        with quiet_native_stderr():
            return read_frame(path, number=frame)

    def process_next(self) -> str:
        """Post-process the oldest queued pass file; the progress line."""
        frame, path = self.pending.popleft()
        began = time.perf_counter()
        sidecar = self.sidecars[frame]
        with self._internal():
            finish_pass_file(
                path, self.scene, self.job.view_layer, sidecar, self.job.denoise_passes
            )
        passes = self._read(frame, path)
        precompile.prepare(self.job.params.backend, self.job.methods, math.prod(passes.shape), _log)
        result = self.stream.step(passes)[self.method]
        alpha = read_alpha(path, self.job.view_layer.name)
        rgba = np.empty((*result.composite.shape[:2], 4), np.float32)
        rgba[..., :3] = result.composite
        rgba[..., 3] = 1.0 if alpha is None else alpha
        self.last = rgba
        if self.movie or self.deferred:
            np.save(self.final / f"{frame}.npy", rgba)
        self.processed.append(frame)
        if not self.still:
            self.undelivered.append(frame)
        from .images import show_result
        from .properties import store_stats

        show_result(result)
        store_stats(self.scene.sss_settings, frame, self.method, result.spp, result.pass_ms, None)
        seconds = time.perf_counter() - began
        return f"frame {frame} {self.method}: spp {result.spp:.2f}, post {seconds:.2f} s"

    def _rgba(self, frame: int) -> np.ndarray | None:
        if self.last is not None and self.processed and self.processed[-1] == frame:
            return self.last
        path = self.final / f"{frame}.npy"
        return np.load(path) if path.is_file() else None

    def deliver_next(self) -> str:
        """Write the oldest finished frame of an animation with Blender's own writer."""
        frame = self.undelivered.popleft()
        out = self.output
        path = out.render.frame_path(frame=frame)
        if frame in self.skip or (self.deferred and not self.overwrite and Path(path).exists()):
            return f"{path} exists, kept (Overwrite is off)"
        rgba = self._rgba(frame)
        out.frame_start = out.frame_end = frame
        with self._internal(), _rendering(lambda _frame: rgba):
            with bpy.context.temp_override(scene=out):
                bpy.ops.render.render(animation=True)
        self.delivered.append((frame, path))
        with contextlib.suppress(ValueError):
            self.placeholders.remove(Path(path))
        return f"-> {path}"

    def encode(self) -> str:
        """Encode the finished frames into the user's movie with Blender's own writer."""
        out = self.output
        frames = self.processed
        out.frame_start, out.frame_end, out.frame_step = frames[0], frames[-1], self.step
        with self._internal(), _rendering(self._rgba):
            with bpy.context.temp_override(scene=out):
                bpy.ops.render.render(animation=True)
        path = out.render.frame_path(frame=frames[0])
        self.delivered += [(f, path) for f in frames]
        return f"{len(frames)} frame(s) encoded -> {path}"

    def display(self, write: bool) -> str:
        """Render the last finished frame on the user's scene: the Render Result (and, with
        ``write``, the still file where Blender writes it)."""
        rgba = self.last
        with DisplaySetup(self.scene, self.job.view_layer), self._internal():
            with _rendering(lambda _frame: rgba):
                bpy.ops.render.render(write_still=write, scene=self.scene.name)
        if write:
            return f"frame {self.processed[-1]} -> {bpy.path.abspath(self.scene.render.filepath)}"
        return f"frame {self.processed[-1]} shown as the Render Result"

    def save_render_result(self) -> None:
        """A still rendered without writing: its passes from the Render Result."""
        frame = self.started[-1]
        path = self.passes / "still.exr"
        self.passes.mkdir(parents=True, exist_ok=True)
        with self._internal():
            bpy.data.images["Render Result"].save_render(str(path), scene=self.scene)
        self.still = True
        self._queue(frame, path)

    def abort(self, message: str) -> None:
        """Stop Blender's animation: its next write fails, so it cancels."""
        self.error = message
        _log("error: " + message)
        blocker = self.folder / "stop"
        blocker.write_text("cvsss stopped this render\n")
        self.scene.render.filepath = str(blocker / "pass_")

    # -- the end -----------------------------------------------------------------------------
    def finish_steps(self) -> Iterator[str]:
        """What is left after Blender's render ended, one step at a time (see module doc)."""
        try:
            if self.error is None:
                if self.started and not self.pending and self.still is None and not self.cancelled:
                    self.save_render_result()  # a still rendered without writing (F12)
                if self.pending and not precompile.prepared(
                    self.job.params.backend, self.job.methods
                ):
                    yield precompile.PREPARING  # UI: in the status bar while the next tick waits
                if self.stream is None and self.pending:
                    first = self.pending[0][0]
                    if self._open_stream(first):
                        yield from self.warm_up_steps(first)
                while self.pending:
                    text = self.process_next()
                    _log(text)
                    yield text
            self.restore()
            if self.error is None and self.processed:
                if self.output is None:
                    self.output = output_scene(self.scene, self.job.view_layer.name)
                if self.movie and not self.still:
                    text = self.encode()
                    _log(text)
                    yield text
                while self.undelivered and not self.movie:
                    frame = self.undelivered[0]
                    text = f"frame {frame} {self.deliver_next()}"
                    _log(text)
                    yield text
                if self.still or self.deferred:
                    text = self.display(write=bool(self.still and self.write_still))
                    _log(text)
                    yield text
        except Exception as exc:  # closed below: its last line names the error
            if self.error is None:
                self.error = f"{type(exc).__name__}: {exc}"
            raise
        finally:
            self.close()

    def restore(self) -> None:
        """The user's materials, passes and render settings back (safe to call twice)."""
        if self.setup is not None:
            self.setup.restore()
            self.setup = None

    def close(self) -> None:
        """Restore everything, remove the temporary scenes and files (safe to call twice)."""
        global _session
        if self.closed:
            return
        self.closed = True
        try:
            self.restore()
        finally:
            if self.output is not None:
                with contextlib.suppress(ReferenceError, RuntimeError):
                    bpy.data.scenes.remove(self.output)
                self.output = None
            for path in self.placeholders:  # frames that never came: as Blender does
                with contextlib.suppress(OSError):
                    if path.stat().st_size == 0:
                        path.unlink()
            shutil.rmtree(self.folder, ignore_errors=True)
            seconds = time.perf_counter() - self.began
            if self.error is not None:
                _log(f"stopped after {len(self.delivered)} delivered frame(s): {self.error}")
            else:
                how = "cancelled" if self.cancelled else "done"
                _log(f"{how}: {len(self.delivered)} frame(s) delivered in {seconds:.1f} s")
            if self.filter is not None:
                self.filter.stop()
            if _session is self:
                _session = None


# -- handlers -------------------------------------------------------------------------------
_session: Session | None = None
#: (scene, engine) of a render stopped at render_init, put back at its end.
_stopped: tuple[object, str] | None = None


def active_session() -> Session | None:
    """The render in progress or waiting for :meth:`Session.finish_steps`, if any."""
    return _session


def _wanted(scene) -> bool:
    if rendering_internally():
        return False
    settings = getattr(scene, "sss_settings", None)
    return settings is not None and settings.apply_on_render


def _stop(scene, message: str) -> None:
    """Make Blender cancel this render before it writes anything, with ``message``."""
    global _stopped, _task
    _log("error: " + message)
    _stopped = (scene, scene.render.engine)
    _task = "cvsss: " + message
    scene.render.engine = ENGINE


def _ours(scene) -> Session | None:
    session = _session
    if session is None or session.closed or session.rendered or rendering_internally():
        return None
    return session if session.scene == scene else None


def _on_render_thread() -> bool:
    """Whether the handler runs on Blender's render thread (a UI render), not the main one."""
    return threading.current_thread() is not threading.main_thread()


@persistent
def on_render_init(scene, *_args) -> None:
    global _session
    if not _wanted(scene):
        return
    deferred = _on_render_thread()
    if _session is not None and not _session.deferred:
        # Blender gave up on that render before it began (its render_init failed after
        # ours): nothing will end it, so it ends here.
        _session.cancelled = _session.rendered = True
        _session.close()
    if _session is not None:
        _stop(scene, "the previous render is still being finished; render again when it is done")
        return
    try:
        _session = Session(scene, deferred)
    except RenderError as exc:
        _stop(scene, str(exc))
    except Exception as exc:  # the user's render must not run half-configured
        _stop(scene, f"could not prepare the render: {type(exc).__name__}: {exc}")


@persistent
def on_render_pre(scene, *_args) -> None:
    session = _ours(scene)
    if session is None or session.error is not None:
        return
    frame = int(scene.frame_current)
    try:
        if not session.deferred and session.stream is None:
            if session._open_stream(frame):
                for _ in session.warm_up_steps(frame):
                    pass
        session.frame_started(frame)
    except Exception as exc:  # reported, and the render stopped
        session.abort(f"frame {frame}: {type(exc).__name__}: {exc}")
    if session.filter is not None:
        session.filter.forward()


@persistent
def on_render_write(scene, *_args) -> None:
    session = _ours(scene)
    if session is None or session.error is not None:
        return
    frame = int(scene.frame_current)
    try:
        session.frame_written(frame)
        if not session.deferred and not session.still:
            while session.pending:
                text = session.process_next()
                if session.movie:
                    text += " (movie: encoded after the last frame)"
                else:
                    text += " " + session.deliver_next()
                _log(text)
    except Exception as exc:  # reported, and the render stopped
        session.abort(f"frame {frame}: {type(exc).__name__}: {exc}")


@persistent
def on_render_stats(*_args) -> None:
    session = _session
    if session is not None and session.filter is not None and not session.rendered:
        session.filter.forward()


def _ended(scene, cancelled: bool) -> None:
    global _stopped, _task
    if _stopped is not None and _stopped[0] == scene and not rendering_internally():
        stopped_scene, engine = _stopped
        _stopped, _task = None, None
        stopped_scene.render.engine = engine
        return
    session = _ours(scene)
    if session is None:
        return
    session.rendered = True
    session.cancelled = cancelled
    if session.deferred:
        return  # the main thread finishes (_poll)
    with contextlib.suppress(Exception):  # restored, and the error logged, by finish_steps
        for _ in session.finish_steps():
            pass


@persistent
def on_render_complete(scene, *_args) -> None:
    _ended(scene, cancelled=False)


@persistent
def on_render_cancel(scene, *_args) -> None:
    _ended(scene, cancelled=True)


@persistent
def on_save_pre(*_args) -> None:
    """A save while a render is being finished (UI): the user's scene goes to the file."""
    session = _session
    if session is not None:
        session.suspend()


@persistent
def on_save_post(*_args) -> None:
    session = _session
    if session is not None:
        session.resume()


@persistent
def on_load_pre(*_args) -> None:
    """A file is loaded over a session that never finished: put the scene back first."""
    session = _session
    if session is not None:
        session.close()


def _poll() -> float:
    """UI: start finishing a render once Blender's render job is over."""
    session = _session
    if (
        session is not None
        and session.deferred
        and not session.closed
        and not session.finishing
        and not bpy.app.is_job_running("RENDER")
    ):
        if not session.rendered:  # the job ended without render_complete/cancel
            session.cancelled = session.rendered = True
        session.finishing = True
        wm = bpy.context.window_manager
        window = wm.windows[0] if wm and wm.windows else None
        try:
            if window is None:
                for _ in session.finish_steps():
                    pass
            else:
                with bpy.context.temp_override(window=window):
                    bpy.ops.sss.finish_render("INVOKE_DEFAULT")
        except Exception as exc:  # never leave the scene switched
            _log(f"error: {type(exc).__name__}: {exc}")
            session.close()
    return 0.25


_HANDLERS = {
    "render_init": on_render_init,
    "render_pre": on_render_pre,
    "render_write": on_render_write,
    "render_stats": on_render_stats,
    "render_complete": on_render_complete,
    "render_cancel": on_render_cancel,
    "load_pre": on_load_pre,
    "save_pre": on_save_pre,
    "save_post": on_save_post,
    # Blender 4.3+: a save that failed (the file unwritable) also ends the suspension.
    "save_post_fail": on_save_post,
}


def register() -> None:
    bpy.utils.register_class(ResultEngine)
    for name, handler in _HANDLERS.items():
        if hasattr(bpy.app.handlers, name):
            getattr(bpy.app.handlers, name).append(handler)
    if not bpy.app.background:
        bpy.app.timers.register(_poll, first_interval=1.0, persistent=True)


def unregister() -> None:
    global _last_stream
    if bpy.app.timers.is_registered(_poll):
        bpy.app.timers.unregister(_poll)
    for name, handler in _HANDLERS.items():
        handlers = getattr(bpy.app.handlers, name, ())
        if handler in handlers:
            handlers.remove(handler)
    if _session is not None:
        _session.close()
    _last_stream = None
    bpy.utils.unregister_class(ResultEngine)

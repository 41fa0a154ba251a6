"""One render of the user's with Apply on Render on: the :class:`Session`.

A Session holds what one Blender render of a scene needs from the moment the
scene switches to the pass configuration (``render_init``) until every
setting is restored and the temporary files are gone: the pass
configuration, the temporary folder, the frames' sidecars, the queue of pass
files, the history (:class:`core.run.FrameStream`, continued across
consecutive background renders), the warm-up frames and the delivery of the
finished frames through :class:`.engine.ResultEngine`. The handlers
(:mod:`.handlers`) drive it; the package's doc tells the order.
"""

from __future__ import annotations

import contextlib
import json
import math
import shutil
import tempfile
import time
from collections import deque
from collections.abc import Iterator, Mapping
from pathlib import Path

import bpy
import numpy as np

from ....core.io.exr import quiet_native_stderr, read_channels, read_frame
from ....core.io.sidecar import write_sidecar
from ....core.methods import METHODS
from ....core.run import FrameStream, RunSpec
from ... import precompile
from .. import materials as sss_materials
from ..autoexec import warning as skipped_python
from ..console import StdoutFilter
from ..denoise_frame import FrameDenoiser, guides_of
from ..errors import RenderError
from ..images import show_result
from ..passes import (
    NEEDED_PASSES,
    finish_pass_file,
    output_size,
    pass_sidecar,
    render_frame,
    render_view_layer,
)
from ..properties import store_stats
from ..render import job_from_scene, warmup_frames
from . import compositor
from .engine import Finished, rendering
from .frame_passes import FramePasses
from .notes import bypassed, model_notes
from .scenes import (
    DisplaySetup,
    camera_animated,
    frame_of,
    output_scene,
    pass_engine,
    scene_copy,
)
from .user_render import KeepingPassSetup, user_render


def warm_up_pays(method: str) -> bool:
    """Whether warm-up frames pay for ``method``: it reuses its history's estimates
    (a temporal method), so a cold history makes the first frames noisier.

    The other methods' history only steers the sample counts: 8 warm-up frames
    changed a still's frame by at most 0.06 dB against Cycles' ground truth
    (``tools/measure/apply_on_render_quality.py``: as_ccv and as_ocv, and the
    temporal ones too, whose reuse has nothing to gain on a still), for one
    pass render each. A still (F12, ``-f``) renders none either way.
    """
    return bool(METHODS[method].temporal)


def log(text: str) -> None:
    """One line of Apply on Render's progress on stdout."""
    print(f"cvsss: {text}", flush=True)


def combined_alpha(channels: Mapping[str, np.ndarray], layer: str) -> np.ndarray | None:
    """The Combined alpha among a pass file's channels (:func:`core.io.exr.read_channels`),
    (H, W) float32 top row first, or None when it has none."""
    for key in (f"{layer}.Combined.A", "Combined.A"):
        if key in channels:
            return np.asarray(channels[key], dtype=np.float32)
    return None


def _remove(*files: Path) -> None:
    """Remove temporary files, those that exist (a file that cannot go stays until the
    session's folder is removed)."""
    for name in files:
        with contextlib.suppress(OSError):
            name.unlink(missing_ok=True)


#: The history of the last render in background mode, continued by a render of the next frame.
_last_stream: tuple[str, FrameStream] | None = None
#: The render in progress or waiting for :meth:`Session.finish_steps` (one at a time).
_active: Session | None = None


def active_session() -> Session | None:
    """The render in progress or waiting for :meth:`Session.finish_steps`, if any."""
    return _active


def start_session(scene, deferred: bool) -> Session:
    """A :class:`Session` for ``scene``, the active one from now on (until it closes)."""
    global _active
    _active = Session(scene, deferred)
    return _active


def forget_history() -> None:
    """Drop the history kept for a next background render (the add-on is unregistered)."""
    global _last_stream
    _last_stream = None


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
        settings = scene.sss_settings
        engine = pass_engine(scene)
        if scene.render.use_multiview:
            raise RenderError("Apply on Render does not support stereoscopy / multi-view")
        self.scene = scene
        self.deferred = deferred
        # What the user's own render would make, read before anything changes.
        self.user = user_render(scene, render_view_layer(scene))
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
        # The scene's denoiser, for the finished frames (then the passes are not denoised).
        self.denoise = self.job.denoise
        # Built once for the whole render (OIDN's filters), freed by close().
        self.denoiser = None if self.denoise is None else FrameDenoiser(self.denoise)
        self.warmup = int(settings.warmup_frames) if warm_up_pays(self.method) else 0
        self.step = max(1, int(scene.frame_step))
        r = scene.render
        self.movie = bool(r.is_movie_format)
        self.overwrite, self.placeholder = bool(r.use_overwrite), bool(r.use_placeholder)
        self.notes = bypassed(scene) + model_notes(scene)
        self.setup: KeepingPassSetup | None = None
        self.output = None
        self.groups: list = []  # the output scene's copies of the compositor's node groups
        self.frame_passes: FramePasses | None = None
        self.paths: dict[int, Path] = {}  # frame -> its pass file (read again at delivery)
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
        self.last_noisy: np.ndarray | None = None  # self.last before its denoise
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
                self.output = self._output_scene()
            self.setup = self._switch()
        except BaseException:
            self.close()
            raise
        if self.filter is not None:
            self.filter.start()
        what = "movie: frames are encoded after the last one" if self.movie else ""
        warm = (
            f"warm-up {self.warmup} frame(s) before an animation"
            if self.warmup
            else "no warm-up"
            + ("" if warm_up_pays(self.method) else f" ({self.method} reuses no estimates)")
        )
        log(
            f"Apply on Render: {self.method} on {engine} passes, {warm}"
            f"{'; ' + what if what else ''}"
        )
        if self.denoise is not None:
            why = "on EEVEE" if self.denoise.subsurface_only else "as the scene asks"
            log(f"the finished frames are denoised {why}: {self.denoise.describe()}")
        if self.user.needs_passes:
            where = " and ".join(
                what
                for what, on in (
                    ("the compositor", self.user.compositor),
                    ("the multilayer EXR", self.user.multilayer),
                )
                if on
            )
            log(f"{len(self.user.passes)} pass(es) of the view layer go to {where}")
        for note in self.notes:
            log("note: " + note)
        # Blender's own render skips them as well.
        skipped = skipped_python(
            "trust the file (blender -y, or Auto Run Python Scripts) to run them"
        )
        if skipped is not None:
            log(skipped)
        # The numba passes compile in a process of their own while Blender renders, when
        # they are not cached yet (the add-on's registration in the UI started it already).
        precompile.start_background(
            self.job.params.backend, self.job.methods, log, math.prod(output_size(scene))
        )

    def _switch(self) -> KeepingPassSetup:
        """The scene in the pass configuration, its passes written into the temporary folder:
        the add-on's, the user's when the finished frames carry them, and the denoiser's
        guides when the scene denoises."""
        user = self.user if self.user.needs_passes else None
        setup = KeepingPassSetup(
            self.scene,
            self.job.materials,
            self.job.view_layer,
            self.job.engine,
            self.job.normal,
            self.job.denoise_passes,
            user=user,
            guides=self.denoise is not None,
            thin=self.job.thin,
            thin_points=self.job.thin_points,
            # Its one method: the Vector pass only where it reprojects estimates.
            motion=bool(METHODS[self.method].temporal),
        ).__enter__()
        r = self.scene.render
        r.filepath = str(self.passes / "pass_")
        r.use_overwrite = True
        r.use_placeholder = False
        if user is not None:
            self.frame_passes = FramePasses(
                user.passes, self.job.view_layer.name, setup.index_tables()
            )
        return setup

    def _output_scene(self):
        """The output scene (:func:`.scenes.output_scene`), with the user's compositor."""
        return output_scene(self.scene, self.job.view_layer.name, self.user.compositor, self.groups)

    def _remove_output(self) -> None:
        if self.output is not None:
            with contextlib.suppress(ReferenceError, RuntimeError):
                bpy.data.scenes.remove(self.output)
            self.output = None
        compositor.remove(self.groups)

    # -- saving while the render is finished (UI) ------------------------------------------
    def suspend(self) -> None:
        """Before a save: the user's settings back and the output scene gone, so the .blend
        holds the user's scene only (:meth:`resume` after the save)."""
        if not self.rendered or self.closed or self.suspended is not None:
            return  # only between Blender's render and the end (the render thread is done)
        self.suspended = (self.setup is not None, self.output is not None)
        self.restore()
        self._remove_output()

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
            self.output = self._output_scene()

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

    def open_stream(self, first: int) -> bool:
        """The history for a render starting at ``first``; True when it needs warm-up
        (a method whose history pays for it, in an animation: :func:`warm_up_pays`)."""
        global _last_stream
        key = self._key()
        if bpy.app.background and _last_stream is not None and _last_stream[0] == key:
            stream = _last_stream[1]
            if stream.last is not None and first in (stream.last + 1, stream.last + self.step):
                self.stream = stream
                log(f"continuing the history of frame {stream.last}")
                return False
        self.stream = FrameStream(RunSpec((self.method,), self.job.params, self.job.options))
        _last_stream = (key, self.stream) if bpy.app.background else None
        return self.warmup > 0 and not self.still

    def warm_up_steps(self, first: int) -> Iterator[str]:
        """Render and process the warm-up frames before ``first`` (one step each)."""
        frames = warmup_frames(first, self.warmup, self.step)
        for index, frame in enumerate(frames, 1):
            began = time.perf_counter()
            # A scene of its own has its own Render, so this nests inside the user's
            # render. One per frame: between steps (a save in the UI) none exists.
            copy = scene_copy(self.scene, "warm-up")
            try:
                layer = copy.view_layers[self.job.view_layer.name]
                self._lean(layer)
                with frame_of(self.scene, frame):
                    copy.frame_set(frame)
                    specs = sss_materials.material_specs(self.job.materials, copy)
                    with self._internal(), bpy.context.temp_override(scene=copy):
                        path = render_frame(
                            copy,
                            frame,
                            self.passes,
                            specs,
                            layer,
                            self.job.denoise_passes,
                            thin=self.job.thin_record,
                        )
            finally:
                bpy.data.scenes.remove(copy)
            frame_passes, _ = self._read(frame, path)
            precompile.ensure_compiled(
                self.job.params.backend, self.job.methods, math.prod(frame_passes.shape), log
            )
            self.stream.warm_up(frame_passes)
            _remove(path, path.with_suffix(".json"))  # the history holds what it needs
            text = (
                f"warm-up frame {frame} ({index}/{len(frames)}): passes and post "
                f"{time.perf_counter() - began:.2f} s"
            )
            log(text)
            yield text

    def _lean(self, layer) -> None:
        """A warm-up copy's view layer renders the add-on's passes only: nothing is
        delivered or denoised from a warm-up frame."""
        own = set(NEEDED_PASSES) | ({"use_pass_normal"} if self.job.normal else set())
        for ident in self.user.pass_flags - own:
            setattr(layer, ident, False)
        cycles = getattr(layer, "cycles", None)
        if cycles is not None:
            for ident in self.user.cycles_flags:
                setattr(cycles, ident, False)
            cycles.denoising_store_passes = self.job.denoise_passes

    # -- frames ------------------------------------------------------------------------------
    def _internal(self):
        return self.filter.internal() if self.filter is not None else contextlib.nullcontext()

    def frame_started(self, frame: int) -> None:
        """render_pre: the sidecar, placeholders and existing files of ``frame``."""
        self.started.append(frame)
        scene = self.scene
        if not self.deferred and camera_animated(scene, self.job.materials):
            scene.frame_set(frame)
        specs = sss_materials.material_specs(self.job.materials, scene)
        self.sidecars[frame] = pass_sidecar(
            scene, frame, specs, self.job.view_layer, self.job.thin_record
        )
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
        """The frame's passes and every channel of its file (read once)."""
        with quiet_native_stderr():
            channels = read_channels(path)
            return read_frame(path, number=frame, channels=channels), channels

    def process_next(self) -> str:
        """Post-process the oldest queued pass file; the progress line."""
        frame, path = self.pending.popleft()
        began = time.perf_counter()
        sidecar = self.sidecars[frame]
        with self._internal():
            finish_pass_file(
                path, self.scene, self.job.view_layer, sidecar, self.job.denoise_passes
            )
        passes, channels = self._read(frame, path)
        precompile.ensure_compiled(
            self.job.params.backend, self.job.methods, math.prod(passes.shape), log
        )
        result = self.stream.step(passes)[self.method]
        alpha = combined_alpha(channels, self.job.view_layer.name)
        rgba = np.empty((*result.composite.shape[:2], 4), np.float32)
        rgba[..., :3] = result.composite
        rgba[..., 3] = 1.0 if alpha is None else alpha
        noisy = None
        if self.denoise is not None:
            noisy = rgba
            guides = guides_of(channels, self.job.view_layer.name)
            rgba = self.denoiser.finished(noisy, result, passes, guides)
        self.last, self.last_noisy = rgba, noisy
        self.paths[frame] = path
        if self.movie or self.deferred:
            np.save(self.final / f"{frame}.npy", rgba)
            if noisy is not None and self.frame_passes is not None:
                np.save(self.final / f"{frame}.noisy.npy", noisy)
        self.processed.append(frame)
        if not self.still:
            self.undelivered.append(frame)
        show_result(result)
        store_stats(
            self.scene.sss_settings, frame, self.method, result.spp, result.sampling_ms, None
        )
        seconds = time.perf_counter() - began
        return f"frame {frame} {self.method}: spp {result.spp:.2f}, post {seconds:.2f} s"

    def _rgba(self, frame: int, noisy: bool = False) -> np.ndarray | None:
        if self.last is not None and self.processed and self.processed[-1] == frame:
            return self.last_noisy if noisy else self.last
        path = self.final / (f"{frame}.noisy.npy" if noisy else f"{frame}.npy")
        return np.load(path) if path.is_file() else None

    def _finished(self, frame: int) -> Finished:
        """What :class:`.engine.ResultEngine` delivers for ``frame``: the finished frame,
        with the view layer's passes when a compositor or a multilayer file takes them."""
        rgba = self._rgba(frame)
        if rgba is None or self.frame_passes is None:
            return rgba
        return self.frame_passes.delivery(self.paths[frame], rgba, self._rgba(frame, noisy=True))

    @contextlib.contextmanager
    def _delivering(self, scene, task) -> Iterator[None]:
        """:class:`.engine.ResultEngine` renders ``task`` in the block, ``scene``'s Render
        Layers nodes offering the passes it declares (and the scene's own ones after)."""
        specs = ()
        if self.frame_passes is not None and self.paths:
            specs = self.frame_passes.specs(next(iter(self.paths.values())))
        try:
            with self._internal(), rendering(task, specs):
                compositor.refresh_render_layers(scene)
                yield
        finally:
            compositor.refresh_render_layers(scene)

    def deliver_next(self) -> str:
        """Write the oldest finished frame of an animation with Blender's own writer."""
        frame = self.undelivered.popleft()
        out = self.output
        path = out.render.frame_path(frame=frame)
        if frame in self.skip or (self.deferred and not self.overwrite and Path(path).exists()):
            self._done_with(frame)
            return f"{path} exists, kept (Overwrite is off)"
        out.frame_start = out.frame_end = frame
        with self._delivering(out, self._finished):
            with bpy.context.temp_override(scene=out):
                bpy.ops.render.render(animation=True)
        self.delivered.append((frame, path))
        with contextlib.suppress(ValueError):
            self.placeholders.remove(Path(path))
        self._done_with(frame)
        return f"-> {path}"

    def _done_with(self, frame: int) -> None:
        """Remove the temporary files of a delivered frame (its pass file and sidecar, its
        finished frame), so a long animation's temporary folder holds a few frames' files,
        not all of them, until the render ends."""
        path = self.paths.pop(frame, None)
        _remove(self.final / f"{frame}.npy", self.final / f"{frame}.noisy.npy")
        if path is not None:
            _remove(path, path.with_suffix(".json"))

    def encode(self) -> str:
        """Encode the finished frames into the user's movie with Blender's own writer."""
        out = self.output
        frames = self.processed
        out.frame_start, out.frame_end, out.frame_step = frames[0], frames[-1], self.step
        with self._delivering(out, self._finished):
            with bpy.context.temp_override(scene=out):
                bpy.ops.render.render(animation=True)
        path = out.render.frame_path(frame=frames[0])
        self.delivered += [(f, path) for f in frames]
        return f"{len(frames)} frame(s) encoded -> {path}"

    def display(self, write: bool) -> str:
        """Render the last finished frame on the user's scene: the Render Result (and, with
        ``write``, the still file where Blender writes it)."""
        frame = self.processed[-1]
        with DisplaySetup(self.scene, self.job.view_layer):
            with self._delivering(self.scene, lambda _frame: self._finished(frame)):
                bpy.ops.render.render(write_still=write, scene=self.scene.name)
        compositor.refresh_render_layers(self.scene)  # the user's engine's sockets again
        where = bpy.path.abspath(self.scene.render.filepath) if write else "the Render Result"
        self.delivered.append((frame, where))
        if write:
            return f"frame {frame} -> {where}"
        return f"frame {frame} shown as the Render Result"

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
        log("error: " + message)
        blocker = self.folder / "stop"
        blocker.write_text("cvsss stopped this render\n")
        self.scene.render.filepath = str(blocker / "pass_")

    # -- the end -----------------------------------------------------------------------------
    def finish_steps(self) -> Iterator[str]:
        """What is left after Blender's render ended, one step at a time (see the package doc)."""
        try:
            if self.error is None:
                if self.started and not self.pending and self.still is None and not self.cancelled:
                    self.save_render_result()  # a still rendered without writing (F12)
                if self.pending and not precompile.compiled_ready(
                    self.job.params.backend, self.job.methods
                ):
                    yield precompile.COMPILING_STATUS  # UI: in the status bar while the next tick waits
                if self.stream is None and self.pending:
                    first = self.pending[0][0]
                    if self.open_stream(first):
                        yield from self.warm_up_steps(first)
                while self.pending:
                    text = self.process_next()
                    log(text)
                    yield text
            self.restore()
            if self.error is None and self.processed:
                if self.output is None:
                    self.output = self._output_scene()
                if self.movie and not self.still:
                    text = self.encode()
                    log(text)
                    yield text
                while self.undelivered and not self.movie:
                    frame = self.undelivered[0]
                    text = f"frame {frame} {self.deliver_next()}"
                    log(text)
                    yield text
                if self.still or self.deferred:
                    text = self.display(write=bool(self.still and self.write_still))
                    log(text)
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
        global _active
        if self.closed:
            return
        self.closed = True
        try:
            self.restore()
        finally:
            if self.denoiser is not None:
                self.denoiser.close()
            self._remove_output()
            for path in self.placeholders:  # frames that never came: as Blender does
                with contextlib.suppress(OSError):
                    if path.stat().st_size == 0:
                        path.unlink()
            shutil.rmtree(self.folder, ignore_errors=True)
            seconds = time.perf_counter() - self.began
            if self.error is not None:
                log(f"stopped after {len(self.delivered)} delivered frame(s): {self.error}")
            else:
                how = "cancelled" if self.cancelled else "done"
                log(f"{how}: {len(self.delivered)} frame(s) delivered in {seconds:.1f} s")
            if self.filter is not None:
                self.filter.stop()
            if _active is self:
                _active = None

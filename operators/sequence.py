"""Pass rendering and post-processing operators.

``sss.render_passes`` and ``sss.render_sequence`` work frame by frame through
a step generator: ``execute()`` runs it to the end (background mode and
scripts); ``invoke()`` in the UI starts a modal timer that advances one frame
per tick with progress, and ESC closes the generator, which restores the
scene and keeps the finished frames.
"""

import traceback

import bpy
from bpy.types import Operator

from ..core.backends.select import describe as describe_backend
from ..core.io.errors import CheckpointError, OutputError, PassError
from ..core.params import ParameterError
from ..sss_addon import precompile
from ..sss_addon.blender import render
from ..sss_addon.blender.errors import RenderError

#: Problems the user can fix: reported without a traceback.
USER_ERRORS = (
    RenderError,
    ParameterError,
    PassError,
    OutputError,
    FileExistsError,
    CheckpointError,
)


def _message(exc: BaseException) -> str:
    if isinstance(exc, USER_ERRORS):
        return str(exc)
    traceback.print_exc()
    return f"{type(exc).__name__}: {exc}"


def status(context, text: str | None) -> None:
    """Show ``text`` in the status bar (None clears it)."""
    workspace = getattr(context, "workspace", None)
    if workspace is not None:
        workspace.status_text_set(text)


class _SteppedOperator:
    """Mixin: run ``self.steps(context)`` (job, generator) to the end or modally."""

    bl_options = {"REGISTER"}  # noqa: RUF012
    verb = "Processed"
    #: The job runs the Monte Carlo step: the summary says which backend sampled.
    samples = False

    def steps(self, context):
        raise NotImplementedError

    def _summary(self, job, done: int) -> str:
        text = f"{self.verb} {done}/{len(job.frames)} frame(s) into {job.out}"
        if self.samples:  # numba is missing where its wheel is: say what ran
            text += f"; sampling on {describe_backend(job.params.backend)}"
        return text

    def execute(self, context):
        try:
            job, steps = self.steps(context)
            done = 0
            for _ in steps:
                done += 1
        except Exception as exc:
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        self.report({"INFO"}, self._summary(job, done))
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        return self.start_modal(context)

    def start_modal(self, context):
        """Start the job and a timer; ``modal`` then advances one frame per tick."""
        try:
            self._job, self._steps = self.steps(context)
        except Exception as exc:
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        self._done = 0
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, len(self._job.frames))
        text = f"cvsss: starting {len(self._job.frames)} frame(s)"
        if self.samples and not precompile.compiled_ready(
            self._job.params.backend, self._job.methods
        ):
            text += " (the first also prepares the numba passes: a minute on first use)"
        self._status(context, text + ", ESC to cancel")
        return {"RUNNING_MODAL"}

    def _status(self, context, text):
        status(context, text)

    def _stop(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        self._status(context, None)

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._steps.close()  # restores the scene; finished frames stay on disk
            self._stop(context)
            self.report({"WARNING"}, "Cancelled: " + self._summary(self._job, self._done))
            return {"CANCELLED"}
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"PASS_THROUGH"}
        try:
            step = next(self._steps)
        except StopIteration:
            self._stop(context)
            self.report({"INFO"}, self._summary(self._job, self._done))
            return {"FINISHED"}
        except Exception as exc:
            self._stop(context)
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        self._done = step.index
        context.window_manager.progress_update(step.index)
        self._status(
            context, f"cvsss: frame {step.frame} ({step.index}/{step.total}), ESC to cancel"
        )
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        return {"RUNNING_MODAL"}


class SSS_OT_render_passes(_SteppedOperator, Operator):
    """Render the frame range's passes to multilayer EXR with subsurface disabled"""

    bl_idname = "sss.render_passes"
    bl_label = "Render Passes"
    verb = "Rendered passes of"

    def steps(self, context):
        job = render.job_from_scene(context.scene, context=context, reference=False)
        return job, render.iter_passes(job)


class SSS_OT_render_sequence(_SteppedOperator, Operator):
    """Render passes and post-process the whole frame range (ESC cancels, keeping finished frames)"""

    bl_idname = "sss.render_sequence"
    bl_label = "Render Sequence"
    samples = True

    def steps(self, context):
        job = render.job_from_scene(context.scene, context=context, images=True, log=print)
        return job, render.iter_sequence(job)


class SSS_OT_apply_frame(Operator):
    """Post-process the current frame (rendering its passes when missing) and show the maps as images"""

    bl_idname = "sss.apply_frame"
    bl_label = "Apply to Frame"
    bl_options = {"REGISTER"}  # noqa: RUF012

    def execute(self, context):
        scene = context.scene
        frame = scene.frame_current
        try:
            job = render.job_from_scene(scene, frames=(frame, frame), context=context, images=True)
            step = render.apply_frame(job)
        except Exception as exc:
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        result = step.results[job.display]
        self.report(
            {"INFO"},
            f"Frame {frame} ({job.display}): mean spp {result.spp:.2f}, "
            f"pass {result.sampling_ms:.1f} ms",
        )
        return {"FINISHED"}


classes = (SSS_OT_render_passes, SSS_OT_apply_frame, SSS_OT_render_sequence)
register, unregister = bpy.utils.register_classes_factory(classes)

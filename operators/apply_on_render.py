"""``sss.finish_render``: the UI's end of Apply on Render (sss_addon/blender/apply_on_render/).

Blender calls the render handlers on its render thread when the UI renders
(F12, Ctrl-F12), so the warm-up, the post-process and the writing of the
finished frames wait for the render job to end; a timer then starts this
operator, which does them one frame per timer tick on the main thread with
progress in the status bar. Esc stops it: the scene is restored and the
frames written so far stay.
"""

import bpy
from bpy.types import Operator

from ..sss_addon.blender.apply_on_render.session import active_session
from .sequence import _message, status


class SSS_OT_finish_render(Operator):
    """Finish an Apply on Render render: warm up, post-process and write the frames (Esc stops)"""

    bl_idname = "sss.finish_render"
    bl_label = "Finish Render (cvsss)"
    bl_options = {"INTERNAL"}  # noqa: RUF012

    @classmethod
    def poll(cls, context):
        return active_session() is not None

    def execute(self, context):
        session = active_session()
        try:
            for _ in session.finish_steps():
                pass
        except Exception as exc:
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        return self._ended(session)

    def _ended(self, session):
        """An error met while Blender rendered (a frame it could not stop at) is reported."""
        if session.error is not None:
            self.report({"ERROR"}, f"cvsss: {session.error}")
            return {"CANCELLED"}
        self.report({"INFO"}, "cvsss: render finished")
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        self._session = active_session()
        self._steps = self._session.finish_steps()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.modal_handler_add(self)
        self._status(context, "cvsss: finishing the render, Esc to stop")
        return {"RUNNING_MODAL"}

    def _status(self, context, text):
        status(context, text)

    def _stop(self, context):
        context.window_manager.event_timer_remove(self._timer)
        self._status(context, None)
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self._steps.close()  # restores the scene; frames written so far stay
            self._stop(context)
            self.report({"WARNING"}, "cvsss: stopped; the scene is restored")
            return {"CANCELLED"}
        if event.type != "TIMER" or event.timer is not self._timer:
            return {"PASS_THROUGH"}
        try:
            text = next(self._steps)
        except StopIteration:
            self._stop(context)
            return self._ended(self._session)
        except Exception as exc:
            self._stop(context)
            self.report({"ERROR"}, _message(exc))
            return {"CANCELLED"}
        self._status(context, f"cvsss: {text}, Esc to stop")
        for area in context.screen.areas if context.screen else ():
            area.tag_redraw()
        return {"RUNNING_MODAL"}


classes = (SSS_OT_finish_render,)
register, unregister = bpy.utils.register_classes_factory(classes)

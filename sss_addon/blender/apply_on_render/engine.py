"""The render engine through which Apply on Render hands finished frames to Blender.

:class:`ResultEngine` renders whatever it was handed last: inside
:func:`rendering`, a function frame -> finished RGBA pixels; otherwise the
message of :func:`refuse`, with which it stops the render (a render the
handlers refused at ``render_init`` runs on this engine, so Blender cancels
it before it writes anything).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator

import bpy
import numpy as np

from ..internal_renders import internal_render

#: Identifier of :class:`ResultEngine`.
ENGINE = "CVSSS_RESULT"

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
def rendering(task: Callable[[int], np.ndarray | None]) -> Iterator[None]:
    """:class:`ResultEngine` renders ``task`` inside the block (an internal render).

    ``task(frame)`` returns the finished (H, W, 4) float32 RGBA of ``frame``, linear,
    top row first, or None when there is none.
    """
    global _task
    before = _task
    _task = task
    try:
        with internal_render():
            yield
    finally:
        _task = before


def refuse(message: str | None) -> None:
    """Outside :func:`rendering`, :class:`ResultEngine` stops its renders with ``message``
    (None: the message that says it is Apply on Render's engine)."""
    global _task
    _task = message


classes = (ResultEngine,)
register, unregister = bpy.utils.register_classes_factory(classes)

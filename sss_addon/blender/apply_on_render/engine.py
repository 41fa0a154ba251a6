"""The render engine through which Apply on Render hands finished frames to Blender.

:class:`ResultEngine` renders whatever it was handed last: inside
:func:`rendering`, a function frame -> finished frame (RGBA pixels, or a
:class:`.frame_passes.Delivery` with the view layer's passes); otherwise the
message of :func:`refuse`, with which it stops the render (a render the
handlers refused at ``render_init`` runs on this engine, so Blender cancels
it before it writes anything).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator, Sequence

import bpy
import numpy as np

from ..internal_renders import internal_render
from .frame_passes import Delivery, PassSpec

#: Identifier of :class:`ResultEngine`.
ENGINE = "CVSSS_RESULT"

#: What a task gives for a frame: its RGBA, its passes, or None (no finished frame).
Finished = np.ndarray | Delivery | None

#: What :class:`ResultEngine` renders: a function frame -> :data:`Finished`,
#: or a message (the render is stopped with it).
_task: Callable[[int], Finished] | str | None = None

#: The passes :class:`ResultEngine` declares besides Combined (see :func:`rendering`).
_passes: tuple[PassSpec, ...] = ()


class ResultEngine(bpy.types.RenderEngine):
    """Renders finished frames (or stops a render with a message) for Apply on Render.

    Blender then does what it does with any render result: runs the scene's
    compositor on it (``bl_use_postprocess``: its Render Layers nodes read
    the passes declared here), shows it as the Render Result and writes it
    with the scene's output settings (a multilayer EXR holds every pass). It
    is registered for as long as the add-on (the render thread of a UI render
    cannot register classes), so it shows in the engine menu; chosen there,
    it says so.
    """

    bl_idname = ENGINE
    bl_label = "cvsss (internal: Apply on Render)"
    bl_use_postprocess = True
    bl_use_preview = False

    def update_render_passes(self, scene=None, renderlayer=None):
        # Blender asks when a render starts and when a Render Layers node updates its
        # sockets: a pass not declared then leaves the node's socket unavailable, and
        # the compositor drops the links from it.
        self.register_pass(scene, renderlayer, "Combined", 4, "RGBA", "COLOR")
        for spec in _passes:
            if spec.name != "Combined":
                self.register_pass(
                    scene, renderlayer, spec.name, len(spec.channels), spec.channels, spec.kind
                )

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
        finished = task(int(scene.frame_current))
        if finished is None:
            self.report({"ERROR"}, f"cvsss: no finished frame {scene.frame_current}")
            return
        if not isinstance(finished, Delivery):
            finished = Delivery({"Combined": finished})
        height, width = finished.passes["Combined"].shape[:2]
        result = self.begin_result(0, 0, width, height, layer=depsgraph.view_layer.name)
        passes = result.layers[0].passes
        for name, pixels in finished.passes.items():
            target = passes.find_by_name(name, "")
            if target is not None:
                # Render results start at the bottom row; the core's images at the top.
                target.rect.foreach_set(
                    np.ascontiguousarray(pixels[::-1], dtype=np.float32).reshape(-1)
                )
        self.end_result(result)
        if finished.stamp:
            # On the render's own result: the one of begin_result is freed by end_result.
            main = self.get_result()
            for key, value in finished.stamp.items():
                main.stamp_data_add_field(key, value)


@contextlib.contextmanager
def rendering(task: Callable[[int], Finished], passes: Sequence[PassSpec] = ()) -> Iterator[None]:
    """:class:`ResultEngine` renders ``task`` inside the block (an internal render).

    ``task(frame)`` returns the finished frame of ``frame``: (H, W, 4) float32
    RGBA, linear, top row first; or a :class:`.frame_passes.Delivery` whose
    passes are those of ``passes`` (Combined always declared); or None when
    there is none.
    """
    global _task, _passes
    before = _task, _passes
    _task, _passes = task, tuple(passes)
    try:
        with internal_render():
            yield
    finally:
        _task, _passes = before


def refuse(message: str | None) -> None:
    """Outside :func:`rendering`, :class:`ResultEngine` stops its renders with ``message``
    (None: the message that says it is Apply on Render's engine)."""
    global _task
    _task = message


classes = (ResultEngine,)
register, unregister = bpy.utils.register_classes_factory(classes)

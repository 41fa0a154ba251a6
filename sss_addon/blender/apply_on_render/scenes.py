"""The scenes Apply on Render renders with, and what it tells about the user's scene.

The *output scene* (:func:`output_scene`) keeps the user's output settings
for :class:`.engine.ResultEngine` to write finished frames with Blender's own
writer; :class:`DisplaySetup` turns the user's scene itself into one that
shows a finished frame; :func:`scene_copy` makes the linked copies both the
output scene and the warm-up renders use. :func:`pass_engine` says which
engine renders the passes.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

from ..errors import RenderError
from ..passes import SceneSetup
from .compositor import retarget
from .engine import ENGINE

#: Engines whose renders Apply on Render turns into pass renders (Blender id -> cvsss name).
PASS_ENGINES = {
    "CYCLES": "CYCLES",
    "BLENDER_EEVEE": "EEVEE",
    "BLENDER_EEVEE_NEXT": "EEVEE",
}


def pass_engine(scene) -> str:
    """``CYCLES`` or ``EEVEE`` for the scene's render engine; RenderError for any other."""
    engine = scene.render.engine
    if engine not in PASS_ENGINES:
        raise RenderError(
            f"Apply on Render needs Cycles or EEVEE as the render engine, the scene uses {engine}"
        )
    return PASS_ENGINES[engine]


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


def output_scene(scene, layer_name: str, compositor: bool = False, made: list | None = None):
    """A linked copy of ``scene`` with its output settings and only its camera, for
    :class:`.engine.ResultEngine` to write finished frames with Blender's own writer.

    With ``compositor`` it runs a copy of the scene's compositor whose Render
    Layers nodes read it (:func:`.compositor.retarget`; the copies are appended
    to ``made``); otherwise none.
    """
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
    r.use_compositing = bool(compositor)
    if compositor:
        out.compositing_node_group = retarget(
            scene.compositing_node_group, scene, out, made if made is not None else []
        )
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
    """The user's scene rendering with :class:`.engine.ResultEngine` (the Render Result, a
    still's file), only the processed view layer, whole frame, its compositor as the
    user has it (its Render Layers nodes read this render), the sequencer bypassed;
    restored on exit."""

    def _apply(self) -> None:
        r = self.scene.render
        r.engine = ENGINE
        r.use_border = False
        r.use_sequencer = False
        for layer in self.scene.view_layers:
            layer.use = layer == self.view_layer


def camera_animated(scene, materials) -> bool:
    """Whether the sidecar of a frame needs the scene evaluated at that frame."""
    cam = scene.camera
    ids = [cam.data] if cam is not None else []
    ids += [m.node_tree for m in materials if m.node_tree is not None]
    if any(m.camera is not None for m in scene.timeline_markers):
        return True
    return any(i.animation_data is not None for i in ids)

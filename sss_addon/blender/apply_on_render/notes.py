"""What Apply on Render will do differently from the user's own render, said before it starts.

The panel lists :func:`scene_notes` under *Apply on Render*; a render logs
:func:`bypassed` and :func:`model_notes` as it begins. Each note is a limit the user can see
coming: a part of the render that Blender's API leaves out (the sequencer,
other view layers), or a pass that differs from a plain render's because the
pass render has Subsurface Weight 0; or where the post's model is known to
part from Cycles (:func:`model_notes`). Everything here reads settings only (the
panel draws it, and drawing may not create datablocks).
"""

from __future__ import annotations

import bpy

from .. import materials as sss_materials
from ..errors import RenderError
from ..passes import render_view_layer
from .compositor import render_layer_names
from .scenes import PASS_ENGINES, pass_engine
from .user_render import compositing, material_index_exact, multilayer

#: View layer pass switches whose passes the pass render makes without subsurface.
_DIFFUSE = ("use_pass_diffuse_direct", "use_pass_diffuse_indirect", "use_pass_diffuse_color")


def _used_layers(scene) -> list:
    return [layer for layer in scene.view_layers if layer.use]


def bypassed(scene) -> list[str]:
    """What of the user's render the finished frames leave out or change."""
    notes = []
    editor = scene.sequence_editor
    strips = getattr(editor, "strips_all", None) or getattr(editor, "sequences_all", None)
    if scene.render.use_sequencer and editor is not None and strips:
        notes.append("the sequencer's strips are bypassed")
    used = _used_layers(scene)
    layer = render_view_layer(scene)
    if len(used) > 1:
        notes.append(f"only view layer {layer.name!r} is rendered (of {len(used)})")
    if scene.render.use_motion_blur:
        notes.append("motion blur is off (the post-process needs the Vector pass)")
    if compositing(scene):
        others = sorted(render_layer_names(scene.compositing_node_group, scene) - {layer.name})
        if others:
            names = ", ".join(map(repr, others))
            notes.append(f"the compositor's Render Layers of {names} get no image")
    if compositing(scene) or multilayer(scene):
        notes += _pass_notes(scene, layer)
    cycles = getattr(scene, "cycles", None)
    if scene.render.engine == "CYCLES" and cycles is not None and cycles.use_denoising:
        if cycles.denoiser == "OPTIX":
            notes.append("the finished frame is denoised with OpenImageDenoise (not OptiX)")
    eevee = PASS_ENGINES.get(scene.render.engine) == "EEVEE"
    if eevee and scene.sss_settings.use_denoise_subsurface:
        notes.append(
            "the subsurface pixels are denoised with OpenImageDenoise (Denoise Subsurface)"
        )
    return notes


def _pass_notes(scene, layer) -> list[str]:
    """How the passes a compositor or a multilayer file gets differ from a plain render's."""
    notes = []
    if any(getattr(layer, flag, False) for flag in _DIFFUSE):
        notes.append("the Diffuse passes hold no subsurface light (only Combined does)")
    if len(getattr(layer, "lightgroups", ())):
        notes.append("light group passes are without the subsurface post-process")
    if getattr(layer, "use_pass_material_index", False) and not material_index_exact(
        sss_materials.participating(scene, layer)
    ):
        notes.append(
            "Material Index: the materials without subsurface all get one number (the "
            "pass render numbers materials for the post-process)"
        )
    return notes


#: Parts thinner than this many mean free paths of their Random Walk material are
#: noted: Cycles' walk loses light through their far side (a free slab of the demo's
#: marble returns 0.87 of a deep slab's red light at 4 mean free paths, 0.97 at 8;
#: docs/explanation/accuracy.md §2.3), which the post, seeing the near side only, keeps.
THIN_MEAN_FREE_PATHS = 4.0


def model_notes(scene) -> list[str]:
    """Where the post's model is known to part from Cycles on this scene: objects thin
    for their Random Walk material (smallest dimension under
    :data:`THIN_MEAN_FREE_PATHS` mean free paths). Reads the materials' settings and the
    objects' material slots and sizes only; no object is read without a walk."""
    walks = {}
    for material in bpy.data.materials:
        if sss_materials.participates(material):
            path = sss_materials.walk_mean_free_path(material)
            if path:
                walks[material.name] = path
    if not walks:
        return []
    thin = []
    for obj in scene.objects:
        if obj.type != "MESH" or obj.hide_render:
            continue
        slots = [s.material.name for s in obj.material_slots if s.material is not None]
        longest = max((walks.get(name, 0.0) for name in slots), default=0.0)
        if longest > 0 and min(obj.dimensions) < THIN_MEAN_FREE_PATHS * longest:
            thin.append(obj.name)
    if not thin:
        return []
    names = ", ".join(map(repr, thin[:3])) + (f" and {len(thin) - 3} more" if len(thin) > 3 else "")
    return [
        f"{names} {'is' if len(thin) == 1 else 'are'} thin for Random Walk (under "
        f"{THIN_MEAN_FREE_PATHS:g} mean free paths): Cycles loses light through the far "
        "side, the post keeps it (brighter than Cycles)"
    ]


def scene_notes(scene) -> list[str]:
    """Short notes for the panel: what Apply on Render will do differently with this scene."""
    notes = []
    try:
        pass_engine(scene)
    except RenderError:
        notes.append("Needs Cycles or EEVEE as the render engine")
    if scene.render.is_movie_format:
        notes.append("Movie: frames are encoded after the last one")
    return notes + [note[0].upper() + note[1:] for note in bypassed(scene) + model_notes(scene)]

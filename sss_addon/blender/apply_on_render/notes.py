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

from .. import materials as sss_materials
from .. import thin_parts
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


#: Apply on Render with no material taking part: the add-on steps aside.
NOTHING_TO_DO = (
    "no material takes part in subsurface scattering (a Principled BSDF with Subsurface "
    "Weight > 0): Blender renders the frame as without the add-on"
)


def model_notes(scene) -> list[str]:
    """Where the post's model is known to part from Cycles on this scene, and what
    Apply on Render does about it: objects thin for their Random Walk material
    (:mod:`.thin_parts`); no material taking part (:data:`NOTHING_TO_DO`), read from
    the slots of the objects and of the collections they instance."""
    if not any(map(sss_materials.participates, sss_materials.slot_materials(scene))):
        return [NOTHING_TO_DO]
    return thin_parts.note(scene, PASS_ENGINES.get(scene.render.engine))


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

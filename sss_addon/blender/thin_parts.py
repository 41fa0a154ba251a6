"""Thin parts: found, and by default left to Cycles.

Cycles' random walk loses light through the far side of a part only a few mean
free paths thick, how much depending on what lies beyond (measured on slabs in
docs/explanation/accuracy.md §2.3). The post sees the near side's irradiance
only and keeps that light, so such a part comes out brighter than Cycles
renders it, and over a large flat part, where the blur changes little, that
error outweighs what the post adds.

Thin, for an object, reaches well beyond "a few": on every part under 50 mean free
paths across that was measured, Cycles' walk with its denoiser came out as close to
the ground truth as the post or closer (:data:`THIN_OBJECT_MEAN_FREE_PATHS`). A
Christensen-Burley part 8 to 50 d across, or under 8 d every way, goes to Cycles
whole as well (:data:`BURLEY_OBJECT_D`): the light of its hidden faces reaches
through it to the face the camera sees, where Cycles' disk probes find it and the
post does not.

With *Thin Parts* on Cycles (the default; ``cvsss render
--thin-walks``), the pass render gives each such object (:func:`thin_objects`) its
own copy of those materials, taking no part (``sss_material.mode`` OFF), so Cycles renders
their subsurface as in the user's own render and the post leaves their pixels
as rendered; a denoised finished frame treats them as the user's denoiser
would. :class:`CyclesRendersThin` (entered by :class:`.passes.PassSetup`) makes
the copies, and puts the objects' slots back and removes the copies
afterwards, also on error.

Thin features of thick objects (an ear, a fin, the rim along an edge) are found
per shading point instead: :func:`thin_point_nodes` gives the material's weight
back where Ambient Occlusion nodes looking inside meet the part's own surface
within five mean free paths (a thin feature) or within a shorter bound, which grows with the
object's thickness (the rim along an edge, where the walk leaves through the other
face), for Christensen-Burley materials too (:func:`thin_length`: Cycles' disk
probes reach such surface as well), and the pass reader
(:func:`core.io.exr.read_frame`) takes the pixels made mostly of such points out
of the post. Apply on Render,
``cvsss render`` and the farm's pass chunks all follow the setting. When every
subsurface object is thin (:func:`cycles_renders_all`), Apply on Render starts no
session and Blender renders the frame itself.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import bpy

from ...core.io.exr import THIN_POINT_AOV
from . import materials as sss_materials
from .whole_parts import BURLEY_OBJECT_D, THIN_OBJECT_MEAN_FREE_PATHS, burley_sizes_text

#: A point is thin when its far side lies within this many mean free paths of its Random
#: Walk material (the thin-feature node of :func:`thin_point_nodes`: an ear, a fin): below
#: it a free slab still loses a tenth of its light, which the post would keep
#: (docs/explanation/accuracy.md §2.3).
THIN_MEAN_FREE_PATHS = 5.0


def _whole_object_lengths() -> tuple[dict[str, float], dict[str, float]]:
    """({material: longest mean free path} of the participating Random Walk materials the
    post models, {material: longest d} of the Christensen-Burley ones), scene units."""
    walks, burleys = {}, {}
    for material in bpy.data.materials:
        if not sss_materials.participates(material):
            continue
        path = sss_materials.walk_mean_free_path(material)
        if path:
            walks[material.name] = path
            continue
        model = sss_materials.own_model(material)
        d = sss_materials.principled_shape(material) if model and model[0] == "BURLEY" else None
        if d:
            burleys[material.name] = float(max(d))
    return walks, burleys


def _goes_whole(dimensions: Sequence[float], name: str, walks: dict, burleys: dict) -> bool:
    """Whether an object of these bounding-box ``dimensions`` (x, y, z, scene units)
    goes to Cycles whole for its material ``name`` (:func:`thin_objects`)."""
    smallest = min(dimensions)
    if name in walks:
        return smallest < THIN_OBJECT_MEAN_FREE_PATHS * walks[name]
    if name not in burleys:
        return False
    low, high = BURLEY_OBJECT_D
    d = burleys[name]
    return low * d <= smallest < high * d or max(dimensions) < low * d


def thin_objects(scene) -> list[tuple[object, list]]:
    """The scene's objects Cycles renders whole, each with those of its materials that
    make it so: [(object, [material, ...])], in the scene's order.

    An object goes whole when its smallest dimension (its bounding box, scene units) is
    under :data:`THIN_OBJECT_MEAN_FREE_PATHS` times a Random Walk material's longest
    mean free path (thin), or within :data:`BURLEY_OBJECT_D` times a Christensen-Burley
    material's longest d, or when its largest dimension is under the lower end of
    :data:`BURLEY_OBJECT_D` times that d (a part small every way). Materials the post
    models otherwise (a measured preset, an override) never send an object whole.
    Reads settings, slots and sizes only (the panel calls it on every redraw); objects
    are read only when some participating material has such a length.
    """
    walks, burleys = _whole_object_lengths()
    if not walks and not burleys:
        return []
    found = []
    for obj in scene.objects:
        if obj.type != "MESH" or obj.hide_render:
            continue
        thin = [
            slot.material
            for slot in obj.material_slots
            if slot.material is not None
            and _goes_whole(obj.dimensions, slot.material.name, walks, burleys)
        ]
        if thin:
            found.append((obj, list(dict.fromkeys(thin))))
    return found


#: Rays of the Ambient Occlusion node that tells a thin point: few, since a pixel
#: averages many shading points (its samples), and each costs a ray.
THIN_POINT_RAYS = 4
#: A point is thin when fewer than this share of those rays leave the part unhit within
#: THIN_MEAN_FREE_PATHS mean free paths (a pixel is left to Cycles when at least
#: core.io.exr.THIN_PIXEL_SHARE of its samples were thin points).
THIN_POINT_SHARE = 0.5
#: A point is on the rim of an edge when at least half of another node's rays (fewer
#: than this share unhit) meet the part's own surface within a bound: at a right-angled
#: edge half of them head for the other face, and the longer the bound the wider the band
#: along the edge that has them meet it. THIN_EDGE_MEAN_FREE_PATHS is the bound's least;
#: for a thick part it is THIN_EDGE_MAX_MEAN_FREE_PATHS, for a thinner one
#: THIN_EDGE_THICKNESS_SHARE of the part's thickness (its smallest dimension): beyond
#: about two-thirds of it most points of a slab have half their rays meet its far side,
#: so the whole part would be rim. The rims of the demo's marble block (20 mean free paths
#: across, its hidden top lit) came out closer to the ground truth from Cycles the wider
#: they were, while the candles' wax (about six across) came out further once more of it
#: went to Cycles. A part thicker than THIN_EDGE_FALL_MEAN_FREE_PATHS[0] scattering
#: lengths (fall_scale: a Christensen-Burley material's are its d) has the bound fall back
#: to the least by THIN_EDGE_FALL_MEAN_FREE_PATHS[1]: through a thinner part the light of
#: its hidden faces crosses the whole part, through a thicker one it arrives only round
#: the edge, where the least bound's band takes it, and a wider band there only trades
#: the post's smooth pixels for Cycles' noisier walk. Blender's default cube (500 across)
#: lost 1.2 dB to the wider band; the same cube made more translucent came out closer
#: with the wide band up to about 22 across and with the least from 25 (docs/explanation/
#: accuracy.md §2.3). Since a Random Walk object under THIN_OBJECT_MEAN_FREE_PATHS goes to
#: Cycles whole, a Random Walk rim always has the least bound; the wider ones serve
#: Christensen-Burley parts under BURLEY_OBJECT_D[0] (the candles, the marble tops), and parts
#: the whole-object rules do not reach (objects of a linked library or an instanced
#: collection).
THIN_EDGE_MEAN_FREE_PATHS = 2.0
THIN_EDGE_MAX_MEAN_FREE_PATHS = 8.0
THIN_EDGE_THICKNESS_SHARE = 0.4
THIN_EDGE_FALL_MEAN_FREE_PATHS = (22.0, 25.0)
THIN_EDGE_SHARE = 0.75
#: The object property (scene units) through which the rim's nodes read each object's
#: thickness: set by :class:`Thickness` for the pass render only.
THICKNESS_PROPERTY = "cvsss_thickness"


#: The length the thin-point rules count in for a Christensen-Burley material, per unit
#: of its longest channel's d (the shape the post samples): Cycles' disk probes reach the
#: faces round an edge as a walk does, over a length that scales with d. 0.4 came out
#: closest to the ground truth on the demo scenes of the three tried (0.25, 0.4, 0.6).
#: Such a material gets the rim's node only: the thin-feature node's four more rays a
#: shading point cost more than the issue's bound on Apply on Render's time allows, for
#: little (docs/explanation/accuracy.md §2.3).
BURLEY_THIN_LENGTH = 0.4


def thin_length(material) -> float | None:
    """The length (scene units) in which :func:`thin_point_nodes` counts its bounds for
    ``material``: a Random Walk's longest mean free path, or :data:`BURLEY_THIN_LENGTH`
    times a Christensen-Burley's longest d; None for what the post models otherwise (a
    measured preset, an override)."""
    ell = sss_materials.walk_mean_free_path(material)
    if ell is not None:
        return ell
    model = sss_materials.own_model(material)
    if model is None or model[0] != "BURLEY":
        return None
    d = sss_materials.principled_shape(material)
    return BURLEY_THIN_LENGTH * float(max(d)) if d else None


def has_thin_points(materials) -> bool:
    """Whether :func:`thin_point_nodes` applies to any of ``materials``."""
    return any(thin_length(m) for m in materials)


def record(objects: list[str], points: bool) -> dict:
    """The pass sidecar's ``thin_parts``: the objects Cycles rendered, and whether it
    rendered thin points too (with the rule's bound)."""
    return {
        "objects": sorted(objects),
        "points": bool(points),
        "object_mean_free_paths": THIN_OBJECT_MEAN_FREE_PATHS,
        "mean_free_paths": THIN_MEAN_FREE_PATHS,
        "edge_mean_free_paths": THIN_EDGE_MEAN_FREE_PATHS,
        "edge_max_mean_free_paths": THIN_EDGE_MAX_MEAN_FREE_PATHS,
        "edge_thickness_share": THIN_EDGE_THICKNESS_SHARE,
        "edge_fall_mean_free_paths": list(THIN_EDGE_FALL_MEAN_FREE_PATHS),
        "burley_length": BURLEY_THIN_LENGTH,
        "burley_object_d": list(BURLEY_OBJECT_D),
    }


def cycles_renders(who: str, engine: str | None) -> bool:
    """Whether the pass render leaves thin parts to Cycles: ``who`` (the
    setting, "CYCLES" or "POST") asks it and the passes are Cycles'."""
    return engine == "CYCLES" and who == "CYCLES"


def cycles_renders_all(
    scene, engine: str | None, who: str | None = None, materials=None, thin=None
) -> bool:
    """Whether Cycles renders every part that takes part in subsurface (``who`` as in
    :func:`note`): every participating material sits, in every object's slots, only on
    objects thin for it. The post would then change no pixel, and Apply on Render lets
    Blender render the frame as without the add-on. ``materials``: the participating
    ones (:func:`.materials.participating`, which also sees instanced ones); by default
    those in the scene's objects' slots, which is all the panel reads on a redraw.
    ``thin``: :func:`thin_objects`' answer, when the caller has it.
    Conservative: an object hidden from the render, a non-mesh object or a material
    seen only through instancing (not in a slot of the scene's objects) carrying one of
    them answers False."""
    who = who or scene.sss_settings.thin_walks
    if not cycles_renders(who, engine):
        return False
    thin_names = {
        obj.name: {m.name for m in mats}
        for obj, mats in (thin_objects(scene) if thin is None else thin)
    }
    carried = set()
    for obj in scene.objects:
        for slot in getattr(obj, "material_slots", ()):
            material = slot.material
            if material is None or not sss_materials.participates(material):
                continue
            if material.name not in thin_names.get(obj.name, ()):
                return False
            carried.add(material.name)
    wanted = carried if materials is None else {m.name for m in materials}
    return bool(carried) and carried >= wanted


def _why(walks: bool, burleys: bool) -> str:
    """Why objects go to Cycles whole: for Random Walk (``walks``), Christensen-Burley
    (``burleys``) or both."""
    walk = f"under {THIN_OBJECT_MEAN_FREE_PATHS:g} mean free paths across"
    burley = burley_sizes_text()
    if walks and burleys:
        return f"left to Cycles whole (Random Walk {walk}, Christensen-Burley {burley})"
    if burleys:
        return f"{burley} for Christensen-Burley"
    return f"thin for Random Walk ({walk})"


def all_thin_note(apply_on_render: bool = True, walks: bool = True, burleys: bool = False) -> str:
    """The note when :func:`cycles_renders_all`: Apply on Render steps aside; ``cvsss
    render`` (``apply_on_render`` False) still renders the passes. ``walks``,
    ``burleys``: which rule sent the objects whole (:func:`thin_objects`)."""
    return f"every subsurface object is {_why(walks, burleys)}: " + (
        "Cycles renders the frame as without the add-on"
        if apply_on_render
        else "Cycles renders all of their subsurface, the post changes no pixel"
    )


def kinds(found) -> tuple[list[str], list[str]]:
    """The names of :func:`thin_objects`' objects sent whole for a Random Walk material,
    and of the others (for a Christensen-Burley one)."""
    walks = [
        obj.name for obj, mats in found if any(sss_materials.walk_mean_free_path(m) for m in mats)
    ]
    return walks, [obj.name for obj, _ in found if obj.name not in walks]


def _named(names: list[str]) -> str:
    more = f" and {len(names) - 3} more" if len(names) > 3 else ""
    return ", ".join(map(repr, names[:3])) + more


def note(
    scene, engine: str | None, who: str | None = None, apply_on_render: bool = True
) -> list[str]:
    """The panel's and the log's notes on objects Cycles renders whole (none without
    them); ``who`` defaults to the scene's setting. ``apply_on_render`` False: for
    ``cvsss render``, which renders the passes even when every part goes whole."""
    who = who or scene.sss_settings.thin_walks
    found = thin_objects(scene)
    walks, burleys = kinds(found)
    cycles = cycles_renders(who, engine)
    if not cycles:
        burleys = []  # the post renders them as any other part, and nothing is left out
    if not walks and not burleys:
        return []
    if cycles_renders_all(scene, engine, who, thin=found):
        return [all_thin_note(apply_on_render, bool(walks), bool(burleys))]
    notes = []
    for names, why in ((walks, _why(True, False)), (burleys, _why(False, True))):
        if not names:
            continue
        head = f"{_named(names)} {'is' if len(names) == 1 else 'are'} {why}"
        if cycles:
            notes.append(
                f"{head}: Cycles renders {'its' if len(names) == 1 else 'their'} subsurface"
            )
        else:
            notes.append(
                f"{head}: Cycles loses light through the far side, the post keeps it "
                "(brighter than Cycles)"
            )
    return notes


def thin_point_nodes(material, new: Callable[[object, str], object]) -> None:
    """Wire ``material``'s Principled BSDFs (held at Subsurface Weight 0 by
    :class:`.materials.SSSDisabled`) so Cycles keeps their subsurface at thin points.

    A point is thin when most inward rays of an Ambient Occlusion node (Inside,
    Only Local, :data:`THIN_POINT_RAYS` rays) meet the part's own surface within
    :data:`THIN_MEAN_FREE_PATHS` mean free paths (an ear, a fin), or at least half
    of a second node's meet it within the rim's bound (the rim along an edge):
    :data:`THIN_EDGE_THICKNESS_SHARE` of the object's thickness (the property
    :data:`THICKNESS_PROPERTY`, :class:`Thickness`), kept between
    :data:`THIN_EDGE_MEAN_FREE_PATHS` and :data:`THIN_EDGE_MAX_MEAN_FREE_PATHS` mean
    free paths and back to the least on a part many of them thick (:func:`rim_bound`;
    the least on an object without the property, a linked one): where
    Cycles' walk, or its disk probes, reach surface the camera may not see. Mean free
    paths are :func:`thin_length`'s. There
    the weight is the user's again (its value or its link); elsewhere it stays 0. The
    value AOV :data:`THIN_POINT_AOV` is 1 at thin points (read by :func:`core.io.exr.read_frame`).
    An animated (unlinked) weight keeps there the value it had when the pass render
    was set up: its animation stays muted, as for the points the post renders.
    ``new(tree, node type)`` makes a node the pass render removes afterwards. Random
    Walk and Christensen-Burley materials (:func:`thin_length`); a Christensen-Burley
    material gets the rim's node only (:data:`BURLEY_THIN_LENGTH`); a Principled BSDF
    shared through a node group is wired once.
    """
    ell = thin_length(material)
    if ell is None:
        return
    walk = sss_materials.walk_mean_free_path(material) is not None
    for tree, node in sss_materials.principled_nodes(material.node_tree):
        saved = sss_materials.disabled(node)
        if saved is None or saved.wired:
            continue
        saved.wired = True
        rules = [(THIN_EDGE_MEAN_FREE_PATHS, THIN_EDGE_SHARE, True)]  # (bound, share, rim)
        if walk:
            rules.append((THIN_MEAN_FREE_PATHS, THIN_POINT_SHARE, False))
        thin = None
        for paths, share, rim in rules:
            ao = new(tree, "ShaderNodeAmbientOcclusion")
            ao.inside = True
            ao.only_local = True
            ao.samples = THIN_POINT_RAYS
            ao.inputs["Distance"].default_value = paths * ell
            if rim:
                _rim_bound(tree, ao.inputs["Distance"], ell, fall_scale(material), new)
            hit = new(tree, "ShaderNodeMath")
            hit.operation = "LESS_THAN"
            tree.links.new(ao.outputs["AO"], hit.inputs[0])
            hit.inputs[1].default_value = share
            if thin is None:
                thin = hit
            else:
                either = new(tree, "ShaderNodeMath")
                either.operation = "MAXIMUM"
                tree.links.new(thin.outputs["Value"], either.inputs[0])
                tree.links.new(hit.outputs["Value"], either.inputs[1])
                thin = either
        weight = new(tree, "ShaderNodeMath")
        weight.operation = "MULTIPLY"
        tree.links.new(thin.outputs["Value"], weight.inputs[0])
        if saved.links:
            tree.links.new(saved.links[0], weight.inputs[1])
        else:
            weight.inputs[1].default_value = saved.value
        tree.links.new(weight.outputs["Value"], node.inputs[sss_materials.WEIGHT])
        out = new(tree, "ShaderNodeOutputAOV")
        out.aov_name = THIN_POINT_AOV
        tree.links.new(thin.outputs["Value"], out.inputs["Value"])


def rim_bound(thickness: float, ell: float, scale: float | None = None) -> float:
    """The rim's bound (scene units) for a part ``thickness`` thick (scene units) of a
    material whose bounds count in ``ell`` (:func:`thin_length`) and whose scattering
    length is ``scale`` (:func:`fall_scale`; default ``ell``):
    :data:`THIN_EDGE_THICKNESS_SHARE` of the thickness, at most
    :data:`THIN_EDGE_MAX_MEAN_FREE_PATHS` ``ell``, falling from there to the least
    (:data:`THIN_EDGE_MEAN_FREE_PATHS` ``ell``) as the thickness goes over
    :data:`THIN_EDGE_FALL_MEAN_FREE_PATHS` ``scale``, and never under the least. What
    the nodes of :func:`_rim_bound` compute per object."""
    slope, offset = _fall_line(ell, ell if scale is None else scale)
    most = min(
        THIN_EDGE_THICKNESS_SHARE * thickness,
        offset - slope * thickness,
        THIN_EDGE_MAX_MEAN_FREE_PATHS * ell,
    )
    return max(THIN_EDGE_MEAN_FREE_PATHS * ell, most)


def fall_scale(material) -> float | None:
    """The length (scene units) in which the rim bound's fall counts a part's thickness
    for ``material``: its scattering length, a Random Walk's longest mean free path or a
    Christensen-Burley's longest d (on the demo's marble the two are about equal); None
    where :func:`thin_length` is."""
    ell = thin_length(material)
    if ell is None or sss_materials.walk_mean_free_path(material) is not None:
        return ell
    return ell / BURLEY_THIN_LENGTH


def _fall_line(ell: float, scale: float) -> tuple[float, float]:
    """(slope, offset) of the falling line ``offset - slope * thickness`` (scene units):
    the most bound at the fall's start, the least at its end."""
    start, end = (paths * scale for paths in THIN_EDGE_FALL_MEAN_FREE_PATHS)
    slope = (THIN_EDGE_MAX_MEAN_FREE_PATHS - THIN_EDGE_MEAN_FREE_PATHS) * ell / (end - start)
    return slope, THIN_EDGE_MAX_MEAN_FREE_PATHS * ell + slope * start


def _rim_bound(
    tree, distance, ell: float, scale: float, new: Callable[[object, str], object]
) -> None:
    """Feed ``distance`` (an Ambient Occlusion node's input) :func:`rim_bound` of the
    object's thickness (its property :data:`THICKNESS_PROPERTY`; 0 without it, which
    gives the least) with ``ell`` and ``scale``."""
    attribute = new(tree, "ShaderNodeAttribute")
    attribute.attribute_type = "OBJECT"
    attribute.attribute_name = THICKNESS_PROPERTY
    thickness = attribute.outputs["Fac"]

    def math(operation: str, *inputs):
        node = new(tree, "ShaderNodeMath")
        node.operation = operation
        for socket, value in zip(node.inputs, inputs):
            if isinstance(value, int | float):
                socket.default_value = value
            else:
                tree.links.new(value, socket)
        return node.outputs["Value"]

    slope, offset = _fall_line(ell, scale)
    fall = math("MULTIPLY_ADD", thickness, -slope, offset)
    share = math("MULTIPLY", thickness, THIN_EDGE_THICKNESS_SHARE)
    bound = math("MINIMUM", math("MINIMUM", share, fall), THIN_EDGE_MAX_MEAN_FREE_PATHS * ell)
    tree.links.new(math("MAXIMUM", bound, THIN_EDGE_MEAN_FREE_PATHS * ell), distance)


class Thickness(contextlib.AbstractContextManager):
    """Give each editable mesh object carrying one of ``materials`` its thickness (its
    smallest dimension, scene units) as the property :data:`THICKNESS_PROPERTY`, which
    :func:`thin_point_nodes` reads; :meth:`restore` puts back what was there (nothing,
    usually), also on error."""

    _NONE = object()

    def __init__(self, materials) -> None:
        self.materials = set(materials)
        self._saved: dict[str, object] = {}

    def __enter__(self) -> Thickness:
        try:
            for obj in bpy.data.objects:
                if (
                    obj.type == "MESH"
                    and obj.is_editable
                    and sss_materials.carries(obj, self.materials)
                ):
                    value = obj.get(THICKNESS_PROPERTY, self._NONE)
                    if hasattr(value, "to_dict"):  # a group or an array: keep a copy
                        value = value.to_dict()
                    elif hasattr(value, "to_list"):
                        value = value.to_list()
                    self._saved[obj.name] = value
                    obj[THICKNESS_PROPERTY] = float(min(obj.dimensions))
        except BaseException:
            self.restore()
            raise
        return self

    def restore(self) -> None:
        """Put the objects' property back (safe to call more than once)."""
        for name, value in self._saved.items():
            obj = bpy.data.objects.get(name)
            if obj is None:
                continue
            if value is self._NONE:
                obj.pop(THICKNESS_PROPERTY, None)
            else:
                obj[THICKNESS_PROPERTY] = value
        self._saved = {}

    def __exit__(self, *exc) -> None:
        self.restore()


@dataclass
class _Slot:
    obj: str
    index: int
    link: str
    material: str | None  # the object's own material of the slot (None: none)


class CyclesRendersThin(contextlib.AbstractContextManager):
    """Give ``objects``' slots of their thin materials copies that take no part.

    Parameters
    ----------
    objects : list of (bpy.types.Object, list of bpy.types.Material)
        As :func:`thin_objects` returns; linked (read-only) objects are skipped.

    Each slot is linked to the object with the copy, the copy's node groups
    copied too (the pass render switches subsurface off inside the originals'
    groups). :meth:`restore` puts links and materials back and removes the copies.
    Names, not datablocks, are kept between the two: a save during a UI render
    restores and enters again (:meth:`.apply_on_render.session.Session.suspend`).
    In the UI, Apply on Render enters it on Blender's render thread, where it
    switches every other setting of the pass render, and restores it on the main
    thread when it finishes the frames.
    """

    def __init__(self, objects) -> None:
        self.objects = [(obj.name, [m.name for m in mats]) for obj, mats in objects]
        self._slots: list[_Slot] = []
        self._materials: list[str] = []
        self._groups: list[str] = []
        self.names: list[str] = []  # the objects whose subsurface Cycles renders

    def __enter__(self) -> CyclesRendersThin:
        try:
            copies = {}
            for name, thin in self.objects:
                obj = bpy.data.objects.get(name)
                if obj is None or not obj.is_editable:
                    continue
                for index, slot in enumerate(obj.material_slots):
                    material = slot.material
                    if material is None or material.name not in thin:
                        continue
                    if material.name not in copies:
                        copies[material.name] = self._copy(material)
                    own = material.name if slot.link == "OBJECT" else None
                    self._slots.append(_Slot(name, index, slot.link, own))
                    slot.link = "OBJECT"
                    slot.material = copies[material.name]
                if name not in self.names:
                    self.names.append(name)
        except BaseException:
            self.restore()
            raise
        return self

    def _copy(self, material):
        copy = material.copy()
        self._materials.append(copy.name)
        copy.sss_material.mode = "OFF"
        pending = [copy.node_tree]
        done: dict[str, object] = {}
        while pending:
            tree = pending.pop()
            for node in getattr(tree, "nodes", ()):
                group = node.node_tree if node.bl_idname == "ShaderNodeGroup" else None
                if group is None:
                    continue
                if group.name not in done:
                    done[group.name] = group.copy()
                    self._groups.append(done[group.name].name)
                    pending.append(done[group.name])
                node.node_tree = done[group.name]
        return copy

    @property
    def copies(self) -> list[str]:
        """The copies' names (while entered), each once."""
        return list(self._materials)

    def restore(self) -> None:
        """Slots back, copies removed (safe to call more than once)."""
        for saved in reversed(self._slots):
            obj = bpy.data.objects.get(saved.obj)
            if obj is None:
                continue
            slot = obj.material_slots[saved.index]
            # While linked to the object, assigning sets the object's own material.
            slot.material = bpy.data.materials.get(saved.material) if saved.material else None
            slot.link = saved.link
        self._slots = []
        for name in self._materials:
            material = bpy.data.materials.get(name)
            if material is not None:
                bpy.data.materials.remove(material)
        self._materials = []
        for name in self._groups:
            group = bpy.data.node_groups.get(name)
            if group is not None:
                bpy.data.node_groups.remove(group)
        self._groups = []

    def __exit__(self, *exc) -> None:
        self.restore()

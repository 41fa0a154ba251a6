"""Subsurface materials: which take part, their Burley shape, and switching SSS off.

A material takes part when its ``sss_material.mode`` is ON, or AUTO and one
of its Principled BSDFs (also inside node groups) has a Subsurface Weight > 0
or a linked weight. Its Burley shape per channel comes from that node,
``d_c = Subsurface Radius_c · Subsurface Scale · 0.25/π``
(:func:`core.profiles.burley.blender_shape`), unless overridden.

The node's subsurface method travels with it (``MaterialSpec.method``): for
Random Walk and Random Walk (Skin) the core replaces that d by the fitted
model's and scales the light by the walk's energy
(core.profiles.random_walk), from the Base Color, Radius, Scale, Subsurface
IOR and Subsurface Anisotropy written into the spec's options
(:func:`subsurface_model`). An override or a measured preset defines the
profile instead, and the model is not used.

For the pass render the weight is forced to 0 (links removed, animation
muted) so the Diffuse passes hold unblurred lighting; :class:`SSSDisabled`
puts every value, link and mute flag back, also on error.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field

import bpy

from ...core.frame import SUBSURFACE_METHODS, MaterialSpec
from ...core.profiles import presets, random_walk
from ...core.profiles.burley import blender_shape

WEIGHT = "Subsurface Weight"
RADIUS = "Subsurface Radius"
SCALE = "Subsurface Scale"
BASE_COLOR = "Base Color"
SUBSURFACE_IOR = "Subsurface IOR"
ANISOTROPY = "Subsurface Anisotropy"

#: What the material panel calls each subsurface method.
METHOD_LABELS = {
    "BURLEY": "Christensen-Burley",
    "RANDOM_WALK": "Random Walk",
    "RANDOM_WALK_SKIN": "Random Walk (Skin)",
}


def principled_nodes(node_tree, _seen: set | None = None) -> Iterator[tuple[object, object]]:
    """(node tree, node) of every Principled BSDF, descending into node groups once."""
    seen = set() if _seen is None else _seen
    if node_tree is None or node_tree.as_pointer() in seen:
        return
    seen.add(node_tree.as_pointer())
    for node in node_tree.nodes:
        if node.bl_idname == "ShaderNodeBsdfPrincipled":
            yield node_tree, node
        elif node.bl_idname == "ShaderNodeGroup" and node.node_tree is not None:
            yield from principled_nodes(node.node_tree, seen)


def live_links(socket) -> list:
    """The links into ``socket`` that Blender evaluates: a muted link passes nothing,
    and the socket's own value counts (``socket.is_linked`` is true for muted links too)."""
    return [link for link in socket.links if not link.is_muted]


def _has_weight(node) -> bool:
    """Whether the node's Subsurface Weight is above 0, linked, or animated or driven
    (0 at this frame may not be 0 at the next one the render reaches)."""
    socket = node.inputs.get(WEIGHT)
    if socket is None:
        return False
    if live_links(socket) or socket.default_value > 0.0:
        return True
    anim = getattr(node.id_data, "animation_data", None)
    path = socket.path_from_id("default_value")
    return any(fc.data_path == path and not fc.mute for fc in _fcurves(anim))


def _source_node(material):
    """The Principled BSDF that defines the material's subsurface (or None)."""
    nodes = [node for _, node in principled_nodes(getattr(material, "node_tree", None))]
    for node in nodes:
        if _has_weight(node):
            return node
    return nodes[0] if nodes else None


def _settings(material):
    return getattr(material, "sss_material", None)


def participates(material) -> bool:
    """Whether ``material`` takes part in screen-space subsurface scattering."""
    if material is None:
        return False
    settings = _settings(material)
    mode = settings.mode if settings is not None else "AUTO"
    if mode == "OFF":
        return False
    if mode == "ON":
        return True
    return any(_has_weight(node) for _, node in principled_nodes(material.node_tree))


def principled_shape(material) -> tuple[float, float, float] | None:
    """Burley ``d`` per channel (scene units) from the material's Principled BSDF."""
    node = _source_node(material)
    if node is None:
        return None
    radius = node.inputs[RADIUS].default_value
    scale = node.inputs[SCALE].default_value
    return tuple(float(v) for v in blender_shape(tuple(radius), float(scale)))


def node_input(node, identifier: str):
    """The node's input socket ``identifier``, or None.

    By identifier, not name: ``node.inputs[name]`` does not find a socket its node
    hides (Blender 5.0 raises KeyError for Subsurface IOR unless the method is
    Random Walk (Skin)), and the hidden socket still holds the user's value.
    """
    for socket in node.inputs:
        if socket.identifier == identifier:
            return socket
    return None


def subsurface_model(material) -> tuple[str, dict]:
    """(method, options) of the material's subsurface method for MaterialSpec.

    ``method`` is the Principled BSDF's ``subsurface_method`` (BURLEY without
    a node). For the random walks ``options`` holds what the fitted model needs
    (core.profiles.random_walk.shape): ``base_color`` (the socket's linear RGB),
    ``base_color_linked`` (a live link: the core takes the mean of the Diffuse
    Color pass over the material's pixels instead, since one colour per
    material is what the model takes), ``subsurface_radius``,
    ``subsurface_scale``, ``subsurface_ior`` and ``subsurface_anisotropy``;
    for BURLEY it is empty.
    """
    node = _source_node(material)
    if node is None:
        return "BURLEY", {}
    method = str(node.subsurface_method)
    if method not in SUBSURFACE_METHODS or method == "BURLEY":
        return "BURLEY", {}
    color = node_input(node, BASE_COLOR)
    options = {
        "base_color": [float(v) for v in tuple(color.default_value)[:3]],
        "base_color_linked": bool(live_links(color)),
        "subsurface_radius": [float(v) for v in node_input(node, RADIUS).default_value],
        "subsurface_scale": float(node_input(node, SCALE).default_value),
        "subsurface_ior": float(node_input(node, SUBSURFACE_IOR).default_value),
        "subsurface_anisotropy": float(node_input(node, ANISOTROPY).default_value),
    }
    return method, options


def own_model(material) -> tuple[str, dict] | None:
    """:func:`subsurface_model` where the post models the node's own method; None where a
    measured preset or an override replaces it (material panel, *Subsurface (cvsss)*)."""
    settings = _settings(material)
    if settings is not None and (settings.preset != "NONE" or settings.use_override):
        return None
    return subsurface_model(material)


def walk_mean_free_path(material) -> float | None:
    """The longest channel's mean free path (scene units) of the random walk the post
    models for ``material``, or None when it models none (Christensen-Burley, a
    measured preset or an override)."""
    model = own_model(material)
    if model is None or model[0] == "BURLEY":
        return None
    method, options = model
    ell = random_walk.mean_free_path(
        options["subsurface_radius"],
        options["subsurface_scale"],
        options["base_color"],
        method,
        options["subsurface_ior"],
    )
    return float(max(ell))


def model_summary(material) -> dict | None:
    """What the post models of ``material``'s subsurface, for the material panel.

    None without a Principled BSDF; else ``method`` (the Blender identifier),
    ``label``, ``d`` (the Burley shape the post samples, scene units) and
    ``energy`` (per channel, the factor on the scattered light before the view
    and curvature terms; 1 for BURLEY) and ``linked`` (a textured Base Color,
    whose socket value the panel's figures use).
    """
    node = _source_node(material)
    if node is None:
        return None
    method, options = subsurface_model(material)
    if method == "BURLEY":
        d, e = principled_shape(material), (1.0, 1.0, 1.0)
    else:
        d, e = random_walk.shape(
            options["subsurface_radius"],
            options["subsurface_scale"],
            options["base_color"],
            method,
            options["subsurface_ior"],
            options["subsurface_anisotropy"],
        )
    return {
        "method": method,
        "label": METHOD_LABELS[method],
        "d": tuple(float(v) for v in d),
        "energy": tuple(float(v) for v in e),
        "linked": bool(options.get("base_color_linked", False)),
    }


def _mm_per_unit(scene) -> float:
    # Millimetres per scene unit: 1000 for metres, times Blender's unit scale.
    scale_length = float(scene.unit_settings.scale_length) if scene is not None else 1.0
    return 1000.0 * (scale_length if scale_length > 0 else 1.0)


def preset_shape(material, scene=None) -> tuple[float, float, float] | None:
    """Burley ``d`` (scene units) of the material's measured preset, or None.

    ``d = ℓ/s(A_tot)`` of the preset (core.profiles.presets) times the
    material's ``preset_scale``, converted with the scene's unit scale.
    None when no preset is chosen.
    """
    settings = _settings(material)
    if settings is None or settings.preset == "NONE":
        return None
    measured = presets.get(settings.preset.lower())
    d = measured.burley_d(mm_per_unit=_mm_per_unit(scene), scale=float(settings.preset_scale))
    return tuple(float(v) for v in d)


def material_shape(material, scene=None) -> tuple[float, float, float]:
    """Burley ``d`` used for ``material``: the override, else its measured preset,
    else the Principled BSDF's."""
    settings = _settings(material)
    if settings is not None and settings.use_override:
        return tuple(float(v) for v in settings.d_override)
    shape = preset_shape(material, scene) or principled_shape(material)
    if shape is None:
        raise ValueError(
            f"material {material.name!r} takes part but has no Principled BSDF; "
            "set an override d in its Subsurface (cvsss) panel"
        )
    return shape


def scene_materials(scene, view_layer=None) -> list:
    """Materials the scene renders (evaluated: instances and modifiers included), by name.

    Off the main thread (a render handler during a UI render) the depsgraph
    belongs to the main thread: only the objects' material slots are read.
    """
    view_layer = view_layer or scene.view_layers[0]
    found = {}
    if threading.current_thread() is threading.main_thread():
        try:
            depsgraph = view_layer.depsgraph
            depsgraph.update()
            for id_ in depsgraph.ids:
                if isinstance(id_, bpy.types.Material):
                    found[id_.original.name] = id_.original
        except (AttributeError, RuntimeError):
            pass
    for obj in scene.objects:
        for slot in getattr(obj, "material_slots", ()):
            if slot.material is not None:
                found.setdefault(slot.material.name, slot.material)
    return [found[name] for name in sorted(found)]


def carries(obj, materials) -> bool:
    """Whether one of ``obj``'s material slots holds one of ``materials`` (a set)."""
    return any(s.material in materials for s in getattr(obj, "material_slots", ()))


def slot_materials(scene) -> Iterator:
    """Materials in the slots of the scene's objects and of the collections they
    instance: what can be read without evaluating the scene (a panel's redraw)."""
    seen = set()
    for obj in scene.objects:
        objects = [obj]
        collection = getattr(obj, "instance_collection", None)
        if obj.instance_type == "COLLECTION" and collection is not None:
            objects += list(collection.all_objects)
        for each in objects:
            if each.name in seen:
                continue
            seen.add(each.name)
            for slot in getattr(each, "material_slots", ()):
                if slot.material is not None:
                    yield slot.material


def participating(scene, view_layer=None) -> list:
    """Scene materials that take part, in slot order (sorted by name)."""
    return [m for m in scene_materials(scene, view_layer) if participates(m)]


def subsurface_weight(material) -> tuple[float, bool]:
    """(w, linked): the Subsurface Weight of the material's Principled BSDF, in [0, 1].

    A linked (textured) weight is written per pixel by the pass render (value
    AOV ``cvsss_weight``); its constant is then 1. A material without a
    Principled BSDF (an override) counts as fully subsurface.
    """
    node = _source_node(material)
    socket = None if node is None else node.inputs.get(WEIGHT)
    if socket is None:
        return 1.0, False
    saved = disabled(node)
    if saved is not None:  # forced to 0 for a pass render: the user's value counts
        return (1.0, True) if saved.links else (min(max(saved.value, 0.0), 1.0), False)
    if live_links(socket):
        return 1.0, True
    return min(max(float(socket.default_value), 0.0), 1.0), False


def weight_source(material):
    """(node tree, output socket) feeding a linked Subsurface Weight, or None."""
    for tree, node in principled_nodes(getattr(material, "node_tree", None)):
        socket = node.inputs.get(WEIGHT)
        links = [] if socket is None else live_links(socket)
        if links and node == _source_node(material):
            return tree, links[0].from_socket
    return None


def unmodelled_inputs(material) -> list[str]:
    """Warnings for what cvsss reads as a constant although the material textures it."""
    node = _source_node(material)
    if node is None:
        return []
    out = []
    for name in (RADIUS, SCALE):
        socket = node.inputs.get(name)
        if socket is not None and live_links(socket):
            out.append(
                f"material {material.name!r}: {name} is linked (textured); cvsss uses its "
                "socket value everywhere, Cycles varies it per point"
            )
    return out


def material_specs(materials: Iterable, scene=None) -> list[MaterialSpec]:
    """MaterialSpec per participating material; slots 1..K in the given order.

    A chosen measured preset travels in ``options`` (name, scale and the
    scene's millimetres per unit) so the core can build its dipole profile;
    ``weight`` is the Subsurface Weight (``options["weight_linked"]`` when it is
    linked and travels per pixel instead). Without a preset or an override,
    ``method`` and the random-walk model's inputs come from the node
    (:func:`subsurface_model`).
    """
    specs = []
    for slot, material in enumerate(materials, 1):
        settings = _settings(material)
        options = {}
        method = "BURLEY"
        if settings is not None and settings.preset != "NONE":
            options = {
                "preset": settings.preset.lower(),
                "preset_scale": float(settings.preset_scale),
                "mm_per_unit": _mm_per_unit(scene),
            }
        elif (model := own_model(material)) is not None:
            # The node's own profile: its method's model (an override replaces it).
            method, options = model
        weight, linked = subsurface_weight(material)
        if linked:
            options["weight_linked"] = True
        specs.append(
            MaterialSpec(
                slot=slot,
                name=material.name,
                d=material_shape(material, scene),
                options=options,
                weight=weight,
                method=method,
            )
        )
    return specs


# -- switching subsurface off for the pass render ------------------------------------
def _fcurves(anim) -> Iterator:
    """Drivers and action F-curves of an AnimData (legacy and layered actions)."""
    if anim is None:
        return
    yield from anim.drivers
    action = anim.action
    if action is None:
        return
    if getattr(action, "layers", None):
        for layer in action.layers:
            for strip in layer.strips:
                for bag in getattr(strip, "channelbags", ()):
                    yield from bag.fcurves
    elif hasattr(action, "fcurves"):
        yield from action.fcurves


#: Principled nodes whose weight SSSDisabled holds at 0: node pointer -> saved state.
_DISABLED: dict[int, _SavedSocket] = {}


@dataclass
class _SavedSocket:
    node_tree: object
    node: str
    value: float
    links: list = field(default_factory=list)
    muted: list = field(default_factory=list)  # (fcurve, mute flag)
    muted_links: list = field(default_factory=list)  # from-sockets of muted links
    wired: bool = False  # its weight fed again at thin points (thin_parts.thin_point_nodes)


def disabled(node) -> _SavedSocket | None:
    """What :class:`SSSDisabled` saved of ``node`` (a Principled BSDF) while it holds its
    weight at 0, or None."""
    return _DISABLED.get(node.as_pointer())


class SSSDisabled(contextlib.AbstractContextManager):
    """Force Subsurface Weight to 0 on ``materials``; restore on exit, whatever happens.

    Linked weights are unlinked and animation or drivers on the weight muted,
    so the render sees 0 on every frame. A muted link passes nothing: it stays
    as it is (muted), and only the links Blender evaluates are removed and
    put back; a muted link replaced meanwhile (the thin points' nodes feed the
    socket, :func:`.thin_parts.thin_point_nodes`) is put back muted.
    """

    def __init__(self, materials: Iterable) -> None:
        self.materials = list(materials)
        self.saved: list[_SavedSocket] = []

    def __enter__(self) -> SSSDisabled:
        try:
            for material in self.materials:
                for tree, node in principled_nodes(material.node_tree):
                    socket = node.inputs[WEIGHT]
                    path = socket.path_from_id("default_value")
                    saved = _SavedSocket(
                        tree,
                        node.name,
                        float(socket.default_value),
                        [link.from_socket for link in live_links(socket)],
                        muted_links=[link.from_socket for link in socket.links if link.is_muted],
                    )
                    self.saved.append(saved)
                    _DISABLED.setdefault(node.as_pointer(), saved)
                    for fcurve in _fcurves(tree.animation_data):
                        if fcurve.data_path == path:
                            saved.muted.append((fcurve, fcurve.mute))
                            fcurve.mute = True
                    for link in live_links(socket):
                        tree.links.remove(link)
                    socket.default_value = 0.0
        except BaseException:
            self.restore()
            raise
        return self

    def restore(self) -> None:
        # Reverse order: a node group shared by two materials is saved twice,
        # and the first record holds the original state.
        for saved in reversed(self.saved):
            node = saved.node_tree.nodes[saved.node]
            if _DISABLED.get(node.as_pointer()) is saved:
                del _DISABLED[node.as_pointer()]
            socket = node.inputs[WEIGHT]
            socket.default_value = saved.value
            for from_socket in saved.links:
                if not any(link.from_socket == from_socket for link in live_links(socket)):
                    saved.node_tree.links.new(from_socket, socket)
            for from_socket in saved.muted_links:
                if not any(link.from_socket == from_socket for link in socket.links):
                    saved.node_tree.links.new(from_socket, socket).is_muted = True
            for fcurve, mute in saved.muted:
                fcurve.mute = mute
        self.saved.clear()

    def __exit__(self, *exc) -> None:
        self.restore()

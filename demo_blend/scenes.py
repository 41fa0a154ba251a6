"""Deterministic demo scenes, built into an existing Blender scene.

Each demo lives in its own collection ``cvsss demo <name>``; building it
again replaces the previous build. Geometry comes from bmesh (no operators,
so no context is needed) and animation from keyframes (no Python drivers,
so the scene renders the same with auto-run scripts disabled).

Registry: :data:`SCENES` maps a name to its :class:`DemoScene`; add a scene
with the :func:`demo` decorator. ``build(name, scene=None)`` builds one.

Demos
-----
flash
    A plane and Suzanne with a skin-like Principled subsurface material,
    lit by a sun whose strength is ``I(t) = sin(2π·5t) + 1`` at 60 fps
    (t = 0 at the first frame), and a camera. Frames 1–120.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import bmesh
import bpy

FPS = 60
COLLECTION_PREFIX = "cvsss demo "


@dataclass(frozen=True)
class DemoScene:
    """A registered demo: name, one-line description, builder(scene, collection)."""

    name: str
    description: str
    builder: Callable[[object, object], None]


#: Name -> DemoScene, in registration order.
SCENES: dict[str, DemoScene] = {}


def demo(name: str, description: str):
    """Decorator registering ``builder(scene, collection)`` as the demo ``name``."""

    def wrap(builder):
        SCENES[name] = DemoScene(name, description, builder)
        return builder

    return wrap


def names() -> tuple[str, ...]:
    """Names of the registered demos."""
    return tuple(SCENES)


def describe() -> dict[str, str]:
    """Name -> description of the registered demos."""
    return {name: scene.description for name, scene in SCENES.items()}


def build(name: str, scene=None):
    """Build the demo ``name`` into ``scene`` (default: the context scene).

    Returns
    -------
    bpy.types.Collection
        The demo's collection (replaced if it existed).
    """
    if name not in SCENES:
        raise ValueError(f"demo must be one of {', '.join(SCENES)}, got {name!r}")
    scene = scene or bpy.context.scene
    collection = _fresh_collection(scene, COLLECTION_PREFIX + name)
    SCENES[name].builder(scene, collection)
    return collection


# -- helpers --------------------------------------------------------------------------------
def _fresh_collection(scene, name: str):
    old = bpy.data.collections.get(name)
    if old is not None:
        for obj in list(old.all_objects):
            data = obj.data
            bpy.data.objects.remove(obj, do_unlink=True)
            if data is not None and data.users == 0:
                _remove_data(data)
        bpy.data.collections.remove(old)
    collection = bpy.data.collections.new(name)
    scene.collection.children.link(collection)
    return collection


def _remove_data(data) -> None:
    if isinstance(data, bpy.types.Mesh):
        bpy.data.meshes.remove(data)
    elif isinstance(data, bpy.types.Light):
        bpy.data.lights.remove(data)
    elif isinstance(data, bpy.types.Camera):
        bpy.data.cameras.remove(data)


def _mesh_object(name: str, collection, make: Callable[[bmesh.types.BMesh], None],
                 smooth: bool = False):
    bm = bmesh.new()
    make(bm)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    if smooth:
        mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    return obj


def _material(name: str):
    """A fresh material ``name`` (an existing one is reset to the defaults)."""
    material = bpy.data.materials.get(name)
    if material is not None:
        bpy.data.materials.remove(material)
    material = bpy.data.materials.new(name)
    return material, material.node_tree.nodes["Principled BSDF"]


def skin_material(name: str = "cvsss Skin"):
    """Skin-like Principled subsurface material (Blender's skin radius, Burley)."""
    material, bsdf = _material(name)
    bsdf.inputs["Base Color"].default_value = (0.8, 0.45, 0.35, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.45
    bsdf.inputs["Subsurface Weight"].default_value = 1.0
    bsdf.inputs["Subsurface Radius"].default_value = (1.0, 0.2, 0.1)
    bsdf.inputs["Subsurface Scale"].default_value = 0.25
    bsdf.subsurface_method = "BURLEY"
    material.diffuse_color = (0.8, 0.45, 0.35, 1.0)
    return material


def diffuse_material(name: str, color: tuple[float, float, float]):
    """Plain diffuse Principled material without subsurface."""
    material, bsdf = _material(name)
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.8
    material.diffuse_color = (*color, 1.0)
    return material


def _fcurves(id_data):
    anim = id_data.animation_data
    if anim is None or anim.action is None:
        return []
    action = anim.action
    if getattr(action, "layers", None):
        return [fc for layer in action.layers for strip in layer.strips
                for bag in strip.channelbags for fc in bag.fcurves]
    return list(getattr(action, "fcurves", ()))


def keyframe_values(id_data, prop: str, frames, values) -> None:
    """Keyframe ``id_data.prop`` at every frame, linear in between."""
    for frame, value in zip(frames, values, strict=True):
        setattr(id_data, prop, value)
        id_data.keyframe_insert(prop, frame=frame)
    for fcurve in _fcurves(id_data):
        if fcurve.data_path == prop:
            for key in fcurve.keyframe_points:
                key.interpolation = "LINEAR"


def _world(scene, strength: float = 0.05):
    world = bpy.data.worlds.get("cvsss demo world") or bpy.data.worlds.new("cvsss demo world")
    if world.node_tree is not None and "Background" in world.node_tree.nodes:
        bg = world.node_tree.nodes["Background"]
        bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
        bg.inputs["Strength"].default_value = strength
    world.color = (strength, strength, strength)
    scene.world = world


def _camera(name: str, collection, location, rotation, lens: float = 50.0):
    cam = bpy.data.cameras.new(name)
    cam.lens = lens
    cam.clip_start, cam.clip_end = 0.1, 100.0
    obj = bpy.data.objects.new(name, cam)
    obj.location = location
    obj.rotation_euler = rotation
    collection.objects.link(obj)
    return obj


def _render_settings(scene, frame_end: int) -> None:
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.frame_start, scene.frame_end = 1, frame_end
    scene.frame_set(1)
    scene.render.resolution_x, scene.render.resolution_y = 320, 180
    scene.render.resolution_percentage = 100
    scene.render.engine = "CYCLES"
    if getattr(scene, "cycles", None) is not None:
        scene.cycles.samples = 16
        scene.cycles.use_denoising = False
        scene.cycles.seed = 0


def flash_strength(frame: int, frame_start: int = 1, fps: int = FPS) -> float:
    """Sun strength of the flash demo, ``sin(2π·5t) + 1`` with ``t = (frame − start)/fps``."""
    t = (frame - frame_start) / fps
    return math.sin(2.0 * math.pi * 5.0 * t) + 1.0


# -- demos ----------------------------------------------------------------------------------
@demo("flash", "Suzanne with skin-like SSS on a plane, sun flashing at 5 Hz (60 fps)")
def _build_flash(scene, collection) -> None:
    frame_end = 120
    _render_settings(scene, frame_end)
    _world(scene)

    plane = _mesh_object(
        "flash Plane", collection,
        lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=5.0),
    )
    plane.location = (0.0, 0.0, -1.0)
    plane.data.materials.append(diffuse_material("cvsss Floor", (0.6, 0.6, 0.6)))

    suzanne = _mesh_object("flash Suzanne", collection,
                           lambda bm: bmesh.ops.create_monkey(bm), smooth=True)
    suzanne.rotation_euler = (math.radians(-10.0), 0.0, 0.0)
    subsurf = suzanne.modifiers.new("Subdivision", "SUBSURF")
    subsurf.levels = subsurf.render_levels = 1
    suzanne.data.materials.append(skin_material())

    light = bpy.data.lights.new("flash Sun", "SUN")
    light.angle = math.radians(2.0)
    sun = bpy.data.objects.new("flash Sun", light)
    sun.rotation_euler = (math.radians(50.0), 0.0, math.radians(20.0))
    collection.objects.link(sun)
    frames = range(1, frame_end + 1)
    keyframe_values(light, "energy", frames, [flash_strength(f) for f in frames])

    scene.camera = _camera("flash Camera", collection, (0.0, -6.5, 0.9),
                           (math.radians(83.0), 0.0, 0.0))

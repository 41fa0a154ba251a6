"""Deterministic demo scenes, built into an existing Blender scene.

Each demo lives in its own collection ``cvsss demo <name>``; building it
again replaces the previous build. Geometry comes from bmesh (no operators,
so no context is needed) and animation from keyframes (no Python drivers,
so the scene renders the same with auto-run scripts disabled). Every random
choice (candle flicker, boid emission) comes from a fixed seed, the camera is
static and scene units are metres.

Registry: :data:`SCENES` maps a name to its :class:`DemoScene`; add a scene
with the :func:`demo` decorator. ``build(name, scene=None, frames=None)``
builds one; ``frames`` sets the length of the animation (default 120 at
60 fps).

Subsurface materials are Principled BSDFs (Christensen-Burley) whose
Subsurface Radius and Scale give a Burley shape ``d = radius·scale·0.25/π``
(Cycles' mapping) of about 10 mm in the widest channel. The cameras frame
the subjects at 1.5–1.8 m with a 50 mm lens, where a pixel of the default
320×180 render covers 3.4–4 mm: the scattering reaches a few pixels (its
0.997 energy radius is ~16·d). Marble, apple and skin take ``d = ℓ/s(A)``
and the albedo ``A`` of the measured materials (core.profiles.presets),
scaled up by :data:`PRESET_SCALE` so that real-size scattering (< 1 mm)
shows at this resolution.

Demos
-----
flash
    Suzanne (skin), a marble block and two apples on a table, crossed by
    the hard shadow of an overhead slat, lit by a sun whose strength is
    ``I(t) = FLASH_PEAK/2 · (sin(2π·5t) + 1)`` at 60 fps (t = 0 at frame 1).
regular
    The same kind of table lit by an area light switched on and off every
    3 s (off at t = 1 s, 7 s, …; on at t = 4 s, 10 s, …) and three
    flickering candles of wax (Subsurface Weight 0.5: half diffuse, half
    subsurface) with point lights at their flames.
boids
    A marble table top with a candle in the middle, 48 bird-sized boid
    particles (Blender's BOIDS physics) flocking around the flame under a
    small lamp 1 m above the table and a weak sun: their shadows, about 8 cm
    across, sweep over the marble, a skin Suzanne and the candle. The
    particle cache is baked when the scene is built.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import bmesh
import bpy
from mathutils import Euler, Matrix, Vector

from ..core.profiles import presets

FPS = 60
#: Default animation length in frames (2 s at 60 fps).
FRAMES = 120
COLLECTION_PREFIX = "cvsss demo "
#: Seed of every random choice in the demos.
SEED = 5
#: Burley shape of the widest channel of every subsurface material (metres).
D_MAX = 0.010
#: Shadow lines of the flash demo's slats (multiples of 0.2 m in y at 0.15 m height; one slat).
BLIND_LINES = (0,)
MARBLE_TOP = 1
#: Peak sun strength (W/m²) of the flash demo: I(t) = FLASH_PEAK/2 · (sin(2π·5t) + 1).
FLASH_PEAK = 2.0
#: Strength of the regular demo's switched area light when on (W).
LAMP_POWER = 10.0
#: Mean power of a candle's point light (W) and the depth of its flicker.
CANDLE_POWER = 0.5
CANDLE_FLICKER = 0.35


@dataclass(frozen=True)
class DemoScene:
    """A registered demo: name, one-line description, builder(scene, collection, frames)."""

    name: str
    description: str
    builder: Callable[[object, object, int], None]


#: Name -> DemoScene, in registration order.
SCENES: dict[str, DemoScene] = {}


def demo(name: str, description: str):
    """Decorator registering ``builder(scene, collection, frames)`` as the demo ``name``."""

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


def build(name: str, scene=None, frames: int | None = None):
    """Build the demo ``name`` into ``scene`` (default: the context scene).

    Parameters
    ----------
    name : str, a key of :data:`SCENES`
    scene : bpy.types.Scene, optional
    frames : int, optional
        Animation length; the scene's range becomes 1..frames (default
        :data:`FRAMES`). Lights are keyframed and boids baked over it.

    Returns
    -------
    bpy.types.Collection
        The demo's collection (replaced if it existed).
    """
    if name not in SCENES:
        raise ValueError(f"demo must be one of {', '.join(SCENES)}, got {name!r}")
    frames = FRAMES if frames is None else int(frames)
    if frames < 1:
        raise ValueError(f"frames must be >= 1, got {frames}")
    scene = scene or bpy.context.scene
    collection = _fresh_collection(scene, COLLECTION_PREFIX + name)
    _render_settings(scene, frames)
    SCENES[name].builder(scene, collection, frames)
    scene.frame_set(1)
    return collection


# -- animation curves (pure functions of the frame; the tests check the keys against them) --
def flash_strength(frame: int, frame_start: int = 1, fps: int = FPS) -> float:
    """Sun strength of the flash demo, ``FLASH_PEAK/2 · (sin(2π·5t) + 1)``, t = (frame − start)/fps."""
    t = (frame - frame_start) / fps
    return 0.5 * FLASH_PEAK * (math.sin(2.0 * math.pi * 5.0 * t) + 1.0)


def lamp_on(frame: int, frame_start: int = 1, fps: int = FPS, period: float = 3.0) -> bool:
    """The regular demo's area light: on for t < 1 s, then toggled every ``period`` s."""
    t = (frame - frame_start) / fps
    return math.floor((t + period - 1.0) / period) % 2 == 0


def flicker(frame: int, seed: int, depth: float = CANDLE_FLICKER, knot: int = 4) -> float:
    """Candle flicker factor around 1: value noise with a random knot every ``knot`` frames.

    Deterministic in (frame, seed) whatever the order of evaluation: each
    knot's value comes from its own string-seeded generator.
    """

    def value(k: int) -> float:
        return random.Random(f"cvsss-flicker:{seed}:{k}").uniform(-1.0, 1.0)

    k, rest = divmod(frame, knot)
    w = rest / knot
    w = w * w * (3.0 - 2.0 * w)  # smoothstep: no kinks at the knots
    return 1.0 + depth * ((1.0 - w) * value(k) + w * value(k + 1))


# -- helpers --------------------------------------------------------------------------------
def _fresh_collection(scene, name: str):
    old = bpy.data.collections.get(name)
    if old is not None:
        for obj in list(old.all_objects):
            data = obj.data
            settings = [
                m.particle_system.settings for m in obj.modifiers if m.type == "PARTICLE_SYSTEM"
            ]
            bpy.data.objects.remove(obj, do_unlink=True)
            if data is not None and data.users == 0:
                _remove_data(data)
            for ps in settings:
                if ps.users == 0:
                    bpy.data.particles.remove(ps)
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


def _mesh_object(
    name: str, collection, make: Callable[[bmesh.types.BMesh], None], smooth: bool = False
):
    bm = bmesh.new()
    make(bm)
    mesh = bpy.data.meshes.get(name)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)
    mesh = bpy.data.meshes.new(name)
    bm.to_mesh(mesh)
    bm.free()
    if smooth:
        mesh.shade_smooth()
    obj = bpy.data.objects.new(name, mesh)
    collection.objects.link(obj)
    return obj


def _place(obj, location=(0.0, 0.0, 0.0), rotation=(0.0, 0.0, 0.0), scale=(1.0, 1.0, 1.0)):
    obj.location = location
    obj.rotation_euler = tuple(math.radians(a) for a in rotation)
    obj.scale = scale
    return obj


def _box(name, collection, size, material, location, rotation=(0.0, 0.0, 0.0)):
    """Axis-aligned box of ``size`` (x, y, z) metres, bottom face at ``location.z``."""
    x, y, z = size
    obj = _mesh_object(name, collection, lambda bm: bmesh.ops.create_cube(bm, size=1.0))
    _place(obj, (location[0], location[1], location[2] + z / 2), rotation, (x, y, z))
    obj.data.materials.append(material)
    return obj


def _sphere(name, collection, radius, material, location, segments=32):
    def make(bm):
        bmesh.ops.create_uvsphere(bm, u_segments=segments, v_segments=segments // 2, radius=radius)

    obj = _mesh_object(name, collection, make, smooth=True)
    _place(obj, location)
    obj.data.materials.append(material)
    return obj


def _cylinder(name, collection, radius, height, material, location, segments=32):
    """Upright capped cylinder standing on ``location``."""

    def make(bm):
        bmesh.ops.create_cone(
            bm,
            cap_ends=True,
            cap_tris=False,
            segments=segments,
            radius1=radius,
            radius2=radius,
            depth=height,
            matrix=Matrix.Translation((0.0, 0.0, height / 2)),
        )

    obj = _mesh_object(name, collection, make, smooth=True)
    _place(obj, location)
    obj.data.materials.append(material)
    return obj


def _suzanne(name, collection, material, location, size=0.12, turn=0.0):
    """Suzanne ``2.7·size`` m wide, face towards −Y (the cameras), chin near ``location.z``."""

    def make(bm):
        bmesh.ops.create_monkey(bm, matrix=Matrix.Scale(size, 4))

    obj = _mesh_object(name, collection, make, smooth=True)
    _place(obj, (location[0], location[1], location[2] + 0.85 * size), (-10.0, 0.0, turn))
    subsurf = obj.modifiers.new("Subdivision", "SUBSURF")
    subsurf.levels = subsurf.render_levels = 1
    obj.data.materials.append(material)
    return obj


def _material(name: str):
    """A fresh material ``name`` (an existing one is reset to the defaults)."""
    material = bpy.data.materials.get(name)
    if material is not None:
        bpy.data.materials.remove(material)
    material = bpy.data.materials.new(name)
    return material, material.node_tree.nodes["Principled BSDF"]


def sss_material(
    name: str,
    color: Sequence[float],
    d: Sequence[float],
    roughness: float = 0.5,
):
    """Principled subsurface material (Burley) with Burley shape ``d`` (metres, RGB).

    Subsurface Radius is ``d`` normalised to its largest channel and the
    Scale carries the size, ``max(d)·π/0.25``, so that Cycles' mapping
    ``radius·scale·0.25/π`` gives back ``d``.
    """
    material, bsdf = _material(name)
    d_max = max(d)
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = roughness
    bsdf.inputs["Subsurface Weight"].default_value = 1.0
    bsdf.inputs["Subsurface Radius"].default_value = tuple(v / d_max for v in d)
    bsdf.inputs["Subsurface Scale"].default_value = d_max * math.pi / 0.25
    bsdf.subsurface_method = "BURLEY"
    material.diffuse_color = (*color, 1.0)
    return material


def preset_material(name: str, preset: str, d_max: float | None = None, roughness: float = 0.5):
    """Subsurface material from a measured preset: albedo A_tot and ``d ∝ ℓ/s(A)``.

    The preset's per-channel shape is scaled so its widest channel is
    ``d_max`` (default :data:`D_MAX`): the colour of the scattering is the
    measured one, its size one that shows at the demo resolution.
    """
    measured = presets.get(preset)
    color = [min(float(a), 0.95) for a in measured.total_reflectance()]
    d = [float(v) for v in measured.burley_d()]
    scale = (D_MAX if d_max is None else d_max) / max(d)
    return sss_material(name, color, [v * scale for v in d], roughness)


def skin_material(name: str = "cvsss Skin"):
    """Skin: the measured skin1 preset (albedo ≈ (0.47, 0.27, 0.17), d ∝ (0.72, 0.37, 0.22))."""
    return preset_material(name, "skin1", roughness=0.45)


def wax_material(name: str = "cvsss Wax", weight: float = 1.0):
    """Candle wax: pale, strongly scattering, d ∝ (1, 0.8, 0.5); Subsurface Weight ``weight``."""
    material = sss_material(name, (0.92, 0.86, 0.72), (D_MAX, 0.8 * D_MAX, 0.5 * D_MAX), 0.35)
    material.node_tree.nodes["Principled BSDF"].inputs["Subsurface Weight"].default_value = weight
    return material


def diffuse_material(name: str, color: tuple[float, float, float]):
    """Plain diffuse Principled material without subsurface."""
    material, bsdf = _material(name)
    bsdf.inputs["Base Color"].default_value = (*color, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.8
    material.diffuse_color = (*color, 1.0)
    return material


def emission_material(name: str, color: tuple[float, float, float], strength: float):
    """Emissive material (a candle flame); black base so it takes no light."""
    material, bsdf = _material(name)
    bsdf.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    bsdf.inputs["Emission Color"].default_value = (*color, 1.0)
    bsdf.inputs["Emission Strength"].default_value = strength
    material.diffuse_color = (*color, 1.0)
    return material


def _fcurves(id_data):
    anim = id_data.animation_data
    if anim is None or anim.action is None:
        return []
    action = anim.action
    if getattr(action, "layers", None):
        return [
            fc
            for layer in action.layers
            for strip in layer.strips
            for bag in strip.channelbags
            for fc in bag.fcurves
        ]
    return list(getattr(action, "fcurves", ()))


def keyframe_values(id_data, prop: str, frames, values, interpolation: str = "LINEAR") -> None:
    """Keyframe ``id_data.prop`` at every frame (LINEAR or CONSTANT in between)."""
    for frame, value in zip(frames, values, strict=True):
        setattr(id_data, prop, value)
        id_data.keyframe_insert(prop, frame=frame)
    for fcurve in _fcurves(id_data):
        if fcurve.data_path == prop:
            for key in fcurve.keyframe_points:
                key.interpolation = interpolation


def _world(scene, strength: float = 0.03):
    world = bpy.data.worlds.get("cvsss demo world") or bpy.data.worlds.new("cvsss demo world")
    if world.node_tree is not None and "Background" in world.node_tree.nodes:
        bg = world.node_tree.nodes["Background"]
        bg.inputs["Color"].default_value = (0.8, 0.9, 1.0, 1.0)
        bg.inputs["Strength"].default_value = strength
    world.color = (strength, strength, strength)
    scene.world = world


def _camera(name: str, collection, location, target, lens: float = 50.0):
    """Static perspective camera at ``location`` looking at ``target``."""
    cam = bpy.data.cameras.new(name)
    cam.lens = lens
    cam.sensor_width = 36.0
    cam.sensor_fit = "HORIZONTAL"
    cam.clip_start, cam.clip_end = 0.05, 50.0
    obj = bpy.data.objects.new(name, cam)
    obj.location = location
    direction = (
        target[0] - location[0],
        target[1] - location[1],
        target[2] - location[2],
    )
    obj.rotation_euler = Vector(direction).to_track_quat("-Z", "Y").to_euler()
    collection.objects.link(obj)
    return obj


def _sun(name, collection, strength, rotation, angle=2.0):
    light = bpy.data.lights.new(name, "SUN")
    light.energy = strength
    light.angle = math.radians(angle)
    obj = bpy.data.objects.new(name, light)
    _place(obj, (0.0, 0.0, 3.0), rotation)
    collection.objects.link(obj)
    return obj


def _blind(sun_rotation, height: float, at: float, lines, spacing: float):
    """Slat centres at ``height`` whose shadows fall on lines y = k·spacing at height ``at``."""
    direction = Euler([math.radians(a) for a in sun_rotation]).to_matrix() @ Vector((0, 0, -1))
    travel = (height - at) / -direction.z
    return [(-travel * direction.x, k * spacing - travel * direction.y, height) for k in lines]


def _render_settings(scene, frame_end: int) -> None:
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.frame_start, scene.frame_end = 1, frame_end
    scene.frame_set(1)
    scene.unit_settings.system = "METRIC"
    scene.unit_settings.scale_length = 1.0
    scene.render.resolution_x, scene.render.resolution_y = 320, 180
    scene.render.resolution_percentage = 100
    scene.render.engine = "CYCLES"
    # Frames 2+ only move lights or particles: keep the synced scene between frames.
    scene.render.use_persistent_data = True
    cycles = getattr(scene, "cycles", None)
    if cycles is not None:
        # The passes' noise is the same input for every method: a few samples do,
        # with a fixed (not animated) seed so the noise pattern does not flicker.
        cycles.samples = 16
        cycles.use_adaptive_sampling = False
        cycles.use_denoising = False
        cycles.seed = SEED
        cycles.use_animated_seed = False
        cycles.max_bounces = 4
        cycles.diffuse_bounces = 2
        cycles.glossy_bounces = 1
        cycles.transmission_bounces = 0
        cycles.volume_bounces = 0
        cycles.transparent_max_bounces = 2
        cycles.sample_clamp_indirect = 2.0
        cycles.caustics_reflective = cycles.caustics_refractive = False


def _table(prefix, collection, material, size=(3.0, 3.0)):
    plane = _mesh_object(
        f"{prefix} Plane",
        collection,
        lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=0.5),
    )
    plane.scale = (size[0], size[1], 1.0)
    plane.data.materials.append(material)
    return plane


def _candle(prefix, index, collection, wax, flame_mat, location, height, radius, frames):
    """A wax candle with an emissive flame and a flickering point light at it."""
    x, y, z = location
    body = _cylinder(f"{prefix} Candle {index}", collection, radius, height, wax, location)
    flame_z = z + height + 0.018
    flame = _sphere(f"{prefix} Flame {index}", collection, 0.006, flame_mat, (x, y, flame_z), 12)
    flame.scale = (1.0, 1.0, 2.2)
    # The point light stands for the flame's light: the flame mesh is seen by
    # the camera only, so it neither blocks nor (noisily) adds that light.
    flame.visible_shadow = flame.visible_diffuse = flame.visible_glossy = False
    flame.visible_transmission = flame.visible_volume_scatter = False
    light = bpy.data.lights.new(f"{prefix} Candle Light {index}", "POINT")
    light.color = (1.0, 0.72, 0.42)
    light.shadow_soft_size = 0.004
    obj = bpy.data.objects.new(f"{prefix} Candle Light {index}", light)
    obj.location = (x, y, flame_z + 0.004)
    collection.objects.link(obj)
    keys = range(1, frames + 1)
    keyframe_values(
        light, "energy", keys, [CANDLE_POWER * flicker(f, SEED * 100 + index) for f in keys]
    )
    return body, flame, obj


# -- demos ----------------------------------------------------------------------------------
@demo("flash", "Suzanne (skin), marble and apples under a blind, sun flashing at 5 Hz (60 fps)")
def _build_flash(scene, collection, frames: int) -> None:
    _world(scene)
    _table("flash", collection, diffuse_material("cvsss Floor", (0.55, 0.5, 0.45)))
    marble = preset_material("cvsss Marble", "marble", roughness=0.5)
    if MARBLE_TOP:
        _box("flash Marble Top", collection, (1.6, 1.0, 0.02), marble, (0.0, 0.15, 0.0))

    skin = skin_material()
    _suzanne("flash Suzanne", collection, skin, (0.0, 0.02, 0.02), turn=12.0)
    _box("flash Marble", collection, (0.2, 0.2, 0.34), marble, (-0.38, 0.06, 0.0), (0, 0, 28))
    apple = preset_material("cvsss Apple", "apple", roughness=0.4)
    _sphere("flash Apple", collection, 0.075, apple, (0.33, -0.04, 0.075))
    _sphere("flash Apple 2", collection, 0.06, apple, (0.45, 0.12, 0.06))

    # A low sun (30° elevation, from the front left) past an overhead slat
    # draws a hard-edged, slightly soft (0.5° sun) shadow line across the
    # subjects at y = 0, over the curved SSS surfaces.
    rotation = (60.0, 0.0, -20.0)
    dark = diffuse_material("cvsss Dark", (0.05, 0.05, 0.05))
    for i, (x, y, z) in enumerate(
        _blind(rotation, height=1.0, at=0.15, lines=BLIND_LINES, spacing=0.2)
    ):
        slat = _box(
            f"flash Slat {i}", collection, (2.4, 0.04, 0.01), dark, (x, y, z), (0.0, 0.0, 8.0)
        )
        slat.visible_camera = False  # only its shadow matters (it hangs above, out of view)

    sun = _sun("flash Sun", collection, flash_strength(1), rotation, angle=0.5)
    keys = range(1, frames + 1)
    keyframe_values(sun.data, "energy", keys, [flash_strength(f) for f in keys])

    scene.camera = _camera("flash Camera", collection, (0.0, -1.5, 0.5), (0.0, 0.0, 0.14))


@demo(
    "regular",
    "Marble table with skin, marble and three flickering wax candles; a lamp switched every 3 s",
)
def _build_regular(scene, collection, frames: int) -> None:
    _world(scene, 0.02)
    _table("regular", collection, diffuse_material("cvsss Floor", (0.3, 0.28, 0.26)))
    marble = preset_material("cvsss Marble", "marble", roughness=0.5)
    _box("regular Marble Top", collection, (1.6, 1.0, 0.02), marble, (0.0, 0.15, 0.0))
    skin = skin_material()
    _suzanne("regular Suzanne", collection, skin, (-0.22, 0.1, 0.02), turn=20.0)
    _sphere("regular Marble", collection, 0.09, marble, (0.34, 0.18, 0.11))

    # Half-subsurface wax (Subsurface Weight 0.5): Cycles mixes diffuse and subsurface.
    wax = wax_material(weight=0.5)
    flame = emission_material("cvsss Flame", (1.0, 0.6, 0.25), 30.0)
    for i, (x, y, h, r) in enumerate(
        ((0.05, -0.12, 0.12, 0.028), (0.2, -0.0, 0.18, 0.032), (-0.45, -0.04, 0.1, 0.03))
    ):
        _candle("regular", i, collection, wax, flame, (x, y, 0.02), h, r, frames)

    light = bpy.data.lights.new("regular Lamp", "AREA")
    light.shape = "DISK"
    light.size = 0.25
    lamp = bpy.data.objects.new("regular Lamp", light)
    lamp.location = (-0.7, -0.6, 1.3)
    lamp.rotation_euler = (
        (Vector((0.0, 0.1, 0.1)) - lamp.location).to_track_quat("-Z", "Y").to_euler()
    )
    collection.objects.link(lamp)
    keys = range(1, frames + 1)
    keyframe_values(
        light, "energy", keys, [LAMP_POWER * lamp_on(f) for f in keys], interpolation="CONSTANT"
    )

    scene.camera = _camera("regular Camera", collection, (0.0, -1.5, 0.5), (0.0, 0.0, 0.12))


#: Radius of a boid (metres) and the power of the lamp above the flock (watts).
BOID_RADIUS = 0.03
BOIDS_LAMP_POWER = 25.0


@demo(
    "boids",
    "48 boids flock around a candle under a lamp, casting large moving shadows on marble and skin",
)
def _build_boids(scene, collection, frames: int) -> None:
    _world(scene, 0.02)
    _table("boids", collection, diffuse_material("cvsss Floor", (0.3, 0.28, 0.26)))
    marble = preset_material("cvsss Marble", "marble", roughness=0.5)
    _box("boids Marble Top", collection, (1.5, 0.9, 0.04), marble, (0.0, 0.1, 0.0))
    skin = skin_material()
    _suzanne("boids Suzanne", collection, skin, (-0.34, 0.12, 0.04), turn=25.0)
    wax = wax_material()
    flame = emission_material("cvsss Flame", (1.0, 0.6, 0.25), 30.0)
    _candle("boids", 0, collection, wax, flame, (0.05, 0.0, 0.04), 0.16, 0.035, frames)

    _sun("boids Sun", collection, 0.25, (12.0, 0.0, 30.0), angle=1.0)
    # A small lamp above the flock: the boids between it and the table cast
    # large, crisp shadows (about 1.3x their size) that sweep across the
    # marble and the skin; the sun only fills in.
    lamp = bpy.data.lights.new("boids Lamp", "POINT")
    lamp.energy = BOIDS_LAMP_POWER
    lamp.shadow_soft_size = 0.01
    lamp_obj = bpy.data.objects.new("boids Lamp", lamp)
    _place(lamp_obj, (-0.1, 0.05, 1.0))
    collection.objects.link(lamp_obj)

    # Boids: dark birds attracted to the flame, flocking and keeping apart.
    moth = _sphere(
        "boids Moth",
        collection,
        BOID_RADIUS,
        diffuse_material("cvsss Moth", (0.08, 0.07, 0.06)),
        (0.0, 0.0, -5.0),
        8,
    )
    moth.hide_render = True  # the instanced source; its instances render
    moth.scale = (1.6, 1.0, 0.6)
    goal = bpy.data.objects.new("boids Goal", None)
    goal.location = (-0.1, 0.05, 0.3)
    collection.objects.link(goal)

    emitter = _mesh_object(
        "boids Emitter",
        collection,
        lambda bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=0.15),
    )
    emitter.location = (0.1, 0.1, 0.45)
    emitter.show_instancer_for_render = False
    emitter.show_instancer_for_viewport = False
    modifier = emitter.modifiers.new("Boids", "PARTICLE_SYSTEM")
    psys = modifier.particle_system
    psys.seed = SEED
    ps = psys.settings
    ps.name = "boids Flock"
    ps.count = 48
    preroll = 90  # the flock forms before frame 1
    ps.frame_start, ps.frame_end = 1 - preroll, 1 - preroll + 10
    ps.lifetime = frames + preroll + 10
    ps.emit_from = "FACE"
    ps.physics_type = "BOIDS"
    ps.render_type = "OBJECT"
    ps.instance_object = moth
    ps.particle_size = 1.0
    ps.size_random = 0.3
    ps.use_rotations = True
    ps.rotation_mode = "VEL"
    boids = ps.boids
    boids.use_flight = True
    boids.air_speed_max = 0.9
    boids.air_speed_min = 0.2
    boids.air_acc_max = 0.6
    boids.air_ave_max = 0.6
    boids.air_personal_space = 1.5
    state = boids.states[0]
    state.ruleset_type = "AVERAGE"
    with bpy.context.temp_override(particle_settings=ps):
        bpy.ops.boid.rule_add(type="GOAL")
    state.rules[-1].object = goal
    cache = psys.point_cache
    cache.frame_start, cache.frame_end = 1 - preroll, frames
    scene.camera = _camera("boids Camera", collection, (0.0, -1.6, 0.62), (0.0, 0.05, 0.12))
    view_layer = scene.view_layers[0]
    with bpy.context.temp_override(scene=scene, view_layer=view_layer, point_cache=cache):
        bpy.ops.ptcache.bake_all(bake=True)

"""The scene Apply on Render's measurements render (imported by the scripts beside it).

A skin-like sphere (Principled BSDF, Random Walk subsurface, radius (1, 0.35,
0.2) × 0.1 m) on a grey floor under a point light, Cycles on the CPU with
its defaults (adaptive sampling, OpenImageDenoise with albedo and normal
guides, *Accurate* prefilter, *High* quality) but the samples and the size.
With ``frames`` > 1 the sphere slides 0.3 m to the right and the light
circles a quarter turn over the range, so the history must follow motion.
"""

from __future__ import annotations

import math

import bpy
import mathutils


def build_scene(width: int = 128, height: int = 72, samples: int = 16, frames: int = 1):
    """The measurement scene in a fresh file (``read_factory_settings``): the scene.

    Parameters
    ----------
    width, height : pixels
    samples : Cycles samples per pixel
    frames : frames 1..frames; more than one animates the sphere and the light
    """
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.frame_start, scene.frame_end = 1, frames
    scene.frame_current = 1
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs[1].default_value = 0.05

    skin = bpy.data.materials.new("skin")
    skin.use_nodes = True
    bsdf = skin.node_tree.nodes["Principled BSDF"]
    bsdf.subsurface_method = "RANDOM_WALK"
    bsdf.inputs["Base Color"].default_value = (0.8, 0.55, 0.45, 1)
    bsdf.inputs["Subsurface Weight"].default_value = 1.0
    bsdf.inputs["Subsurface Radius"].default_value = (1.0, 0.35, 0.2)
    bsdf.inputs["Subsurface Scale"].default_value = 0.1
    bsdf.inputs["Roughness"].default_value = 0.5
    bpy.ops.mesh.primitive_uv_sphere_add(
        radius=0.5, location=(0, 0, 0.5), segments=48, ring_count=24
    )
    bpy.ops.object.shade_smooth()
    sphere = bpy.context.object
    sphere.data.materials.append(skin)

    bpy.ops.mesh.primitive_plane_add(size=6)
    floor = bpy.data.materials.new("floor")
    floor.use_nodes = True
    floor.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.4, 0.4, 0.4, 1)
    bpy.context.object.data.materials.append(floor)

    bpy.ops.object.light_add(type="POINT", location=(1.5, -2.0, 2.5))
    light = bpy.context.object
    light.data.energy = 500.0
    light.data.shadow_soft_size = 0.3
    bpy.ops.object.camera_add(location=(0, -3.0, 1.3))
    camera = bpy.context.object
    scene.camera = camera
    direction = mathutils.Vector((0, 0, 0.45)) - camera.location
    camera.rotation_euler = direction.to_track_quat("-Z", "Y").to_euler()

    if frames > 1:
        for frame, share in ((1, 0.0), (frames, 1.0)):
            sphere.location.x = 0.3 * share
            sphere.keyframe_insert("location", index=0, frame=frame)
            angle = math.atan2(-2.0, 1.5) + 0.5 * math.pi * share
            light.location = (2.5 * math.cos(angle), 2.5 * math.sin(angle), 2.5)
            light.keyframe_insert("location", frame=frame)
    return scene


def exr_output(scene, path) -> None:
    """Write renders as 32-bit RGBA OpenEXR at ``path`` (Blender's output path rules)."""
    r = scene.render
    r.filepath = str(path)
    settings = r.image_settings
    if hasattr(settings, "media_type"):
        settings.media_type = "IMAGE"
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    settings.color_mode = "RGBA"

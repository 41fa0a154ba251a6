"""An independent check scene, built without demo_blend's helpers.

A skin-like sphere and a ketchup-like torus (Principled subsurface) on a grey
floor, lit by one point light whose strength flickers randomly and which is
switched off for frames 16-20
160x90 pixels, 16-spp Cycles passes, 30 frames.
Used to check the temporal-reuse and ground-truth figures on a scene the demo
did not tune (README, *Reading the report*):

    .venv/bin/python docs/checks/flicker_point_light.py out/check/scene.blend
    .venv/bin/cvsss render out/check/scene.blend --frames 1-30 --out out/check/run \
        --method none,separable,as_ccv,as_ccv_t,as_t --reference --reference-every 1 \
        --ground-truth --ground-truth-every 5 --ground-truth-spp 512
"""

import os
import random
import sys

import bpy
import mathutils

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.samples = 16
scene.cycles.use_denoising = False
scene.render.resolution_x, scene.render.resolution_y = 160, 90
scene.render.resolution_percentage = 100
scene.frame_start, scene.frame_end = 1, 30
world = bpy.data.worlds.new("w")
scene.world = world
world.use_nodes = True
world.node_tree.nodes["Background"].inputs[1].default_value = 0.05


def principled(name, color, radius, scale, weight=1.0):
    m = bpy.data.materials.new(name)
    m.use_nodes = True
    b = m.node_tree.nodes["Principled BSDF"]
    b.inputs["Base Color"].default_value = (*color, 1)
    b.inputs["Subsurface Weight"].default_value = weight
    b.inputs["Subsurface Radius"].default_value = radius
    b.inputs["Subsurface Scale"].default_value = scale
    b.inputs["Roughness"].default_value = 0.6
    return m


bpy.ops.mesh.primitive_uv_sphere_add(
    radius=0.5, location=(-0.6, 0, 0.5), segments=48, ring_count=24
)
bpy.ops.object.shade_smooth()
bpy.context.object.data.materials.append(
    principled("skin", (0.8, 0.55, 0.45), (1.0, 0.35, 0.2), 0.08)
)
bpy.ops.mesh.primitive_torus_add(location=(0.7, 0.1, 0.3), major_radius=0.4, minor_radius=0.18)
bpy.ops.object.shade_smooth()
bpy.context.object.data.materials.append(
    principled("ketchup", (0.6, 0.05, 0.03), (1.0, 0.2, 0.1), 0.06)
)
bpy.ops.mesh.primitive_plane_add(size=6)
floor = bpy.data.materials.new("floor")
floor.use_nodes = True
floor.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.4, 0.4, 0.4, 1)
bpy.context.object.data.materials.append(floor)
bpy.ops.object.light_add(type="POINT", location=(1.5, -2.0, 2.5))
light = bpy.context.object
light.data.shadow_soft_size = 0.3
rng = random.Random(7)
for f in range(1, 31):
    energy = 0.0 if 16 <= f <= 20 else 600.0 * (0.55 + 0.45 * rng.random())
    light.data.energy = energy
    light.data.keyframe_insert("energy", frame=f)
for fc in (
    light.data.animation_data.action.fcurves
    if hasattr(light.data.animation_data.action, "fcurves")
    else []
):
    for k in fc.keyframe_points:
        k.interpolation = "CONSTANT"
bpy.ops.object.camera_add(location=(0, -3.2, 1.4))
cam = bpy.context.object
scene.camera = cam
direction = (0 - cam.location.x, 0 - cam.location.y, 0.4 - cam.location.z)
cam.rotation_euler = mathutils.Vector(direction).to_track_quat("-Z", "Y").to_euler()
os.makedirs(os.path.dirname(os.path.abspath(sys.argv[-1])), exist_ok=True)
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[-1])
print("saved", sys.argv[-1])

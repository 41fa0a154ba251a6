"""Cycles' Christensen-Burley gains energy on curved surfaces: a check scene.

A skin-coloured UV sphere of radius 5 cm (Principled subsurface, Burley
d = (10, 5, 3) mm, so R = 5·d in red) alone in a uniform white world: every
point receives the same irradiance, so a profile that conserves energy shades
subsurface exactly like diffuse. Cycles does not: its disk probes weigh a hit
by the radial pdf at the true distance over the pdf of the disk radius, and on
the sphere the disk radius is shorter than the true distance (SPEC §11;
``core.mc.estimator``, *Cycles' kernel*). The mean ratio ours / Cycles per
channel (metrics.csv ``ratio_r/g/b``) shows which kernel follows Cycles:
``none`` (diffuse) below 1 by Cycles' gain, ``--distance surface`` (energy-
conserving, L = B under constant light) likewise, ``--distance cycles`` near 1.
160x90 pixels, SSS-off passes and ground truth at 512 spp:

    .venv/bin/python docs/checks/cycles_disk_gain.py out/gain/scene.blend
    .venv/bin/cvsss render out/gain/scene.blend --frames 1 --out out/gain/run --method none \
        --passes-only --ground-truth --ground-truth-spp 512
    for k in cycles surface; do .venv/bin/cvsss post out/gain/run/passes --method none,reference \
        --ground-truth out/gain/run/ground_truth --out out/gain/$k --distance $k; done
    cat out/gain/cycles/metrics.csv out/gain/surface/metrics.csv
"""

import math
import os
import sys

import bpy

bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
scene.render.engine = "CYCLES"
scene.cycles.samples = 512
scene.cycles.use_adaptive_sampling = False
scene.cycles.use_denoising = False
scene.cycles.seed = 3
scene.render.resolution_x, scene.render.resolution_y = 160, 90
scene.render.resolution_percentage = 100
scene.frame_start = scene.frame_end = 1
scene.view_settings.view_transform = "Standard"
world = bpy.data.worlds.new("uniform white")
scene.world = world
world.use_nodes = True
world.node_tree.nodes["Background"].inputs[0].default_value = (1.0, 1.0, 1.0, 1.0)
world.node_tree.nodes["Background"].inputs[1].default_value = 1.0

material = bpy.data.materials.new("skin sphere")
material.use_nodes = True
bsdf = material.node_tree.nodes["Principled BSDF"]
bsdf.inputs["Base Color"].default_value = (0.8, 0.55, 0.45, 1.0)
bsdf.inputs["Roughness"].default_value = 0.45
bsdf.inputs["Subsurface Weight"].default_value = 1.0
bsdf.inputs["Subsurface Radius"].default_value = (1.0, 0.5, 0.3)
# d = radius·scale·0.25/π: 10 mm in red.
bsdf.inputs["Subsurface Scale"].default_value = 0.01 * math.pi / 0.25
bsdf.subsurface_method = "BURLEY"

bpy.ops.mesh.primitive_uv_sphere_add(radius=0.05, segments=128, ring_count=64)
sphere = bpy.context.object
bpy.ops.object.shade_smooth()
sphere.data.materials.append(material)

camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
camera.data.lens = 50.0
camera.location = (0.0, -0.45, 0.0)
camera.rotation_euler = (math.radians(90.0), 0.0, 0.0)
scene.collection.objects.link(camera)
scene.camera = camera

os.makedirs(os.path.dirname(os.path.abspath(sys.argv[-1])), exist_ok=True)
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[-1])
print(f"saved {sys.argv[-1]}")

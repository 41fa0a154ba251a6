"""Save a sphere lit from the side, for ``cvsss compare``: where *Mirror Hidden Light*
parts from Cycles.

One sphere of the demo's apple material (radius 7.5 times its largest Burley
``d``, Random Walk as Principled has it by default) on a grey floor, a sun at
``--elevation`` degrees from the camera's front left, a dim grey world;
128×72, Cycles at 16 samples with its denoiser, frames 1–2, Apply on Render
on. ``--no-mirror`` turns *Mirror Hidden Light* off. From the repository
root::

    .venv/bin/python tools/measure/side_lit_sphere.py out/sphere.blend --elevation 12
    .venv/bin/cvsss compare out/sphere.blend --frames 1-1 --out out/sphere \\
        --engine CYCLES --samples 16 --method-variants BURLEY

(docs/explanation/accuracy.md §2.1 has the figures.)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import bpy

from cvsss.demo_blend import scenes
from cvsss.sss_addon.blender.standalone import ensure_registered


def build(elevation: float, mirror: bool):
    """The scene, in a fresh file."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    ensure_registered()
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 16
    scene.cycles.use_denoising = True
    scene.render.resolution_x, scene.render.resolution_y = 128, 72
    scene.frame_start, scene.frame_end = 1, 2
    apple = scenes.preset_material("cvsss Apple", "apple", roughness=0.4)
    for node in apple.node_tree.nodes:
        if node.type == "BSDF_PRINCIPLED":
            node.subsurface_method = "RANDOM_WALK"
    scenes._sphere("Apple", scene.collection, 0.075, apple, (0.0, 0.0, 0.075))
    bpy.ops.mesh.primitive_plane_add(size=4)
    bpy.context.object.data.materials.append(scenes.diffuse_material("Floor", (0.5, 0.5, 0.5)))
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.location = (0.0, -0.6, 0.12)
    camera.rotation_euler = (math.radians(84), 0.0, 0.0)
    camera.data.lens = 50
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(sun)
    sun.data.energy = 3.0
    sun.rotation_euler = (math.radians(90 - elevation), 0.0, math.radians(-60))
    world = bpy.data.worlds.new("world")
    scene.world = world
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.3
    scene.sss_settings.apply_on_render = True
    scene.sss_settings.hidden_mirror = mirror
    return scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="the .blend to write")
    parser.add_argument("--elevation", type=float, default=12.0, help="sun elevation, degrees")
    parser.add_argument("--no-mirror", action="store_true", help="Mirror Hidden Light off")
    args = parser.parse_args()
    build(args.elevation, not args.no_mirror)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(args.out.resolve()))


if __name__ == "__main__":
    main()

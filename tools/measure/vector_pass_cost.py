"""What the Vector pass costs a Cycles render of a scene whose geometry is evaluated
per frame (a subdivided, wave-deformed Suzanne with a Random Walk skin): with the
pass, the engine also evaluates the scene at the neighbouring frames for the motion.

Apply on Render renders the Vector pass for the temporal methods only
(``sss_addon.blender.passes.PassSetup``, ``motion``). From the repository root::

    python tools/measure/vector_pass_cost.py --size 128x72 --rounds 3
    python tools/measure/vector_pass_cost.py --save out/deformed.blend
    python tools/measure/apply_on_render_cost.py --blend out/deformed.blend \
        --first-frame 1 --rounds 3

(``python`` with ``bpy`` 5.0 importable.) It prints the seconds of each render of
frames 1–3, pass off and on in turn; with ``--save`` it writes the scene (frames
1–8) instead, for ``apply_on_render_cost.py``.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time

import bpy


def build(width: int, height: int, samples: int):
    """The scene: Suzanne (Subdivision 4 and Wave modifiers, Random Walk subsurface),
    a sun, a camera; frames 1–8."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = samples
    scene.cycles.device = "CPU"
    scene.render.resolution_x, scene.render.resolution_y = width, height
    bpy.ops.mesh.primitive_monkey_add()
    suzanne = bpy.context.object
    subdivision = suzanne.modifiers.new("subdivision", "SUBSURF")
    subdivision.levels = subdivision.render_levels = 4
    suzanne.modifiers.new("wave", "WAVE")
    skin = bpy.data.materials.new("skin")
    skin.use_nodes = True
    principled = skin.node_tree.nodes["Principled BSDF"]
    principled.inputs["Base Color"].default_value = (0.8, 0.5, 0.4, 1.0)
    principled.inputs["Subsurface Weight"].default_value = 1.0
    principled.inputs["Subsurface Radius"].default_value = (1.0, 0.5, 0.25)
    principled.inputs["Subsurface Scale"].default_value = 0.05
    suzanne.data.materials.append(skin)
    scene.frame_start, scene.frame_end = 1, 8
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    scene.collection.objects.link(camera)
    scene.camera = camera
    camera.location = (0.0, -4.0, 0.0)
    camera.rotation_euler = (1.5708, 0.0, 0.0)
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    scene.collection.objects.link(sun)
    return scene


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="128x72", help="WxH pixels (default 128x72)")
    parser.add_argument("--samples", type=int, default=16, help="Cycles samples (default 16)")
    parser.add_argument("--rounds", type=int, default=3, help="rounds of off / on (default 3)")
    parser.add_argument("--save", help="write the scene to this .blend instead of timing it")
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    scene = build(width, height, args.samples)
    if args.save:
        bpy.ops.wm.save_as_mainfile(filepath=bpy.path.abspath(args.save))
        return
    layer = scene.view_layers[0]
    folder = tempfile.mkdtemp(prefix="cvsss-vector-")
    times: dict[bool, list[float]] = {False: [], True: []}
    for _ in range(args.rounds):
        for vector in (False, True):
            layer.use_pass_vector = vector
            for frame in (1, 2, 3):
                scene.frame_set(frame)
                scene.render.filepath = f"{folder}/f{frame}"
                began = time.perf_counter()
                bpy.ops.render.render(write_still=True)
                times[vector].append(time.perf_counter() - began)
    for vector, runs in times.items():
        print(
            f"Vector pass {'on ' if vector else 'off'}: median {statistics.median(runs):.3f} s "
            f"a frame, runs {[round(t, 3) for t in runs]}"
        )


if __name__ == "__main__":
    main()

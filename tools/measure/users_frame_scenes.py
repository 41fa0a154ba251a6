"""Save the scenes issue 44's figures are measured on, at a given size, for ``cvsss compare``.

The three demo scenes (demo_blend/scenes.py, Christensen-Burley materials) and
the independent check scene (docs/checks/flicker_point_light.py, built without
the demo's helpers, Principled BSDF left at Blender's default Random Walk),
Blender's default cube (the factory startup file, its material's Subsurface
Weight set to 1, everything else as Blender has it: Random Walk, radius
(1, 0.2, 0.1) × 0.05 m, a still at frame 1) and ``monkey``, the same file with
the cube replaced by a subdivided Suzanne in a skin tone, each saved as
``OUT/<name>.blend`` with Cycles at ``--samples`` and EEVEE at
``--eevee-samples``; Cycles' denoiser is left as the scene has it (``cvsss
compare`` turns it on for the plain render, as Blender's default does)::

    .venv/bin/python tools/measure/users_frame_scenes.py out/users 128 72
    .venv/bin/cvsss compare out/users/flicker.blend --frames 10-11 \
        --out out/users/flicker --engine CYCLES --samples 16,64 \
        --method-variants material,BURLEY
    .venv/bin/python tools/measure/users_frame_scenes.py out/cube20 128 72 --scenes cube \
        --cube-scale 1.26
"""

from __future__ import annotations

import argparse
import runpy
import sys
from pathlib import Path

import bpy

from cvsss.demo_blend import scenes
from cvsss.sss_addon.blender.standalone import ensure_registered

ROOT = Path(__file__).resolve().parents[2]
CHECK_SCENE = ROOT / "docs" / "checks" / "flicker_point_light.py"


def build(name: str, path: Path, cube_scale: float | None = None) -> None:
    """The scene ``name`` (a demo scene, ``flicker``, ``cube`` or ``monkey``) in a fresh file, saved
    at ``path``; ``cube_scale`` sets the factory material's Subsurface Scale (m; Blender's
    0.05 if None) on ``cube`` and ``monkey``."""
    if name == "flicker":
        argv = sys.argv
        sys.argv = [str(CHECK_SCENE), str(path)]
        try:
            runpy.run_path(str(CHECK_SCENE), run_name="__main__")
        finally:
            sys.argv = argv
        return
    if name in ("cube", "monkey"):
        bpy.ops.wm.read_homefile(use_factory_startup=True)
        bpy.context.scene.render.engine = "CYCLES"
        principled = bpy.data.materials["Material"].node_tree.nodes["Principled BSDF"]
        principled.inputs["Subsurface Weight"].default_value = 1.0
        if name == "monkey":
            _monkey(principled)
        if cube_scale is not None:
            principled.inputs["Subsurface Scale"].default_value = cube_scale
        bpy.ops.wm.save_as_mainfile(filepath=str(path))
        return
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scenes.build(name, bpy.context.scene, frames=120)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def _monkey(principled) -> None:
    """Replace the factory cube by Suzanne as a user adds her (Add ▸ Mesh ▸ Monkey, size
    2 m, Subdivision Surface level 2, Shade Smooth) with the cube's material, its Base
    Color a skin tone."""
    cube = bpy.data.objects["Cube"]
    material = cube.active_material
    bpy.data.objects.remove(cube)
    bpy.ops.mesh.primitive_monkey_add(size=2.0)
    monkey = bpy.context.active_object
    monkey.data.materials.append(material)
    subdivision = monkey.modifiers.new("Subdivision", "SUBSURF")
    subdivision.levels = subdivision.render_levels = 2
    bpy.ops.object.shade_smooth()
    principled.inputs["Base Color"].default_value = (0.8, 0.5, 0.4, 1.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path)
    parser.add_argument("width", type=int)
    parser.add_argument("height", type=int)
    parser.add_argument("--scenes", default="flicker,cube,monkey," + ",".join(scenes.names()))
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--eevee-samples", type=int, default=16)
    parser.add_argument(
        "--cube-scale",
        type=float,
        help="the Subsurface Scale in m of cube's and monkey's material (Blender's 0.05 by "
        "default; the cube is 2 m across, 500 mean free paths of its Random Walk at 0.05, "
        "20 at 1.26)",
    )
    args = parser.parse_args()
    ensure_registered()
    args.out.mkdir(parents=True, exist_ok=True)
    for name in args.scenes.split(","):
        path = args.out / f"{name}.blend"
        build(name, path, args.cube_scale)
        bpy.ops.wm.open_mainfile(filepath=str(path))
        scene = bpy.context.scene
        scene.render.resolution_x, scene.render.resolution_y = args.width, args.height
        scene.render.resolution_percentage = 100
        scene.cycles.device = "CPU"
        scene.cycles.samples = args.samples
        scene.eevee.taa_render_samples = args.eevee_samples
        bpy.ops.wm.save_as_mainfile(filepath=str(path))
        print(f"saved {path}")


if __name__ == "__main__":
    main()

"""What Cycles' Christensen-Burley does at the foot of a slab standing on the floor.

The demo's marble tops are slabs standing on the floor. Their front face darkens
towards the floor in Cycles' ground truth, and Apply on Render's contact rule
(docs/explanation/design.md §5.6) models that darkening. This script renders one
frame of a file of ``users_frame_scenes.py`` with Cycles (``--samples`` per pixel,
no denoising, seed 0) with subsurface on and with it off (every Principled BSDF's
Subsurface Weight held at 0, ``materials.SSSDisabled``), for the slab as built and moved up or down by ``--shifts``
(metres), and prints per row of the slab's front face, counted up from the
floor, the mean of the frame with subsurface over the frame without it (linear,
the mean over the columns where the slab stands on the floor and the channels),
and the same ratio over the rest of the slab's pixels. A row's darkening is 1
minus that ratio. From the repository root::

    .venv/bin/python tools/measure/slab_foot.py out/u640/flash.blend --frame 21 \\
        --object "flash Marble Top" --samples 512 --shifts 0,0.002,-0.002

docs/explanation/accuracy.md §2.2 quotes it.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import bpy
import numpy as np
from denoise_context import exr_output

from cvsss.core.io.exr import read_pass, read_rgb
from cvsss.sss_addon.blender.materials import SSSDisabled

FLOOR = "Plane"


def render(scene, path: Path, index: bool = False) -> None:
    """Render the frame to a multilayer EXR at ``path`` (with the Object Index pass)."""
    scene.view_layers[0].use_pass_object_index = index
    exr_output(scene, path)
    bpy.ops.render.render(write_still=True)


def face_rows(index: np.ndarray, slab: int, floor: int, rows: int) -> list[np.ndarray]:
    """Per row up from the floor, (H, W) bool: the slab's pixels in the columns where
    the slab's lowest pixel stands on a floor pixel."""
    out = [np.zeros(index.shape, bool) for _ in range(rows)]
    height = index.shape[0]
    for x in range(index.shape[1]):
        ys = np.flatnonzero(index[:, x] == slab)
        if ys.size == 0 or ys.max() + 1 >= height or index[ys.max() + 1, x] != floor:
            continue
        for up in range(rows):
            y = ys.max() - up
            if y < 0 or index[y, x] != slab:
                break
            out[up][y, x] = True
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blend", type=Path)
    parser.add_argument("--frame", type=int, required=True)
    parser.add_argument("--object", required=True, help="the slab")
    parser.add_argument("--samples", type=int, default=512)
    parser.add_argument("--shifts", default="0", help="comma-separated z offsets, metres")
    parser.add_argument("--rows", type=int, default=16)
    args = parser.parse_args()
    bpy.ops.wm.open_mainfile(filepath=str(args.blend))
    scene = bpy.context.scene
    scene.frame_set(args.frame)
    slab = scene.objects[args.object]
    floor = next(o for o in scene.objects if o.name.endswith(FLOOR))
    for number, obj in enumerate(scene.objects, 1):
        obj.pass_index = number
    numbers = {obj.name: number for number, obj in enumerate(scene.objects, 1)}
    cycles = scene.cycles
    scene.render.engine = "CYCLES"
    cycles.samples = args.samples
    cycles.use_denoising = cycles.use_adaptive_sampling = False
    cycles.seed = 0
    cycles.use_animated_seed = False
    scene.render.use_compositing = False
    base = slab.location.z
    print(f"{args.blend} frame {args.frame}, {args.samples} spp: with / without subsurface")
    print("row up from the floor: " + " ".join(f"{r:6d}" for r in range(args.rows)))
    with tempfile.TemporaryDirectory() as folder:
        for shift in (float(s) for s in args.shifts.split(",")):
            slab.location.z = base + shift
            on, off = Path(folder) / "on.exr", Path(folder) / "off.exr"
            render(scene, on, index=True)
            with SSSDisabled(bpy.data.materials):
                render(scene, off)
            index = np.rint(read_pass(on, "Object Index")).astype(int)
            lit, dark = read_rgb(on)[..., :3].mean(-1), read_rgb(off)[..., :3].mean(-1)
            ratios = []
            rows = face_rows(index, numbers[slab.name], numbers[floor.name], args.rows)
            for mask in rows:
                ratios.append(lit[mask].mean() / dark[mask].mean() if mask.any() else np.nan)
            rest = (index == numbers[slab.name]) & ~np.any(rows, axis=0)
            print(f"slab {shift * 1000:+5.1f} mm:        " + " ".join(f"{v:6.3f}" for v in ratios)
                  + f"   rest of the slab {lit[rest].mean() / dark[rest].mean():.3f}")  # fmt: skip
    slab.location.z = base
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

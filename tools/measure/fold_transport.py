"""The light a slab's face takes round a convex edge from its lit top: Cycles, the post, the kernel.

A slab floating in a black world (no floor, no other object), d = 1 cm
Christensen-Burley, lit by a sun from above and behind (``--light back``: the
front face unlit, all its light comes round the edge) or from above and in front
(``front``), seen from 20° above at 320×180, so that the 4 cm face spans 12 rows
and each row of the top about 1 cm in depth. Three subcommands:

- ``scene OUT.blend --light back|front`` builds the file (1024-spp passes);
- ``rows RUN POST`` prints, for the rows round the edge (a band of columns in the
  middle of the slab), the light of each row as a share of the top's light without
  subsurface, for the post's frame without subsurface (``POST/none``), Cycles' ground
  truth (``RUN/ground_truth``) and the post's converged estimate
  (``POST/reference``; more folders with ``--also``);
- ``kernel`` integrates Cycles' disk kernel (``core.mc.estimator``, *Cycles'
  kernel*: the Burley profile at the distance times ``G = |Δ|·Σ_a m_a/ρ_a``) over an
  ideal edge, continuous geometry: the top's share of a face point's light at each
  height below the edge, with the top from the edge on and from ``--from-mm`` on.

From the repository root (about 3 minutes per light on two cores)::

    .venv/bin/python tools/measure/fold_transport.py scene out/fold/back.blend --light back
    .venv/bin/cvsss render out/fold/back.blend --frames 1 --out out/fold/run_back \\
        --method none --passes-only --ground-truth --ground-truth-spp 4096
    .venv/bin/cvsss post out/fold/run_back/passes --method none,reference \\
        --reference-spp 1024 --out out/fold/post_back --no-denoise
    .venv/bin/python tools/measure/fold_transport.py rows out/fold/run_back out/fold/post_back
    .venv/bin/python tools/measure/fold_transport.py kernel --from-mm 4.4

``cvsss render ... --thin-walks post`` renders the passes without the edge's rim
band (whose points keep their subsurface in the pass render); link the first
run's ``ground_truth`` into that run's folder to score it.

docs/explanation/accuracy.md (§2.2, *The light round a convex edge*) quotes
them: the kernel's integral follows Cycles' rows, the post's rows fall short
near the edge, and the shortfall is the strip of the top next to the edge that
the pixel straddling it does not hold.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

#: The scene's scattering length (Burley d, all channels), slab height and geometry.
D = 0.01
HEIGHT = 0.04
ELEVATION = 20.0
DISTANCE = 1.48


def build(out: Path, light: str) -> None:
    """Write the floating slab's .blend (Cycles, 1024 spp, no denoising)."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1024
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.seed = 3
    scene.render.resolution_x, scene.render.resolution_y = 320, 180
    scene.render.resolution_percentage = 100
    scene.frame_start = scene.frame_end = 1
    scene.view_settings.view_transform = "Standard"
    world = bpy.data.worlds.new("black")  # Blender 5 gives new worlds and materials nodes
    scene.world = world
    world.color = (0.0, 0.0, 0.0)
    if world.node_tree is not None and "Background" in world.node_tree.nodes:
        world.node_tree.nodes["Background"].inputs[1].default_value = 0.0
    material = bpy.data.materials.new("slab")
    bsdf = material.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    bsdf.inputs["Roughness"].default_value = 0.5
    bsdf.inputs["Subsurface Weight"].default_value = 1.0
    bsdf.inputs["Subsurface Radius"].default_value = (1.0, 1.0, 1.0)
    bsdf.inputs["Subsurface Scale"].default_value = D * math.pi / 0.25  # d = radius·scale·0.25/π
    bsdf.subsurface_method = "BURLEY"
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(0.0, 0.0, 0.1 + HEIGHT / 2))
    slab = bpy.context.object
    slab.scale = (0.5, 0.3, HEIGHT)
    bpy.ops.object.transform_apply(scale=True)
    slab.data.materials.append(material)
    sun = bpy.data.objects.new("sun", bpy.data.lights.new("sun", "SUN"))
    sun.data.energy = 3.0
    sun.data.angle = math.radians(1.0)
    # A sun points along its −Z: tilted back it lights the top and not the front face.
    sun.rotation_euler = (math.radians(-30.0 if light == "back" else 30.0), 0.0, math.radians(15.0))
    scene.collection.objects.link(sun)
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.data.lens = 50.0
    tilt = math.radians(ELEVATION)
    face_centre_y, face_centre_z = -0.15, 0.1 + HEIGHT / 2
    camera.location = (
        0.0,
        face_centre_y - DISTANCE * math.cos(tilt),
        face_centre_z + DISTANCE * math.sin(tilt),
    )
    camera.rotation_euler = (math.radians(90.0) - tilt, 0.0, 0.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    out.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(out.resolve()))
    print(f"saved {out}")


def rows(run: Path, post: Path, also: list[Path], columns: slice, top_rows: slice) -> None:
    """Print each row's light as a share of the top's light without subsurface."""
    from cvsss.core.color import luminance
    from cvsss.core.io.exr import read_result, read_rgb

    def result(folder: Path) -> np.ndarray:
        return luminance(read_result(folder / "0001.exr")["Composite"])

    none = result(post / "none")
    truth = luminance(read_rgb(run / "ground_truth" / "0001.exr")[..., :3])
    estimates = [result(post / "reference")] + [result(p) for p in also]
    top = none[top_rows, columns].mean()
    on_slab = np.flatnonzero((truth[:, columns] > 1e-3 * top).all(axis=1))
    names = ["post"] + [p.parent.name + "/" + p.name for p in also]
    print(f"share of the top's light without subsurface ({top:.4f}), columns {columns.start}-"
          f"{columns.stop - 1}")  # fmt: skip
    print(f"{'row':>4s} {'without':>8s} {'Cycles':>7s} " + " ".join(f"{n:>10s}" for n in names))
    for y in range(on_slab[0], on_slab[-1] + 1):
        values = [e[y, columns].mean() / top for e in estimates]
        print(
            f"{y:4d} {none[y, columns].mean() / top:8.3f} {truth[y, columns].mean() / top:7.3f} "
            + " ".join(f"{v:10.3f}" for v in values)
        )


def _kernel(delta: np.ndarray, normal_q: np.ndarray) -> np.ndarray:
    """Cycles' disk kernel per unit area at offsets ``delta`` (..., 3) from a point of the
    face (normal −y, Cycles' make_orthonormals frame), landing normals ``normal_q`` (3,)."""
    from cvsss.core.mc.samples import disk_frame

    frame = disk_frame(np.array([[0.0, -1.0, 0.0]]))[0].astype(np.float64)
    axes = ((frame[0:3], 0.5), (frame[3:6], 0.25), (frame[6:9], 0.25))
    length = np.linalg.norm(delta, axis=-1)
    pdfs = [pick * abs(float(normal_q @ a)) for a, pick in axes]
    total = sum(p * p for p in pdfs)
    gain = 0.0
    for (a, _), p in zip(axes, pdfs, strict=True):
        rho = np.sqrt(np.maximum(length**2 - (delta @ a) ** 2, 1e-16))
        gain = gain + (p * p / total) / rho
    radial = (np.exp(-length / D) + np.exp(-length / (3 * D))) / (4 * D) * (length < 16 * D)
    return radial / (2 * np.pi) * gain


def top_share(h: float, start: float = 0.0, n: int = 1200) -> float:
    """∫ over the top (from ``start`` behind the edge) of the kernel at a face point ``h``
    below the edge: the share of a uniformly lit top's light the point receives."""
    reach = 16 * D
    xs = ((np.arange(n) + 0.5) / n * 2 - 1) * reach
    ts = start + (np.arange(n) + 0.5) / n * (reach - start)
    x, t = np.meshgrid(xs, ts)
    delta = np.stack([x, t, np.full_like(x, h)], axis=-1)
    cell = (2 * reach / n) * ((reach - start) / n)
    return float(_kernel(delta, np.array([0.0, 0.0, 1.0])).sum() * cell)


def kernel(edge_row: float, row_mm: float, first: int, last: int, start_mm: float) -> None:
    print(f"top's share of a face point's light, Cycles' kernel, d = {D * 1000:.0f} mm, "
          f"edge at row {edge_row}, {row_mm} mm per face row")  # fmt: skip
    print(f"{'row':>4s} {'h (mm)':>7s} {'whole top':>10s} {f'from {start_mm} mm':>13s}")
    for row in range(first, last + 1):
        h = (row - edge_row) * row_mm / 1000
        whole, part = top_share(h), top_share(h, start_mm / 1000)
        print(f"{row:4d} {h * 1000:7.1f} {whole:10.3f} {part:13.3f}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    scene = sub.add_parser("scene", help="build the floating slab's .blend")
    scene.add_argument("out", type=Path)
    scene.add_argument("--light", choices=("back", "front"), default="back")
    shares = sub.add_parser("rows", help="the rows round the edge: Cycles against the post")
    shares.add_argument("run", type=Path, help="the cvsss render --out folder (ground_truth/)")
    shares.add_argument("post", type=Path, help="the cvsss post --out folder (none/, reference/)")
    shares.add_argument("--also", type=Path, action="append", default=[], help="a method folder")
    ideal = sub.add_parser("kernel", help="the kernel integrated over an ideal edge")
    ideal.add_argument("--edge-row", type=float, default=83.95, help="the edge's image row")
    ideal.add_argument("--row-mm", type=float, default=3.29, help="mm of the face per row")
    ideal.add_argument("--rows", default="85-95", help="face rows A-B")
    ideal.add_argument("--from-mm", type=float, default=4.4, help="the top from this depth on")
    args = parser.parse_args()
    if args.command == "scene":
        build(args.out, args.light)
    elif args.command == "rows":
        rows(args.run, args.post, args.also, slice(120, 200), slice(75, 80))
    else:
        first, last = (int(v) for v in args.rows.split("-"))
        kernel(args.edge_row, args.row_mm, first, last, args.from_mm)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The fit judged where it is used: a small perspective scene, post-processed, against Cycles.

Two subsurface spheres (a pale and a dark material) on a grey plane, lit by a
point light, 128x72. Three steps::

    # 1. the scene (bpy), its materials' inputs beside it (scene.blend.json)
    python tools/random_walk/real_case.py scene OUT/scene.blend --method RANDOM_WALK
    # 2. passes and a ground truth through the command line (the Random Walk one here)
    cvsss render OUT/scene.blend --frames 1 --out OUT/run --method as_ccv --reference \
        --ground-truth --ground-truth-method random_walk --ground-truth-spp 1024
    #    or a ground truth of the scene as it is (any method, Skin included):
    python tools/random_walk/real_case.py truth OUT/scene.blend OUT/truth.exr --spp 1024
    # 3. post-process the passes with each material's Burley d (what the post does
    #    today) and with the random-walk model, and measure both against the truth
    python tools/random_walk/real_case.py compare OUT/run/passes OUT/truth.exr \
        --materials OUT/scene.blend.json

The product (the method and inputs of each material in the pass sidecar, the
model applied by the post, the ground truth with each material's own method)
is measured with ``product``, on the run folder of ``cvsss render`` (step 2
with the default ``--ground-truth-method material``)::

    python tools/random_walk/real_case.py product OUT/run
    # the flash demo scene with its subsurface materials switched to a random walk:
    python tools/random_walk/real_case.py demo OUT/flash.blend --method RANDOM_WALK

It prints the display-space PSNR (whole frame / subsurface pixels) of each
method's result EXR (``integrated``) and of the same passes post-processed with
every material taken as BURLEY at its Blender d (``burley``: the post before
the model was integrated).

Step 3 goes through the core's own processors and composite; the model's d
replaces the sidecar's d of each material, and its energy factor e scales the
scattered light: ``F = Combined − A·B + e·A·L`` (subsurface weight 1). Rows:
``burley`` (the material's own d, e = 1: the post today), ``d_only`` (fitted
d, e = 1), ``fitted_normal_view`` (fitted d and e, e as seen along the normal),
``fitted_view`` (e per pixel with the view angle of the depth-buffer normal)
and ``fitted`` (also with the depth buffer's mean curvature).
Figures are the display-space PSNR of cvsss.core.eval.metrics.psnr_gt over the
whole frame and over the post's subsurface pixels.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import numpy as np

#: name -> (Base Color, Subsurface Radius, location x) of the spheres.
SPHERES = {
    "rw_pale": ((0.8, 0.55, 0.45), (1.0, 0.2, 0.1), -0.5),
    "rw_dark": ((0.35, 0.12, 0.06), (1.0, 0.5, 0.25), 0.5),
}
SCALE = 1.0  # Subsurface Scale: d_R = 8 cm, about 4 pixels at the spheres
SPHERE_RADIUS = 0.42


def build_scene(
    path: Path,
    method: str,
    samples: int = 16,
    scale: float = SCALE,
    size: tuple[int, int] = (128, 72),
    lens: float = 50.0,
) -> dict:
    import bpy
    from mathutils import Vector

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    world = bpy.data.worlds.new("dim")
    world.use_nodes = True  # still needed in 5.0 for a new world's node tree
    world.node_tree.nodes["Background"].inputs["Color"].default_value = (0.05, 0.05, 0.05, 1)
    scene.world = world

    inputs = {}
    for name, (color, radius, x) in SPHERES.items():
        mat = bpy.data.materials.new(name)
        mat.use_nodes = True
        node = mat.node_tree.nodes["Principled BSDF"]
        node.subsurface_method = method
        node.inputs["Base Color"].default_value = (*color, 1.0)
        node.inputs["Subsurface Weight"].default_value = 1.0
        node.inputs["Subsurface Radius"].default_value = radius
        node.inputs["Subsurface Scale"].default_value = scale
        bpy.ops.mesh.primitive_uv_sphere_add(
            radius=SPHERE_RADIUS, location=(x, 0, SPHERE_RADIUS), segments=96, ring_count=48
        )
        bpy.ops.object.shade_smooth()
        bpy.context.object.data.materials.append(mat)
        sock = {s.identifier: s for s in node.inputs}
        inputs[name] = {
            "albedo": list(color),
            "radius": list(radius),
            "scale": scale,
            "method": method,
            "ior": sock["IOR"].default_value,
            "roughness": sock["Roughness"].default_value,
            "subsurface_ior": sock["Subsurface IOR"].default_value,
            "anisotropy": sock["Subsurface Anisotropy"].default_value,
        }
    grey = bpy.data.materials.new("floor")
    grey.use_nodes = True
    grey.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.5, 0.5, 0.5, 1)
    bpy.ops.mesh.primitive_plane_add(size=8.0)
    bpy.context.object.data.materials.append(grey)

    light = bpy.data.lights.new("key", "POINT")
    light.energy = 250.0
    light.shadow_soft_size = 0.05
    key = bpy.data.objects.new("key", light)
    key.location = (-1.2, -1.6, 2.4)
    scene.collection.objects.link(key)

    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    cam.location = (0.0, -3.0, 1.2)
    cam.rotation_euler = (
        (Vector((0, 0, SPHERE_RADIUS)) - cam.location).to_track_quat("-Z", "Y").to_euler()
    )
    scene.collection.objects.link(cam)
    scene.camera = cam

    r = scene.render
    r.engine = "CYCLES"
    cam.data.lens = lens
    r.resolution_x, r.resolution_y, r.resolution_percentage = *size, 100
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_denoising = False
    scene.frame_start = scene.frame_end = 1
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    Path(f"{path}.json").write_text(json.dumps(inputs, indent=1) + "\n")
    return inputs


def render_truth(blend: Path, out: Path, spp: int) -> None:
    """Cycles with the scene's own subsurface, as the command line's ground truth renders it."""
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    c = scene.cycles
    c.samples = spp
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.seed = 0
    c.time_limit = 0.0
    scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(out)
    scene.frame_set(1)
    bpy.ops.render.render(write_still=True)


def view_and_curvature(frame) -> tuple[np.ndarray, np.ndarray]:
    """(H, W) |cos| of the angle between each pixel's view ray and its depth-buffer
    normal, and (H, W) the mean curvature of the depth buffer (1/scene unit)."""
    from cvsss.core.geometry import positions, surface
    from cvsss.core.profiles.random_walk import mean_curvature

    normal = surface(frame).normal.reshape((*frame.shape, 3)).astype(np.float64)
    points = positions(frame.camera, frame.depth, frame.origin)
    with np.errstate(invalid="ignore"):
        ray = points / np.linalg.norm(points, axis=-1, keepdims=True)
        mu = np.abs(np.sum(normal * ray, axis=-1))
    labels = frame.material if frame.objects is None else frame.objects
    curvature = mean_curvature(points, normal, labels)
    return np.where(np.isfinite(mu), mu, 1.0), curvature


def compare(passes: Path, truth: Path, materials: dict, methods: list[str]) -> list[dict]:
    from cvsss.core import SSSParams, make_processor
    from cvsss.core.eval.metrics import channel_ratio, psnr_gt
    from cvsss.core.io.exr import list_frames, read_combined, read_frame
    from cvsss.core.profiles import random_walk

    number, path = list_frames(passes)[0]
    frame = read_frame(path, number)
    gt = read_combined(truth)
    mu, curvature = view_and_curvature(frame)
    rows = []
    for model in ("burley", "d_only", "fitted_normal_view", "fitted_view", "fitted"):
        specs, gain = {}, np.ones((*frame.material.shape, 3))
        for slot, spec in frame.materials.items():
            m = materials.get(spec.name)
            if model == "burley" or m is None:
                specs[slot] = spec
                continue
            d, e = random_walk.shape(
                m["radius"],
                m["scale"],
                m["albedo"],
                m["method"],
                m["subsurface_ior"],
                m["anisotropy"],
            )
            specs[slot] = dataclasses.replace(spec, d=tuple(d.tolist()))
            sel = frame.material == slot
            if model == "fitted_normal_view":
                gain[sel] = e
            elif model == "fitted_view":
                gain[sel] = e * random_walk.view_factor(m["albedo"], mu[sel], m["method"])
            elif model == "fitted":
                ell = random_walk.mean_free_path(
                    m["radius"], m["scale"], m["albedo"], m["method"], m["subsurface_ior"]
                )
                gain[sel] = (
                    e
                    * random_walk.view_factor(m["albedo"], mu[sel], m["method"])
                    * random_walk.curvature_factor(
                        m["albedo"], curvature[sel][:, None] * ell, m["method"]
                    )
                )
        fr = dataclasses.replace(frame, materials=specs)
        for method in methods:
            res = make_processor(method, SSSParams()).process(fr)
            out = res.composite.astype(np.float64)
            # e on the scattered light: F = Combined − A·B + e·A·L (weight 1).
            out += (gain - 1.0) * frame.albedo * res.sss * res.mask[..., None]
            rows.append(
                {
                    "model": model,
                    "method": method,
                    "psnr_full_db": round(psnr_gt(out, gt), 2),
                    "psnr_sss_db": round(psnr_gt(out, gt, res.mask), 2),
                    "ratio_sss": [round(float(v), 4) for v in channel_ratio(out, gt, res.mask)],
                    "d": {spec.name: [round(v, 5) for v in spec.d] for spec in specs.values()},
                }
            )
    return rows


def build_demo(path: Path, method: str, size: tuple[int, int], samples: int) -> None:
    """The flash demo scene (frame 1 only), every subsurface Principled BSDF set to ``method``."""
    import bpy

    from cvsss.demo_blend import scenes
    from cvsss.sss_addon.blender import materials, standalone

    standalone.ensure_registered()
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scenes.build("flash", scene, frames=1)
    scene.render.resolution_x, scene.render.resolution_y = size
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    for material in materials.participating(scene):
        for _, node in materials.principled_nodes(material.node_tree):
            node.subsurface_method = method
    path.parent.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(path))


def product_rows(run: Path) -> list[dict]:
    """PSNR of a ``cvsss render`` run's results and of the Burley post on its passes."""
    from cvsss.core import SSSParams, make_processor
    from cvsss.core.eval.metrics import psnr_gt
    from cvsss.core.io.exr import list_frames, read_combined, read_frame, read_result

    rows = []
    for number, path in list_frames(run / "passes"):
        truth = run / "ground_truth" / f"{number:04d}.exr"
        if not truth.is_file():
            continue
        gt = read_combined(truth)
        frame = read_frame(path, number)
        burley = dataclasses.replace(
            frame,
            materials={
                s: dataclasses.replace(spec, method="BURLEY") for s, spec in frame.materials.items()
            },
        )
        for method_dir in sorted(p for p in run.iterdir() if (p / path.name).is_file()):
            if method_dir.name in ("passes", "ground_truth"):
                continue
            result = read_result(method_dir / path.name)
            mask = result["Mask"] > 0.5
            old = make_processor(method_dir.name, SSSParams()).process(burley)
            for model, image in (("burley", old.composite), ("integrated", result["Composite"])):
                rows.append(
                    {
                        "frame": number,
                        "method": method_dir.name,
                        "model": model,
                        "psnr_full_db": round(psnr_gt(image, gt), 2),
                        "psnr_sss_db": round(psnr_gt(image, gt, mask), 2),
                    }
                )
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s = sub.add_parser("scene")
    s.add_argument("blend", type=Path)
    s.add_argument(
        "--method", default="RANDOM_WALK", choices=("BURLEY", "RANDOM_WALK", "RANDOM_WALK_SKIN")
    )
    s.add_argument("--samples", type=int, default=16, help="samples of the passes")
    s.add_argument("--scale", type=float, default=SCALE, help="Subsurface Scale")
    s.add_argument("--size", type=int, nargs=2, default=(128, 72), help="resolution")
    s.add_argument("--lens", type=float, default=50.0, help="focal length, mm")
    t = sub.add_parser("truth")
    t.add_argument("blend", type=Path)
    t.add_argument("out", type=Path)
    t.add_argument("--spp", type=int, default=1024)
    c = sub.add_parser("compare")
    c.add_argument("passes", type=Path)
    c.add_argument("truth", type=Path)
    c.add_argument("--materials", type=Path, required=True)
    c.add_argument("--method", default="reference,as_ccv")
    d = sub.add_parser("demo")
    d.add_argument("blend", type=Path)
    d.add_argument("--method", default="RANDOM_WALK", choices=("RANDOM_WALK", "RANDOM_WALK_SKIN"))
    d.add_argument("--size", type=int, nargs=2, default=(320, 180), help="resolution")
    d.add_argument("--samples", type=int, default=16, help="samples of the passes")
    r = sub.add_parser("product")
    r.add_argument("run", type=Path, help="output folder of cvsss render --ground-truth")
    args = ap.parse_args(argv)
    if args.cmd == "scene":
        build_scene(args.blend, args.method, args.samples, args.scale, tuple(args.size), args.lens)
    elif args.cmd == "truth":
        render_truth(args.blend, args.out, args.spp)
    elif args.cmd == "demo":
        build_demo(args.blend, args.method, tuple(args.size), args.samples)
    elif args.cmd == "product":
        for row in product_rows(args.run):
            print(json.dumps(row))
    else:
        mats = json.loads(args.materials.read_text())
        for row in compare(args.passes, args.truth, mats, args.method.split(",")):
            print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())

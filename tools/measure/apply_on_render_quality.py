"""How close Apply on Render's frame comes to Cycles' own, and what the denoise and the
warm-up buy (issue 44).

On the measurement scene (``scene.py``: Random Walk skin sphere, Cycles
defaults) at ``--spp``, against a Cycles ground truth (1024 spp, denoise
off, fixed seed; cached in OUT), PSNR over the whole frame and over the
subsurface pixels (where the ground truths with and without subsurface
differ by more than 1 % of the peak), with the display rule of
``core.eval.metrics.psnr_gt``:

====  =====================================================================
a     the plain render: Cycles with its subsurface and its denoiser
b     Apply on Render, the scene's denoiser off: the finished frame F
c     Apply on Render, the scene's denoiser on: F denoised (what it does)
d     Apply on Render, denoiser off, *Denoise Passes* on: F of denoised passes
====  =====================================================================

each an F12 still through ``bpy.ops.render.render`` (32-bit EXR output).
Then the warm-up: F (not denoised) of ``--methods`` with no warm-up and with
8 warm-up frames. The scene is still and Cycles' seed fixed, so each warm-up
frame's passes are the frame's own: one pass file is fed 9 times. From the
repository root::

    python tools/measure/apply_on_render_quality.py OUT --spp 16
    python tools/measure/apply_on_render_quality.py OUT --spp 64

(``python`` with ``bpy`` 5.0 and the ``cvsss`` package importable.)
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import bpy
import numpy as np
import OpenEXR

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scene import build_scene, exr_output

import cvsss
from cvsss.core.eval.metrics import psnr_gt
from cvsss.core.io.exr import read_frame
from cvsss.core.run import FrameStream, RunSpec
from cvsss.sss_addon.blender import render

GT_SPP = 1024
GT_SEED = 17


def read_rgb(path: Path, prefix: str = "") -> np.ndarray:
    """(H, W, 3) float64 linear RGB of an EXR (``prefix`` e.g. ``ViewLayer.Combined.``)."""
    exr = OpenEXR.File(str(path), separate_channels=True)
    channels = {k: np.asarray(c.pixels) for p in exr.parts for k, c in p.channels.items()}
    return np.stack([channels[prefix + c] for c in "RGB"], -1).astype(np.float64)


def ground_truth(scene, out: Path, weight: float, name: str) -> np.ndarray:
    """Cycles at 1024 spp, denoise off, with the skin's Subsurface Weight ``weight``
    (cached in ``out``)."""
    w, h = scene.render.resolution_x, scene.render.resolution_y
    path = out / f"gt_{name}_{w}x{h}.exr"
    if not path.is_file():
        bsdf = bpy.data.materials["skin"].node_tree.nodes["Principled BSDF"]
        c = scene.cycles
        kept = c.samples, c.use_denoising, c.seed, bsdf.inputs["Subsurface Weight"].default_value
        c.samples, c.use_denoising, c.seed = GT_SPP, False, GT_SEED
        bsdf.inputs["Subsurface Weight"].default_value = weight
        exr_output(scene, out / f"gt_{name}_{w}x{h}")
        began = time.perf_counter()
        bpy.ops.render.render(write_still=True)
        print(f"ground truth {name}: {time.perf_counter() - began:.1f} s", flush=True)
        c.samples, c.use_denoising, c.seed = kept[:3]
        bsdf.inputs["Subsurface Weight"].default_value = kept[3]
    return read_rgb(path)


def still(scene, path: Path, apply: bool, denoise: bool, denoise_passes: bool = False):
    """One F12 still written to ``path``.exr: (H, W, 3) linear RGB and seconds."""
    scene.sss_settings.apply_on_render = apply
    scene.sss_settings.use_denoise_passes = denoise_passes
    scene.cycles.use_denoising = denoise
    exr_output(scene, path)
    began = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    seconds = time.perf_counter() - began
    return read_rgb(path.with_suffix(".exr")), seconds


def warm_up_rows(scene, out: Path, methods: list[str]) -> dict[str, np.ndarray]:
    """F of each method after 0 and after 8 warm-up frames (the frame's own passes)."""
    scene.cycles.use_denoising = False
    job = render.job_from_scene(
        scene,
        frames=(1, 1),
        out=out / "warm-up",
        methods=methods,
        overwrite=True,
        reference=False,
        ground_truth=False,
        denoise_passes=False,
    )
    (step,) = render.iter_passes(job)
    images = {}
    for method in methods:
        for warmup in (0, 8):
            stream = FrameStream(RunSpec((method,), job.params, job.options))
            for number in range(1, warmup + 1):
                stream.warm_up(read_frame(step.path, number=number))
            frame = read_frame(step.path, number=warmup + 1)
            images[f"{method}, warm-up {warmup}"] = stream.step(frame)[method].composite
    return images


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("out", type=Path, help="folder for the ground truth and the renders")
    parser.add_argument("--size", default="128x72", help="WxH pixels (default 128x72)")
    parser.add_argument("--spp", type=int, default=16, help="Cycles samples (default 16)")
    parser.add_argument("--method", default="as_ccv", help="Apply on Render's method")
    parser.add_argument(
        "--methods",
        default="as_ccv,as_ocv,as_ccv_t,as_ocv_t",
        help="methods of the warm-up rows (default as_ccv,as_ocv,as_ccv_t,as_ocv_t)",
    )
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    out = args.out.resolve()
    out.mkdir(parents=True, exist_ok=True)
    scene = build_scene(width, height, args.spp)
    cvsss.register()
    scene.sss_settings.method = args.method
    scene.sss_settings.warmup_frames = 0  # the warm-up's effect is measured on its own below
    gt = ground_truth(scene, out, 1.0, "sss")
    peak = np.percentile(gt.max(-1), 99)
    mask = np.abs(gt - ground_truth(scene, out, 0.0, "nosss")).max(-1) > 0.01 * peak
    tag = f"{width}x{height}_{args.spp}"
    rows = {
        "a  Cycles + its denoiser": still(scene, out / f"a_{tag}", False, True),
        "b  F, not denoised": still(scene, out / f"b_{tag}", True, False),
        "c  F denoised as the scene asks": still(scene, out / f"c_{tag}", True, True),
        "d  F of denoised passes": still(scene, out / f"d_{tag}", True, False, True),
    }
    print(
        f"\n{width}x{height}, {args.spp} spp, {args.method}; subsurface pixels {int(mask.sum())} "
        f"of {mask.size}; PSNR against Cycles at {GT_SPP} spp"
    )
    print(f"{'':36} {'whole':>8} {'subsurface':>11} {'seconds':>8}")
    record = {}
    for name, (image, seconds) in rows.items():
        whole, sss = psnr_gt(image, gt), psnr_gt(image, gt, mask)
        record[name] = {"whole_db": whole, "sss_db": sss, "seconds": seconds}
        print(f"{name:36} {whole:8.2f} {sss:11.2f} {seconds:8.2f}")
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    print(f"\nwarm-up (F not denoised; {', '.join(methods)}):")
    for name, image in warm_up_rows(scene, out, methods).items():
        whole, sss = psnr_gt(image, gt), psnr_gt(image, gt, mask)
        record[name] = {"whole_db": whole, "sss_db": sss}
        print(f"{name:36} {whole:8.2f} {sss:11.2f}")
    (out / f"quality_{tag}.json").write_text(json.dumps(record, indent=1))


if __name__ == "__main__":
    main()

"""How the denoiser treats the parts left to Cycles, beside the post-process's smooth ones.

Apply on Render denoises its finished frame F once (``denoise_frame``), as the
scene's denoiser would its own render. F holds two kinds of pixels: the
post-process's subsurface pixels, whose light is a smooth estimate, and every
other pixel as the pass render made it (Cycles' own subsurface on the parts
left to it, the floor, the background), as noisy as in the plain render.
OpenImageDenoise takes its cue for how hard to denoise from the whole image,
so a frame made mostly of smooth pixels gets the noisy ones denoised less.

For one frame of a file at ``--samples`` this renders the plain frame (Cycles
with its denoiser: the denoised and the noisy image and its guides), Cycles'
ground truth (``--truth-spp``, denoising off, seed 0) and Apply on Render's F
(``cvsss render --method as_ccv``: F, the finished frame before its denoise, is
made again from the pass file and the post's light, ``core.result.relit``), then denoises F with the
scene's settings in four ways and prints, per object, the squared display
error (×1000, the figures' exposure and display rule) summed over its pixels
outside the post's mask:

- ``plain``: the plain render, as Cycles denoised it;
- ``F``: F denoised, what Apply on Render delivers (from 64 spp the pixels off
  the post's mask from a second denoise beside stand-in noise,
  ``FrameDenoiser.beside_stand_in``);
- ``F, once``: F denoised once, as it is;
- ``F, post ← plain noisy``: F with the post's pixels replaced by the plain
  render's noisy ones;
- ``F, post + plain's noise``: the post's pixels keep their light and take the
  plain render's noise (its noisy image minus the ground truth);
- ``F, post + pass noise``: the post's pixels take the pass render's own noise
  instead (its Combined, whose subsurface parts are diffuse, minus that
  Combined denoised), which Apply on Render could add;
- ``F, post ← truth``: the post's pixels replaced by the ground truth (no noise).

From the repository root, on a file of ``users_frame_scenes.py``::

    .venv/bin/python tools/measure/denoise_context.py out/users/boids.blend OUT \\
        --frame 21 --samples 64
"""

from __future__ import annotations

import argparse
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
from contact_bands import object_index

from cvsss.core.eval.users_frame import display, frame_exposure
from cvsss.core.io.exr import read_channels, read_frame, read_result
from cvsss.core.result import relit
from cvsss.sss_addon.blender.denoise_frame import FrameDenoiser, cycles_denoise, read_guides
from cvsss.sss_addon.blender.passes import render_view_layer
from cvsss.sss_addon.blender.standalone import ensure_registered
from cvsss.sss_addon.blender.users_frame import TruthSetup


def layer(path: Path, layer_name: str, name: str) -> np.ndarray:
    """(H, W, 3) float32 RGB of the pass ``name`` of view layer ``layer_name`` in a
    multilayer EXR (``core.io.exr.read_channels``)."""
    channels = read_channels(path)
    return np.stack([channels[f"{layer_name}.{name}.{c}"] for c in "RGB"], -1)


def exr_output(scene, path: Path) -> None:
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"
    scene.render.use_compositing = False
    scene.render.filepath = str(path)


def render(blend: Path, out: Path, frame: int, samples: int, truth_spp: int):
    """The scene at ``samples`` saved as OUT/scene.blend; OUT/plain.exr (denoised, with
    its noisy image and guides) and OUT/truth.exr; the denoiser's settings and the
    view layer's name."""
    ensure_registered()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    scene.cycles.samples = samples
    out.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.save_as_mainfile(filepath=str(out / "scene.blend"), copy=True)
    settings = cycles_denoise(scene)
    view_layer = render_view_layer(scene)
    scene.frame_set(frame)
    scene.cycles.use_denoising = True
    view_layer.cycles.denoising_store_passes = True
    exr_output(scene, out / "plain.exr")
    bpy.ops.render.render(write_still=True)
    with TruthSetup(scene, view_layer, truth_spp):
        exr_output(scene, out / "truth.exr")
        bpy.ops.render.render(write_still=True)
    return settings, view_layer.name


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blend", type=Path)
    parser.add_argument("out", type=Path)
    parser.add_argument("--frame", type=int, required=True)
    parser.add_argument("--samples", type=int, default=64, help="Cycles' samples per pixel")
    parser.add_argument("--truth-spp", type=int, default=1024)
    args = parser.parse_args()
    settings, layer_name = render(args.blend, args.out, args.frame, args.samples, args.truth_spp)
    post = args.out / "post"
    subprocess.run(
        [sys.executable, "-m", "cvsss.sss_addon.cli.main", "render", str(args.out / "scene.blend"),
         "--frames", str(args.frame), "--out", str(post), "--method", "as_ccv", "--denoise",
         "--no-ground-truth", "--no-reference", "--quiet"],
        check=True,
    )  # fmt: skip
    index, names = object_index(args.out / "scene.blend", args.frame)
    name = f"{args.frame:04d}.exr"
    result = read_result(post / "as_ccv" / name)
    mask = result["Mask"] > 0
    frame = read_frame(post / "passes" / name)
    finished = relit(frame, mask, result["SSS"][..., :3])
    delivered = result["Composite"][..., :3]
    albedo, normal = read_guides(post / "passes" / name, layer_name)
    plain = layer(args.out / "plain.exr", layer_name, "Combined")
    noisy = layer(args.out / "plain.exr", layer_name, "Noisy Image")
    truth = layer(args.out / "truth.exr", layer_name, "Combined")
    inside = np.repeat(mask[..., None], 3, -1)
    inputs = {
        "F": finished,
        "F, post ← plain noisy": np.where(inside, noisy, finished),
        "F, post + plain's noise": np.where(inside, finished + (noisy - truth), finished),
        "F, post ← truth": np.where(inside, truth, finished),
    }
    frames = {"plain": plain}

    def rgba(image: np.ndarray) -> np.ndarray:
        out = np.ones((*image.shape[:2], 4), np.float32)
        out[..., :3] = image
        return out

    with FrameDenoiser(settings) as denoiser:
        combined = np.asarray(frame.combined, np.float32)
        pass_noise = combined - denoiser(rgba(combined), albedo, normal)[..., :3]
        inputs["F, post + pass noise"] = np.where(inside, finished + pass_noise, finished)
        for label in ("F", "F, post ← plain noisy", "F, post + plain's noise",
                      "F, post + pass noise", "F, post ← truth"):  # fmt: skip
            frames[label] = denoiser(rgba(inputs[label]), albedo, normal)[..., :3]
        # The last run had the same guides: the second denoise of what Apply on Render
        # delivers goes on from F's first (FrameDenoiser.finished, step by step).
        frames["F, once"] = frames["F"]
        frames["F"] = denoiser.beside_stand_in(frames["F"], rgba(finished), mask, albedo, normal)[
            ..., :3
        ]
    k = frame_exposure(truth)
    shown = display(truth, k)
    errors = {label: ((display(image, k) - shown) ** 2).mean(-1) for label, image in frames.items()}
    check = float(np.abs(frames["F"] - delivered).max())
    print(
        f"{args.blend.name} frame {args.frame}, {args.samples} spp, {settings.describe()}; "
        f"F denoised here against the frame cvsss render delivered: max |difference| {check:.2g}"
    )
    print("squared display error ×1000 outside the post's mask")
    print(f"{'object':22s} {'pixels':>6s}" + "".join(f" {label:>24s}" for label in frames))
    for number, obj in names.items():
        here = (index == number) & ~mask
        if here.sum() < 20:
            continue
        row = "".join(f" {1000 * errors[label][here].sum():24.2f}" for label in frames)
        print(f"{obj:22s} {here.sum():6d}{row}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What ``--denoise-passes`` should denoise at the demo's 16 spp, measured.

For each frame this renders the scene's SSS-off passes at 16 spp with
Cycles' denoising guides kept, and at 256 spp (another seed) as the target;
then denoises copies of the 16-spp file three ways and prints, per pass, the
squared error on SSS pixels against the 256-spp passes as a fraction of the
undenoised one's (1 = no gain; the 256-spp target has noise of its own, so
the fractions are slightly high), and the seconds each denoise took:

- ``default``: what the add-on does at 16 spp (Diffuse Color left as rendered);
- ``colour``: Diffuse Color denoised too (what it does below 16 spp);
- ``fast``: the default with the guides' *Fast* prefilter instead of *Accurate*.

Run after ``make demo`` (which saves the scenes), from the repo root:

    .venv/bin/python docs/checks/denoise_passes.py out/demo/flash/flash.blend [21,41]
"""

import shutil
import sys
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np
import OpenEXR

import cvsss
from cvsss.sss_addon.blender import denoise, render

PASSES = ("Combined", "Diffuse Direct", "Diffuse Indirect", "Diffuse Color")


def read(path: Path) -> dict:
    exr = OpenEXR.File(str(path), separate_channels=True)
    return {k: np.asarray(c.pixels) for part in exr.parts for k, c in part.channels.items()}


def rgb(pixels: dict, layer: str, name: str) -> np.ndarray:
    return np.stack([pixels[f"{layer}.{name}.{c}"] for c in "RGB"], -1).astype(np.float64)


def render_frame(scene, frame: int, samples: int, seed: int, out: Path, guides: bool) -> Path:
    """One frame's pass file; with ``guides`` the denoiser's guides are kept, nothing denoised."""
    scene.cycles.samples, scene.cycles.seed = samples, seed
    real = denoise.denoise_pass_file
    denoise.denoise_pass_file = lambda path, layer, samples=None: None
    try:
        job = render.job_from_scene(
            scene, frames=(frame, frame), out=out, denoise_passes=guides, overwrite=True
        )
        (step,) = render.iter_passes(job)
    finally:
        denoise.denoise_pass_file = real
    return step.path


def fast_prefilter(build):
    def wrapped(tree, *args, **kwargs):
        build(tree, *args, **kwargs)
        for node in tree.nodes:
            if node.bl_idname == "CompositorNodeDenoise":
                node.inputs["Prefilter"].default_value = "Fast"

    return wrapped


def main() -> None:
    blend = sys.argv[1]
    frames = [int(f) for f in (sys.argv[2] if len(sys.argv) > 2 else "21,41").split(",")]
    bpy.ops.wm.open_mainfile(filepath=blend)
    cvsss.register()
    scene = bpy.context.scene
    layer = scene.view_layers[0].name
    build = denoise._build_tree
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for frame in frames:
            noisy = render_frame(scene, frame, 16, 0, tmp / f"noisy{frame}", guides=True)
            many = render_frame(scene, frame, 256, 17, tmp / f"many{frame}", guides=False)
            a, c = read(noisy), read(many)
            sss = c[f"{layer}.Material Index.X"] > 0
            print(f"frame {frame}: {int(sss.sum())} SSS pixels")
            for name, samples, patch in (
                ("default", 16, None),
                ("colour", None, None),
                ("fast", 16, fast_prefilter(build)),
            ):
                path = tmp / f"{name}{frame}.exr"
                shutil.copy(noisy, path)
                denoise._build_tree = patch or build
                try:
                    t0 = time.perf_counter()
                    denoise.denoise_pass_file(path, layer, samples)
                    seconds = time.perf_counter() - t0
                finally:
                    denoise._build_tree = build
                b = read(path)
                ratios = []
                for p in PASSES:
                    target = rgb(c, layer, p)[sss]
                    before = np.mean((rgb(a, layer, p)[sss] - target) ** 2)
                    after = np.mean((rgb(b, layer, p)[sss] - target) ** 2)
                    ratios.append(f"{p} {after / before:.3f}")
                print(f"  {name:>7}: {seconds:.2f} s  " + "  ".join(ratios))


if __name__ == "__main__":
    main()

"""Where Apply on Render's frame parts from Cycles along one object's borders with others.

Reads a ``cvsss compare`` run (its ground truth, with each frame's Object Index,
and its Cycles renders, plain and Apply on Render) and prints, for the
pixels of ``--object`` within 1, 2 and 4 px of each other object (rings: a pixel
counts in the nearest ring only; pixels summed over the frames), the squared
display error against the ground truth summed over the ring and over the frames, and the mean signed display error
(×1000), Apply on Render beside the plain render; then the rest of the object.
Display space as ``cvsss compare`` scores it (core.eval.users_frame: the ground
truth's exposure, clipped, sRGB-encoded). A run from before the compare kept the
Object Index (no ``ground_truth/objects/``) has it rendered from the file it
compared (Cycles, 1 sample). From the repository root::

    .venv/bin/cvsss compare out/demo/flash/flash.blend --frames 21-22 --out out/contact \\
        --engine CYCLES --samples 16
    .venv/bin/python tools/measure/contact_bands.py out/demo/flash/flash.blend out/contact \\
        --object "flash Marble Top" --frames 21-22

(docs/explanation/accuracy.md §2.2 quotes it on the demo's marble tops.)
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path
from types import SimpleNamespace

import bpy
import numpy as np
from scipy import ndimage

from cvsss.core.eval.users_frame import display, frame_exposure, subsurface_mask
from cvsss.core.io.exr import read_pass, read_rgb
from cvsss.sss_addon.cli.parser import parse_frames

RINGS = (1, 2, 4)


def object_index(blend: Path, frame: int) -> tuple[np.ndarray, dict[int, str]]:
    """(H, W) int: the object each pixel shows (0: none), and {number: object name}."""
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    scene.frame_set(frame)
    names = {}
    for number, obj in enumerate(scene.objects, 1):
        obj.pass_index = number
        names[number] = obj.name
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.render.use_compositing = False
    scene.view_layers[0].use_pass_object_index = True
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    with tempfile.TemporaryDirectory() as folder:
        scene.render.filepath = str(Path(folder) / "index.exr")
        bpy.ops.render.render(write_still=True)
        index = read_pass(Path(folder) / "index.exr", "Object Index")
    return np.rint(index).astype(int), names


def stored_objects(compared: Path, frame: int) -> tuple[np.ndarray, dict[int, str]] | None:
    """The Object Index and object names a ``cvsss compare`` run kept of one frame
    (``ground_truth/objects/####.exr`` and ``.json``); None where it kept none."""
    path = compared / "ground_truth" / "objects" / f"{frame:04d}.exr"
    if not path.exists():
        return None
    names = json.loads(path.with_suffix(".json").read_text())
    index = np.rint(read_pass(path, "Object Index")).astype(int)
    return index, {int(number): name for number, name in names.items()}


def object_truth(compared: Path, frame: int, name: str) -> SimpleNamespace:
    """One frame of a ``cvsss compare`` run, seen from one object: the ground truth with
    and without subsurface (``truth``, ``truth_off``, (H, W, 3) linear), its exposure
    ``k``, the subsurface pixels ``mask`` and of them the object's, ``mine`` ((H, W)
    bool; the figures' rules, core.eval.users_frame). Exits with one line where the
    run kept no Object Index or shows no object ``name``."""
    file = f"{frame:04d}.exr"
    truth = read_rgb(compared / "ground_truth" / "material" / file)
    truth_off = read_rgb(compared / "ground_truth" / "off" / file)
    k = frame_exposure(truth)
    mask = subsurface_mask(truth, truth_off, k)
    stored = stored_objects(compared, frame)
    if stored is None:
        raise SystemExit(f"error: {compared} kept no Object Index of frame {frame}")
    index, names = stored
    number = next((n for n, label in names.items() if label == name), None)
    if number is None:
        raise SystemExit(f"error: {compared} shows no object {name!r}")
    return SimpleNamespace(
        truth=truth, truth_off=truth_off, k=k, mask=mask, mine=(index == number) & mask
    )


def frame_objects(compared: Path, blend: Path, frame: int) -> tuple[np.ndarray, dict[int, str]]:
    """The Object Index and object names of one frame of a ``cvsss compare`` run: the
    run's own (:func:`stored_objects`), else rendered from ``blend``
    (:func:`object_index`)."""
    return stored_objects(compared, frame) or object_index(blend, frame)


def rings(index: np.ndarray, target: int, names: dict[int, str]) -> dict[str, np.ndarray]:
    """{label: (H, W) bool}: the target's pixels in each ring round each other object."""
    mine = index == target
    out, taken = {}, np.zeros_like(mine)
    for number in sorted(set(np.unique(index)) - {0, target}):
        other = index == number
        before = np.zeros_like(mine)
        for width in RINGS:
            ring = mine & ndimage.binary_dilation(other, iterations=width) & ~before
            before |= ring
            if ring.any():
                out[f"{names[number]} <= {width} px"] = ring
        taken |= before
    out["rest"] = mine & ~taken
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("blend", type=Path)
    ap.add_argument("compared", type=Path, help="the cvsss compare --out folder")
    ap.add_argument("--object", required=True, help="the object whose borders to score")
    ap.add_argument("--frames", default="1-1")
    ap.add_argument("--variant", default="material", help="the compare's method variant")
    ap.add_argument("--samples", type=int, default=16)
    args = ap.parse_args()
    first, last = parse_frames(args.frames)
    frames = range(first, last + 1)
    renders = args.compared / "renders" / f"cycles_{args.samples}_denoised"
    sums: dict[str, np.ndarray] = {}  # label -> [who][sse, signed]
    pixels: dict[str, int] = {}
    for frame in frames:
        # Each frame's own Object Index: objects move (the boids' moth, a flickering
        # candle's flame), so the first frame's would misplace the rings of the others.
        index, names = frame_objects(args.compared, args.blend, frame)
        target = next((n for n, name in names.items() if name == args.object), None)
        if target is None:
            raise SystemExit(f"error: {args.blend} has no object {args.object!r}")
        bands = rings(index, target, names)
        for label, mask in bands.items():
            sums.setdefault(label, np.zeros((2, 2)))
            pixels[label] = pixels.get(label, 0) + int(mask.sum())
        truth = read_rgb(args.compared / "ground_truth" / args.variant / f"{frame:04d}.exr")
        k = frame_exposure(truth)
        gt = display(truth, k)
        for who, name in enumerate(("apply_on_render", "plain")):
            image = display(read_rgb(renders / f"{args.variant}_{name}_{frame:04d}.exr"), k)
            error = (image - gt)[..., :3].mean(axis=-1)
            squared = ((image - gt)[..., :3] ** 2).mean(axis=-1)
            for label, mask in bands.items():
                sums[label][who] += squared[mask].sum(), error[mask].sum()
    print(f"{'ring':32s} {'pixels':>7s} {'SSE apply':>10s} {'SSE plain':>10s} "
          f"{'mean err apply':>15s} {'mean err plain':>15s}")  # fmt: skip
    for label in sorted(pixels, key=lambda label: label == "rest"):
        n = pixels[label]
        (sse_a, err_a), (sse_p, err_p) = sums[label]
        print(f"{label:32s} {n:7d} {sse_a:10.3f} {sse_p:10.3f} "
              f"{1000 * err_a / n:+15.2f} {1000 * err_p / n:+15.2f}")  # fmt: skip


if __name__ == "__main__":
    main()

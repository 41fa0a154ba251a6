"""How much of a ``cvsss compare`` figure is the ground truth's own noise.

A path-traced ground truth carries noise of its own, which adds to every row's
squared error alike: it narrows the gap in dB between two renders. For a scene
already compared (COMPARE, a ``cvsss compare`` folder), this renders the same
ground truth (with and without subsurface, the compare's samples per pixel)
again with other Cycles seeds, then scores every finished frame of the compare
(``renders/<setting>/<variant>_<kind>_####.exr``) against the compare's ground
truth alone and against the mean of all the seeds' (``core.eval.users_frame``:
whole frame / subsurface pixels / subsurface effect, dB, the mean over the
frames; the effect where the setting has its frame without subsurface). It
also prints the ground truth's own noise as a PSNR: one render's spread across
the seeds (display space, the mean over the frames' subsurface pixels).

From the repository root, after ``cvsss compare BLEND --frames 21-22 --out COMPARE``::

    python tools/measure/truth_noise.py BLEND COMPARE OUT --frames 21-22 --seeds 1,2,3

(``python`` with ``bpy`` 5.0 and the ``cvsss`` package importable.) The seeds'
renders are kept under OUT/seed_<n>/ and reused when run again.
"""

from __future__ import annotations

import json
from pathlib import Path

import bpy
import numpy as np
from compared import arguments

from cvsss.core.eval.users_frame import display, frame_exposure, frame_figures, subsurface_mask
from cvsss.core.io.exr import read_rgb
from cvsss.sss_addon.blender import materials as sss_materials
from cvsss.sss_addon.blender.passes import render_view_layer
from cvsss.sss_addon.blender.standalone import ensure_registered
from cvsss.sss_addon.blender.users_frame import blend_digest, render_truth


def render_seeds(blend: Path, numbers: list[int], samples: int, seeds: list[int], out: Path):
    """Render the ground truth of ``numbers`` with each of ``seeds`` into
    OUT/seed_<n>/{material,off}/####.exr (kept when their record matches)."""
    ensure_registered()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    view_layer = render_view_layer(scene)
    materials = sss_materials.scene_materials(scene, view_layer)
    for seed in seeds:
        for kind in ("material", "off"):
            for number in numbers:
                record = {"subsurface": kind, "blend_sha256": blend_digest(str(blend))}
                path = out / f"seed_{seed}" / kind / f"{number:04d}.exr"
                render_truth(scene, view_layer, number, path, samples, subsurface=kind == "material",
                             materials=materials, record=record, seed=seed)  # fmt: skip
                print(f"seed {seed} {kind} {number}", flush=True)


def main() -> int:
    parser = arguments(__doc__, "a cvsss compare folder (material variant)")
    parser.add_argument("--seeds", default="1,2,3", help="comma-separated Cycles seeds, not 0")
    args = parser.parse_args()
    first, last = (int(v) for v in args.frames.split("-"))
    numbers = list(range(first, last + 1))
    seeds = [int(v) for v in args.seeds.split(",")]
    truth = args.compare / "ground_truth"
    record = json.loads((truth / "material" / f"{first:04d}.json").read_text())
    render_seeds(args.blend, numbers, record["samples"], seeds, args.out)
    folders = [truth] + [args.out / f"seed_{s}" for s in seeds]

    mean_label = f"mean of {len(folders)}"
    # Each frame's ground truths, read once: seed 0's alone and the mean of all the seeds'.
    truths: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {"seed 0": {}, mean_label: {}}
    noise = []
    for number in numbers:
        with_sss = [read_rgb(f / "material" / f"{number:04d}.exr") for f in folders]
        without = [read_rgb(f / "off" / f"{number:04d}.exr") for f in folders]
        mean, mean_off = sum(with_sss) / len(folders), sum(without) / len(folders)
        truths["seed 0"][number] = with_sss[0], without[0]
        truths[mean_label][number] = mean, mean_off
        k = frame_exposure(mean)
        mask = subsurface_mask(mean, mean_off, k)
        shown = np.stack([display(t, k) for t in with_sss])
        spread = ((shown - shown.mean(0)) ** 2).sum(0).mean(-1) / (len(folders) - 1)
        noise.append(spread[mask].mean())
    one = float(-10 * np.log10(np.mean(noise)))
    print(f"ground truth ({record['samples']} spp, seed 0): its own noise on subsurface pixels "
          f"{one:.2f} dB PSNR; the mean of {len(folders)} seeds: "
          f"{one + 10 * np.log10(len(folders)):.2f} dB")  # fmt: skip
    table = {"samples": record["samples"], "seeds": [0, *seeds], "noise_db": one, "rows": {}}
    for frames in sorted((args.compare / "renders").glob("*/material_*_*.exr")):
        if frames.stem.endswith(f"{first:04d}"):
            setting, kind = frames.parent.name, frames.stem[len("material_") : -5]
            scores = {label: [] for label in truths}
            for number in numbers:
                image = read_rgb(frames.parent / f"material_{kind}_{number:04d}.exr")
                off_path = frames.parent / f"off_{number:04d}.exr"
                off = read_rgb(off_path) if off_path.is_file() else None
                for label, by_frame in truths.items():
                    f = frame_figures(image, *by_frame[number], off)
                    scores[label].append((f.psnr_whole_db, f.psnr_subsurface_db, f.effect_db))
            scores = {
                label: np.mean(rows, axis=0).round(2).tolist() for label, rows in scores.items()
            }
            table["rows"][f"{setting} {kind}"] = scores
            print(f"{setting:22s} {kind:16s} " + "  ".join(
                f"{label}: {w:.2f} / {s:.2f} / {e:.2f}" for label, (w, s, e) in scores.items()))  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "truth_noise.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

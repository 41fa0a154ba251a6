"""Which objects hold a ``cvsss compare`` frame's error on the subsurface pixels.

Reads a ``cvsss compare`` run (with each frame's Object Index, or for a run from
before the compare kept it, the file it compared: ``contact_bands.frame_objects``)
and prints per object, for every finished frame of one setting
(``renders/<setting>/``, plain and Apply on Render): its subsurface pixels, its squared display error summed
over them and over the frames (×1000), and the gain in dB of Apply on Render
over the plain render on that object alone. With ``--effect`` the error is the
subsurface effect's (SPEC §12, ``core.eval.users_frame``: the change
subsurface makes, scaled by the frame's one lighting scale ``s``) instead of
the frame's. The last row is the ground truth's own noise, where ``--truths``
names a ``tools/measure/truth_noise.py`` folder of other seeds' renders (their
mean's squared difference from the compare's ground truth, times the
compare's ground truth's share of that difference's variance, from the
records' samples per pixel). From the repository root::

    .venv/bin/python tools/measure/object_share.py out/demo/flash/flash.blend \\
        out/demo/flash/users_frame --frames 21-22 [--setting cycles_16_denoised] \\
        [--effect] [--truths OUT_OF_TRUTH_NOISE]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from contact_bands import frame_objects

from cvsss.core.eval.users_frame import display, frame_exposure, object_errors, subsurface_mask
from cvsss.core.io.exr import read_rgb
from cvsss.sss_addon.cli.parser import parse_frames

KINDS = ("plain", "apply_on_render")


def samples_of(exr: Path) -> int:
    """The samples per pixel a ground-truth frame's record (``####.json``) states."""
    return int(json.loads(exr.with_suffix(".json").read_text())["samples"])


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blend", type=Path)
    parser.add_argument("compare", type=Path, help="the cvsss compare --out folder")
    parser.add_argument("--frames", required=True, help="A-B, as the compare's")
    parser.add_argument("--setting", default="cycles_16_denoised", help="renders/<setting>")
    parser.add_argument("--variant", default="material", help="the compare's method variant")
    parser.add_argument("--effect", action="store_true", help="the subsurface effect's error")
    parser.add_argument("--truths", type=Path, help="truth_noise.py's OUT (seed_<n>/ folders)")
    args = parser.parse_args()
    first, last = parse_frames(args.frames)
    renders = args.compare / "renders" / args.setting
    seeds = sorted(args.truths.glob("seed_*")) if args.truths else []
    sums: dict[tuple[str, str], float] = {}
    pixels: dict[str, int] = {}
    for number in range(first, last + 1):
        name = f"{number:04d}.exr"
        index, names = frame_objects(args.compare, args.blend, number)
        truth = read_rgb(args.compare / "ground_truth" / args.variant / name)
        truth_off = read_rgb(args.compare / "ground_truth" / "off" / name)
        off = read_rgb(renders / f"off_{name}") if args.effect else None
        sse = "effect_sse" if args.effect else "display_sse"
        for kind in KINDS:
            image = read_rgb(renders / f"{args.variant}_{kind}_{name}")
            for number_, sums_ in object_errors(image, truth, truth_off, index, off).items():
                obj = names.get(number_)
                if obj is None:
                    continue
                if kind == KINDS[0]:
                    pixels[obj] = pixels.get(obj, 0) + sums_["pixels"]
                sums[(obj, kind)] = sums.get((obj, kind), 0.0) + sums_[sse]
        if seeds:
            k = frame_exposure(truth)
            mask = subsurface_mask(truth, truth_off, k)
            others = [read_rgb(seed / "material" / name) for seed in seeds]
            others_off = [read_rgb(seed / "off" / name) for seed in seeds]
            mean, mean_off = sum(others) / len(seeds), sum(others_off) / len(seeds)
            # Var(truth − mean) = σ²·(1/n + 1/(S·m)) for the compare's n spp and S seeds
            # of m spp each; the compare's truth's own share of it is (1/n) / that.
            n = samples_of(args.compare / "ground_truth" / args.variant / name)
            m = samples_of(seeds[0] / "material" / name)
            share = (1 / n) / (1 / n + 1 / (len(seeds) * m))
            if args.effect:
                diff = k * ((truth - truth_off) - (mean - mean_off))
            else:
                diff = display(truth, k) - display(mean, k)
            noise = (diff**2).mean(-1) * share
            for number_, obj in names.items():
                here = mask & (index == number_)
                key = (obj, "ground truth's noise")
                sums[key] = sums.get(key, 0.0) + float(noise[here].sum())
    columns = list(KINDS) + (["ground truth's noise"] if seeds else [])
    what = "effect" if args.effect else "display"
    print(f"{args.setting}, frames {args.frames}: squared {what} error on subsurface pixels, ×1000")
    print(f"{'object':24s} {'pixels':>7s}" + "".join(f" {c:>21s}" for c in columns) + "  gain dB")
    for obj in sorted(pixels, key=lambda o: -sums[(o, "apply_on_render")]):
        row = "".join(f" {1000 * sums[(obj, c)]:21.1f}" for c in columns)
        plain, ours = sums[(obj, "plain")], sums[(obj, "apply_on_render")]
        gain = f"{10 * np.log10(plain / ours):+7.2f}" if plain > 0 and ours > 0 else "      —"
        print(f"{obj:24s} {pixels[obj]:7d}{row}  {gain}")
    total = {c: sum(v for (o, kk), v in sums.items() if kk == c) for c in columns}
    n = sum(pixels.values())
    print(f"{'all':24s} {n:7d}" + "".join(f" {1000 * total[c]:21.1f}" for c in columns)
          + f"  {10 * np.log10(total['plain'] / total['apply_on_render']):+7.2f}")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""How much of Apply on Render's error on one object is a bias along image rows.

Reads a ``cvsss compare`` run (its ground truth, each frame's Object Index in
``ground_truth/objects/``, and its Cycles renders, plain and Apply on Render)
and prints, for each image row ``--rows A-B`` of ``--object``'s subsurface
pixels, the mean signed display error against the ground truth (×1000), Apply
on Render beside the plain render, per frame. Then the gain of Apply on Render
over plain on the subsurface pixels, from the squared display error summed over
the frames, as it is and with each of those rows' mean error taken out of
Apply on Render: what a rule that removed that bias, and nothing else, would
give. Display space as ``cvsss compare`` scores it (core.eval.users_frame).

A slab's face seen nearly head-on lies along image rows, so this splits a
face's error into its rows' bias (too dark or too bright at a height) and the
rest. From the repository root, after ``make demo`` (its compare of flash)::

    .venv/bin/python tools/measure/row_bias.py out/demo/flash/users_frame \\
        --object "flash Marble Top" --rows 162-167 --frames 21-22

``--post DIR`` reads Apply on Render's frames from a ``cvsss post`` method folder
instead (``DIR/####.exr``, its Composite: the post of the pass files of ``cvsss
render --passes-only --denoise``, denoised as the scene says), to score a change
to the post against the same run.

(docs/explanation/accuracy.md, *Where it stands* and §2.2, quotes it on the slabs.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from contact_bands import object_truth

from cvsss.core.eval.users_frame import display
from cvsss.core.io.exr import read_result, read_rgb
from cvsss.sss_addon.cli.parser import parse_frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("compared", type=Path, help="the cvsss compare --out folder")
    parser.add_argument("--object", required=True, help="the object's name")
    parser.add_argument("--rows", required=True, help="image rows A-B (0: the top row)")
    parser.add_argument("--frames", required=True, help="frames A-B of the run")
    parser.add_argument(
        "--setting", default="cycles_16_denoised", help="the run's renders/<setting>"
    )
    parser.add_argument("--post", type=Path, help="a cvsss post method folder (####.exr)")
    args = parser.parse_args()
    first, last = parse_frames(args.rows)
    renders = args.compared / "renders" / args.setting
    sums = {"as it is": 0.0, "rows' bias out": 0.0, "plain": 0.0}
    start, end = parse_frames(args.frames)
    for frame in range(start, end + 1):
        name = f"{frame:04d}.exr"
        seen = object_truth(args.compared, frame, args.object)
        k, mask, mine = seen.k, seen.mask, seen.mine
        shown = display(seen.truth, k)
        if args.post is None:
            frame_ours = read_rgb(renders / f"material_apply_on_render_{name}")
        else:
            frame_ours = read_result(args.post / name)["Composite"]
        ours = display(frame_ours, k) - shown
        plain = display(read_rgb(renders / f"material_plain_{name}"), k) - shown
        unbiased = ours.copy()
        line = []
        for row in range(first, last + 1):
            on = mine[row]
            if not on.any():
                continue
            bias = ours[row][on].mean(axis=0)
            unbiased[row][on] -= bias
            line.append(f"{row}: {1e3 * bias.mean():+.1f} / {1e3 * plain[row][on].mean():+.1f}")
        print(f"frame {frame}, mean display error ×1000, Apply on Render / plain, by row:")
        print("  " + ", ".join(line))
        for label, error in (("as it is", ours), ("rows' bias out", unbiased), ("plain", plain)):
            sums[label] += float(np.mean(error**2, axis=-1)[mask].sum())
    print("gain over plain on the subsurface pixels (summed squared display error):")
    for label in ("as it is", "rows' bias out"):
        gain = 10 * np.log10(sums["plain"] / sums[label])
        print(f"  {label}: {sums[label]:.3f} against plain's {sums['plain']:.3f}, {gain:+.2f} dB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

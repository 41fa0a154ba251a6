"""What subsurface does to an object, image row by image row: Cycles against the post.

For each row ``--rows A-B`` of ``--object``'s subsurface pixels (the figures' mask
rule), the ratio of the summed luminance with subsurface to without: Cycles'
(its ground truth with and without subsurface, from a ``cvsss compare`` run) and
the post's (a method's finished frame, ``Composite``, over the ``none`` method's
on the same passes), then the post's frame over the ground truth. Linear light,
means over ``--frames``; last the post's squared display error summed over the
object's subsurface pixels and the frames (the figures' exposure and display rule,
the mean over the channels), to compare two runs of the post. It tells whether an
object's bias along a row comes from what the post adds (the ratios differ) or from
the passes (the frame without subsurface differs). From the repository root, after ``make demo``::

    .venv/bin/cvsss render out/demo/flash/flash.blend --frames 21-22 --passes-only \\
        --denoise --out out/rows
    .venv/bin/cvsss post out/rows/passes --out out/rows/post --method as_ccv --no-denoise
    .venv/bin/cvsss post out/rows/passes --out out/rows/none --method none --no-denoise
    .venv/bin/python tools/measure/row_gain.py out/demo/flash/users_frame \\
        out/rows/post/as_ccv out/rows/none/none --object "flash Marble Top" \\
        --rows 158-167 --frames 21-22

(docs/explanation/accuracy.md, *Where it stands*, quotes it on flash's slab.)
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from contact_bands import object_truth

from cvsss.core.color import luminance
from cvsss.core.eval.users_frame import display
from cvsss.core.io.exr import read_result
from cvsss.sss_addon.cli.parser import parse_frames


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("compared", type=Path, help="the cvsss compare --out folder")
    parser.add_argument("post", type=Path, help="a method's result folder (####.exr)")
    parser.add_argument("none", type=Path, help="method none's result folder, same passes")
    parser.add_argument("--object", required=True, help="the object's name")
    parser.add_argument("--rows", required=True, help="image rows A-B (0: the top row)")
    parser.add_argument("--frames", required=True, help="frames A-B")
    args = parser.parse_args()
    first, last = parse_frames(args.rows)
    start, end = parse_frames(args.frames)
    squared = 0.0
    ratios: dict[str, dict[int, list[float]]] = {
        key: {} for key in ("Cycles", "post", "post / Cycles")
    }
    for frame in range(start, end + 1):
        name = f"{frame:04d}.exr"
        seen = object_truth(args.compared, frame, args.object)
        post = read_result(args.post / name)["Composite"]
        error = np.mean((display(post, seen.k) - display(seen.truth, seen.k)) ** 2, axis=-1)
        squared += float(error[seen.mine].sum())
        y = {
            "truth": luminance(seen.truth),
            "truth_off": luminance(seen.truth_off),
            "post": luminance(post),
            "none": luminance(read_result(args.none / name)["Composite"]),
        }
        for row in range(first, last + 1):
            on = seen.mine[row]
            if not on.any():
                continue
            s = {image: float(v[row][on].sum()) for image, v in y.items()}
            for key, value in (
                ("Cycles", s["truth"] / s["truth_off"]),
                ("post", s["post"] / s["none"]),
                ("post / Cycles", s["post"] / s["truth"]),
            ):
                ratios[key].setdefault(row, []).append(value)
    print(f"{args.object}, rows {first}-{last}: with subsurface over without (linear luminance)")
    for key, by_row in ratios.items():
        cells = " ".join(f"{row}: {np.mean(v):.3f}" for row, v in by_row.items())
        print(f"  {key:14s} {cells}")
    print(f"the post's squared display error, summed over those pixels: {squared:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What subsurface does to an object, image row by image row: Cycles against the post.

For each row ``--rows A-B`` of ``--object``'s subsurface pixels (the figures' mask
rule), the ratio of the summed luminance with subsurface to without: Cycles'
(its ground truth with and without subsurface, from a ``cvsss compare`` run) and
the post's (a method's finished frame, ``Composite``, over the ``none`` method's
on the same passes), then the post's frame over the ground truth. Linear light,
means over ``--frames``; last the post's squared display error summed over the
object's subsurface pixels and the frames (the figures' exposure and display rule,
the mean over the channels), to compare two runs of the post. It tells whether an object's bias along a row comes
from what the post adds (the ratios differ) or from the passes (the frame without
subsurface differs). From the repository root, after ``make demo``::

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
from contact_bands import stored_objects

from cvsss.core.color import luminance
from cvsss.core.eval.users_frame import display, frame_exposure, subsurface_mask
from cvsss.core.io.exr import read_channels, read_rgb
from cvsss.sss_addon.cli.parser import parse_frames


def composite(path: Path) -> np.ndarray:
    """(H, W, 3) float32, linear: a cvsss result file's finished frame."""
    channels = read_channels(path)
    return np.stack([channels[f"Composite.{c}"] for c in "RGB"], axis=-1)


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
    ratios: dict[str, dict[int, list[float]]] = {k: {} for k in ("Cycles", "post", "post / Cycles")}
    for frame in range(start, end + 1):
        name = f"{frame:04d}.exr"
        truth = read_rgb(args.compared / "ground_truth" / "material" / name)
        truth_off = read_rgb(args.compared / "ground_truth" / "off" / name)
        k = frame_exposure(truth)
        mask = subsurface_mask(truth, truth_off, k)
        stored = stored_objects(args.compared, frame)
        if stored is None:
            raise SystemExit(f"error: {args.compared} kept no Object Index of frame {frame}")
        index, names = stored
        number = next((n for n, label in names.items() if label == args.object), None)
        if number is None:
            raise SystemExit(f"error: {args.compared} shows no object {args.object!r}")
        mine = (index == number) & mask
        post = composite(args.post / name)
        error = np.mean((display(post, k) - display(truth, k)) ** 2, axis=-1)
        squared += float(error[mine].sum())
        y = {
            "truth": luminance(truth),
            "truth_off": luminance(truth_off),
            "post": luminance(post),
            "none": luminance(composite(args.none / name)),
        }
        for row in range(first, last + 1):
            on = mine[row]
            if not on.any():
                continue
            s = {k: float(v[row][on].sum()) for k, v in y.items()}
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

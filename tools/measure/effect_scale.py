"""Where the subsurface effect's one lighting scale fits the engine's light, and where not.

The subsurface effect (``core.eval.users_frame.effect_db``, SPEC §12) scales the
engine's change ``frame − frame without subsurface`` by one number, ``s =
mean(GT without subsurface) / mean(frame without subsurface)`` over the
subsurface pixels. Where the engine lights part of the scene as Cycles does and
another part dimmer (EEVEE without the light that bounces off the table), ``s``
sits between the two and over-scales the first part's effect.

For a ``cvsss compare`` folder this sorts the subsurface pixels by their own
ratio ``r = GT without subsurface / frame without subsurface`` (luminance, each
pixel's 3×3 neighbourhood) and prints per bin of ``r``: the pixels, their share
of the ground truth's light, and each finished frame's squared effect error
(display space, the exposure of the figures) as a share of its total, with the
effect in dB with ``s`` as the figures have it and, as a diagnostic, with
``s = 1``. Reads EXR files only.

From the repository root, after ``cvsss compare BLEND --frames 21-22 --out COMPARE``::

    python tools/measure/effect_scale.py COMPARE --frames 21-22 [--setting eevee_16]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
from scipy.ndimage import uniform_filter

from cvsss.core.eval.users_frame import frame_exposure, lighting_scale, subsurface_mask
from cvsss.core.io.exr import read_rgb

#: Bin edges of the ratio r (the ground truth's light over the engine's, per pixel).
EDGES = (0.0, 0.9, 1.1, 1.3, 2.0, np.inf)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("compare", type=Path, help="a cvsss compare folder")
    parser.add_argument("--frames", required=True, help="A-B, as the compare's")
    parser.add_argument("--setting", default="eevee_16", help="renders/<setting> (eevee_16)")
    args = parser.parse_args()
    first, last = (int(v) for v in args.frames.split("-"))
    renders = args.compare / "renders" / args.setting
    kinds = sorted(
        p.stem[len("material_") : -5] for p in renders.glob(f"material_*_{first:04d}.exr")
    )
    bins = len(EDGES) - 1
    count, light = np.zeros(bins), np.zeros(bins)
    err = {(kind, scale): np.zeros(bins) for kind in kinds for scale in ("s", "1")}
    scales = []
    for number in range(first, last + 1):
        name = f"{number:04d}.exr"
        truth = read_rgb(args.compare / "ground_truth" / "material" / name)
        truth_off = read_rgb(args.compare / "ground_truth" / "off" / name)
        off = read_rgb(renders / f"off_{name}")
        k = frame_exposure(truth)
        mask = subsurface_mask(truth, truth_off, k)
        s = lighting_scale(truth_off, off, mask)
        scales.append(s)
        ratio = uniform_filter(truth_off.mean(-1), 3) / np.maximum(
            uniform_filter(off.mean(-1), 3), 1e-9
        )
        which = np.digitize(ratio, EDGES[1:-1])
        for b in range(bins):
            pixels = mask & (which == b)
            count[b] += pixels.sum()
            light[b] += truth_off[pixels].sum()
        for kind in kinds:
            image = read_rgb(renders / f"material_{kind}_{name}")
            for label, scale in (("s", s), ("1", 1.0)):
                e = ((k * (scale * (image - off) - (truth - truth_off))) ** 2).mean(-1)
                for b in range(bins):
                    err[(kind, label)][b] += e[mask & (which == b)].sum()
    print(f"{args.setting}, frames {args.frames}: s = " + ", ".join(f"{v:.3f}" for v in scales))
    head = "r (GT / engine, without subsurface)   pixels  GT light"
    print(head + "".join(f"  {kind} (s)" for kind in kinds))
    for b in range(bins):
        label = f"{EDGES[b]:.1f} – {EDGES[b + 1]:.1f}"
        shares = "".join(
            f"  {err[(kind, 's')][b] / err[(kind, 's')].sum():>{len(kind) + 4}.1%}"
            for kind in kinds
        )
        print(f"{label:36s} {count[b] / count.sum():7.1%}  {light[b] / light.sum():8.1%}{shares}")
    n = count.sum()
    for label in ("s", "1"):
        name = "as the figures (s)" if label == "s" else "diagnostic, s = 1"
        print(f"effect dB, {name}: " + ", ".join(
            f"{kind} {-10 * np.log10(err[(kind, label)].sum() / n):.2f}" for kind in kinds))  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

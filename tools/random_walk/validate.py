"""Spheres: Cycles' Burley with the fitted d and energy against Cycles' random walk.

Reads the sphere renders of cases.py ``spheres`` (render_slabs.py) and prints,
per method and sphere size, the display-space PSNR (exposure ``k = 1/p99`` of
the random-walk render's brightest channel, sRGB OETF, clip [0, 1]) of

``fitted``  Cycles Burley with the model's d and Base Color A·e,
``plain``   Cycles Burley with the material's own radius (what the post-process
            modelled before: d = radius·scale/(4π), e = 1),
``seed1``   the random walk rendered again with another seed (the noise floor),

against the random-walk render, over the sphere's pixels (where the truth is
not 0) and the whole image, with the per-channel mean ratio to the truth::

    python tools/random_walk/validate.py RENDERS
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import edge

from cvsss.core.eval.color import srgb_encode


def psnr(test: np.ndarray, truth: np.ndarray, mask: np.ndarray | None, k: float) -> float:
    sel = (slice(None),) if mask is None else mask
    diff = srgb_encode(np.clip(test[sel] * k, 0, None)) - srgb_encode(
        np.clip(truth[sel] * k, 0, None)
    )
    return float(10 * np.log10(1.0 / np.mean(diff**2)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("renders", type=Path)
    args = ap.parse_args(argv)
    for truth_path in sorted(args.renders.glob("sphere_*_truth.exr")):
        tag = truth_path.stem[len("sphere_") : -len("_truth")]
        truth = edge.read_exr(truth_path)["Combined"][..., :3].astype(np.float64)
        k = 1.0 / float(np.percentile(truth.max(axis=-1), 99))
        mask = truth.max(axis=-1) > 0
        row = {"sphere": tag}
        for kind in ("fitted", "plain", "seed1"):
            path = args.renders / f"sphere_{tag}_{kind}.exr"
            if not path.exists():
                continue
            img = edge.read_exr(path)["Combined"][..., :3].astype(np.float64)
            row[kind] = {
                "psnr_sphere_db": round(psnr(img, truth, mask, k), 2),
                "psnr_full_db": round(psnr(img, truth, None, k), 2),
                "ratio": [round(float(v), 4) for v in img[mask].mean(0) / truth[mask].mean(0)],
            }
        print(json.dumps(row))
    return 0


if __name__ == "__main__":
    sys.exit(main())

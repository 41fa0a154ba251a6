"""Reflectance of thin Random Walk slabs against a deep one (the ``thickness`` cases).

Reads the renders of ``cases.py thickness`` (``render_slabs.py`` output) and
prints, per slab, the thickness in the red channel's mean free paths and the
mean Combined per channel over that of the deepest slab::

    python tools/random_walk/cases.py thickness --samples 512 > thickness.jsonl
    python tools/random_walk/render_slabs.py thickness.jsonl OUT
    python tools/random_walk/thickness.py OUT
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cvsss.core.io.exr import read_rgb


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="render_slabs.py's output folder")
    args = parser.parse_args()
    slabs = []
    for record in sorted(args.out.glob("thickness_*.json")):
        case = json.loads(record.read_text())
        case = case.get("case", case)
        mean = read_rgb(record.with_suffix(".exr"))[..., :3].reshape(-1, 3).mean(axis=0)
        ell = case["radius"][0] * case["scale"] / (4 * 3.141592653589793)
        slabs.append((case["slab_depth"] / ell, mean))
    slabs.sort(key=lambda item: item[0])
    deep = slabs[-1][1]
    for thickness, mean in slabs:
        print(f"{thickness:6.1f} mfp   " + " ".join(f"{v:.3f}" for v in mean / deep))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

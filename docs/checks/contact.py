"""What the Object Index pass buys against Cycles: objects apart, and contact height.

Cycles scatters light within one object only; the post, given the Object
Index pass, does the same, and a sample on another object resting on the
pixel's surface counts that surface as unlit (SSSParams.contact; the module
doc of core.mc.estimator, *Objects*). This script post-processes the demo's
ground-truth frames with the model's own noise out of the way (``fixed``,
256 spp per pixel: within ~0.1 dB of the 1024-spp reference) in seven ways:

- ``no objects``: the Object Index pass dropped (one object per material, as
  before the pass existed);
- ``contact 0``: objects kept apart, no contact rule;
- ``contact 0.1`` / ``0.2`` / ``0.25`` / ``0.5`` / ``1`` (the rule of 89f183a counted
  them in sample radii, 0.2 its default; since 0eab61e Contact Height counts in d,
  default 1.4).

It prints, per scene, PSNR against Cycles' ground truth on SSS pixels (mean
over the ground-truth frames, and its change against ``no objects``) and the
silhouette luminance ratios ours / Cycles (outer and contact edges, as in
metrics.csv). Run after ``make demo`` (which renders the passes with the
Object Index pass and the ground truth), from the repo root:

    .venv/bin/python docs/checks/contact.py [out/demo] [scene ...]
"""

import dataclasses
import sys
from pathlib import Path

import numpy as np

from cvsss.core.eval.metrics import edge_kinds
from cvsss.core.eval.rows import ground_truth_columns
from cvsss.core.io.exr import read_combined, read_frame
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams

VARIANTS = {
    "no objects": None,
    "contact 0": 0.0,
    "contact 0.1": 0.1,
    "contact 0.2": 0.2,
    "contact 0.25": 0.25,
    "contact 0.5": 0.5,
    "contact 1": 1.0,
}
SPP = 256


def measure(scene_dir: Path) -> dict[str, dict[str, float]]:
    """{variant: {psnr_gt_db, rim_outer_ratio, rim_contact_ratio}} means over GT frames."""
    truth = sorted((scene_dir / "ground_truth").glob("[0-9]*.exr"))
    if not truth:
        raise SystemExit(f"error: {scene_dir}/ground_truth holds no frames; run make demo first")
    rows: dict[str, list[dict]] = {name: [] for name in VARIANTS}
    for path in truth:
        frame = read_frame(scene_dir / "passes" / path.name)
        if frame.objects is None:
            raise SystemExit(
                f"error: {scene_dir}/passes/{path.name} has no Object Index pass; "
                "render the passes again (make demo does)"
            )
        gt = read_combined(path)
        for name, contact in VARIANTS.items():
            params = SSSParams(fixed_spp=SPP, contact=contact or 0.0)
            f = dataclasses.replace(frame, objects=None) if contact is None else frame
            result = make_processor("fixed", params).process(f)
            rims = edge_kinds(result.mask, frame.material, frame.depth)
            rows[name].append(ground_truth_columns(result, gt, rims))
    keys = ("psnr_gt_db", "rim_outer_ratio", "rim_contact_ratio")
    return {
        name: {k: float(np.nanmean([float(r[k]) for r in rs])) for k in keys}
        for name, rs in rows.items()
    }


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path("out/demo")
    scenes = sys.argv[2:] or ["flash", "regular", "boids"]
    print(f"fixed {SPP} spp against Cycles' ground truth, SSS pixels, mean over GT frames")
    print(
        f"{'scene':8s} {'variant':14s} {'PSNR dB':>8s} {'change':>7s} {'outer':>6s} {'contact':>7s}"
    )
    for scene in scenes:
        figures = measure(out / scene)
        base = figures["no objects"]["psnr_gt_db"]
        for name, f in figures.items():
            print(
                f"{scene:8s} {name:14s} {f['psnr_gt_db']:8.2f} {f['psnr_gt_db'] - base:+7.2f} "
                f"{f['rim_outer_ratio']:6.3f} {f['rim_contact_ratio']:7.3f}"
            )


if __name__ == "__main__":
    main()

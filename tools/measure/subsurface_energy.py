"""How much light subsurface adds on a scene, in Cycles and in Apply on Render's frame.

Whether the post's error on a scene is energy (an object brighter or darker
as a whole) or where the light goes. A walk in a thin part (Random Walk, a
table top two mean free paths thick) leaves through the far side, which the
camera does not see; Cycles' Christensen-Burley brightens folded surfaces
(docs/explanation/accuracy.md §2.3). For a ``cvsss compare`` folder (Cycles;
``--variant`` names the ground truth and renders compared: ``material``, the
scene's own methods, or a ``--method-variants`` name such as
``RANDOM_WALK``), this prints per frame, over the subsurface pixels
(``core.eval.users_frame.subsurface_mask`` of that ground truth), the mean
linear RGB of

- Cycles' ground truth, and of the same engine's plain render and Apply on
  Render's frame, each over the ground truth without subsurface;
- and the subsurface pixels' display PSNR of the plain render, of Apply on
  Render's frame, and of that frame with its subsurface pixels scaled per
  channel to the ground truth's mean (what a correct energy alone would give:
  a diagnostic, the scale read from the ground truth).

With ``--passes`` (a pass folder of the same frames and size, from ``cvsss
render``), the means are also given per object (its Object Index pass), and
the last PSNR scales each object on its own.

From the repository root::

    python tools/measure/subsurface_energy.py COMPARE --frames 21-22 --variant RANDOM_WALK \\
        --spp 16 [--passes RENDER/passes]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from cvsss.core.eval.users_frame import frame_exposure, psnr_display, subsurface_mask
from cvsss.core.io.exr import read_frame, read_rgb

#: Objects with fewer subsurface pixels than this are left out of the per-object lines.
MIN_PIXELS = 50


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("compare", type=Path, help="a cvsss compare folder (Cycles)")
    parser.add_argument("--frames", required=True, help="A-B, as the compare's")
    parser.add_argument("--variant", default="material", help="material or a method variant's name")
    parser.add_argument("--spp", type=int, default=16, help="the Cycles sample count compared")
    parser.add_argument("--passes", type=Path, help="pass EXRs of the same frames (Object Index)")
    args = parser.parse_args()
    first, last = (int(v) for v in args.frames.split("-"))
    renders = args.compare / "renders" / f"cycles_{args.spp}_denoised"
    print("frame  mean RGB over GT off: ground truth | plain | Apply on Render;"
          "  subsurface dB: plain | Apply on Render | scaled")  # fmt: skip
    for frame in range(first, last + 1):
        number = f"{frame:04d}"
        truth = read_rgb(args.compare / "ground_truth" / args.variant / f"{number}.exr")[..., :3]
        off = read_rgb(args.compare / "ground_truth" / "off" / f"{number}.exr")[..., :3]
        plain = read_rgb(renders / f"{args.variant}_plain_{number}.exr")[..., :3]
        ours = read_rgb(renders / f"{args.variant}_apply_on_render_{number}.exr")[..., :3]
        k = frame_exposure(truth)
        mask = subsurface_mask(truth, off, k)
        base = off[mask].mean(axis=0)
        scaled = ours.copy()
        objects = None if args.passes is None else read_frame(args.passes / f"{number}.exr").objects
        for index in [None] if objects is None else np.unique(objects[mask]):
            part = mask if index is None else mask & (objects == index)
            scaled[part] *= truth[part].mean(axis=0) / ours[part].mean(axis=0)
        ratios = " | ".join(
            " ".join(f"{v:.3f}" for v in image[mask].mean(axis=0) / base)
            for image in (truth, plain, ours)
        )
        psnr = " | ".join(f"{psnr_display(i, truth, k, mask):.2f}" for i in (plain, ours, scaled))
        print(f"{number}   {ratios};  {psnr}")
        if objects is not None:
            for index in np.unique(objects[mask]):
                part = mask & (objects == index)
                if part.sum() < MIN_PIXELS:
                    continue
                base = off[part].mean(axis=0)
                ratios = " | ".join(
                    " ".join(f"{v:.3f}" for v in image[part].mean(axis=0) / base)
                    for image in (truth, plain, ours)
                )
                print(f"  object {int(index)} ({int(part.sum())} px)   {ratios}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

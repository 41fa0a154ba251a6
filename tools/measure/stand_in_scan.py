"""The second denoise's stand-in noise, scanned: how far it takes the user's frame.

Apply on Render denoises its finished frame F, and from 64 spp denoises it a
second time with stand-in noise on the post's pixels for every other pixel
(``FrameDenoiser.beside_stand_in``): ``σ = gain × context_noise``, at most 0.5.
This script takes one frame that ``denoise_context.py`` rendered (OUT: the
plain render, the pass file and the post's light) and the ground truth of a
``cvsss compare`` folder of the same file (COMPARE: ``ground_truth/material``
and ``ground_truth/off``, Cycles at 4096 spp with and without subsurface), and
prints, for several gains and fixed σ, the PSNR of the delivered frame against
the ground truth minus the plain render's, on the subsurface pixels and the
whole frame (display space, the figures' exposure and mask rule), with the
noise ``context_noise`` reads round the post's pixels and the plain render's
own noise on them (its Noisy Image against the ground truth). From the repository
root, after ``denoise_context.py`` and ``cvsss compare`` on the same file::

    .venv/bin/python tools/measure/stand_in_scan.py OUT out/users/boids --frame 21
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np

from cvsss.core.color import luminance
from cvsss.core.eval.users_frame import display, frame_exposure, subsurface_mask
from cvsss.core.io.exr import read_channels, read_frame, read_result, read_rgb
from cvsss.core.result import relit
from cvsss.sss_addon.blender.denoise_frame import (
    STAND_IN_MAX,
    DenoiseSettings,
    FrameDenoiser,
    context_noise,
    read_guides,
)

GAINS = (0.0, 3.0, 4.0, 5.0)
SIGMAS = (0.1, 0.2, 0.3)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="a denoise_context.py output folder")
    parser.add_argument("compare", type=Path, help="a cvsss compare folder of the same file")
    parser.add_argument("--frame", type=int, required=True)
    args = parser.parse_args()
    name = f"{args.frame:04d}.exr"
    channels = read_channels(args.out / "plain.exr")
    layer = next(k for k in sorted(channels) if k.endswith(".Combined.R")).split(".")[0]
    plain = np.stack([channels[f"{layer}.Combined.{c}"] for c in "RGB"], -1)
    noisy = np.stack([channels[f"{layer}.Noisy Image.{c}"] for c in "RGB"], -1)
    truth = read_rgb(args.compare / "ground_truth" / "material" / name)
    truth_off = read_rgb(args.compare / "ground_truth" / "off" / name)
    k = frame_exposure(truth)
    sss = subsurface_mask(truth, truth_off, k)
    whole = np.ones_like(sss)
    result = read_result(args.out / "post" / "as_ccv" / name)
    mask = result["Mask"] > 0
    frame = read_frame(args.out / "post" / "passes" / name)
    rgba = np.ones((*mask.shape, 4), np.float32)
    rgba[..., :3] = relit(frame, mask, result["SSS"][..., :3])
    guides = read_guides(args.out / "post" / "passes" / name, layer)
    shown = display(truth, k)

    def error(image: np.ndarray, where: np.ndarray) -> float:
        return float(((display(image, k) - shown) ** 2).mean(-1)[where].sum())

    def gain_db(image: np.ndarray) -> str:
        sub = 10 * np.log10(error(plain, sss) / error(image, sss))
        all_ = 10 * np.log10(error(plain, whole) / error(image, whole))
        return f"{sub:+.2f} / {all_:+.2f}"

    noise = context_noise(rgba, mask)
    # The plain render's own noise on the post's pixels: its Noisy Image against the
    # ground truth, the median absolute deviation of the relative luminance error.
    y, y_noisy = luminance(truth), luminance(noisy)
    kept = mask & (y > 1e-3 * np.median(y))
    relative = (y_noisy[kept] - y[kept]) / y[kept]
    own = 1.4826 * float(np.median(np.abs(relative - np.median(relative))))
    print(
        f"{args.out.name} frame {args.frame}: noise round the post's pixels {noise:.3f}; "
        f"the plain render's own on them {own:.3f}"
    )
    print("against plain, dB, subsurface pixels / whole frame:")
    # The first denoise does not depend on the gain: run it once, then only the second
    # (beside_stand_in reruns the main filter with the first's guides).
    denoiser = FrameDenoiser(DenoiseSettings())
    with denoiser:
        denoised = denoiser(rgba, *guides, mask)

        def delivered(gain: float) -> np.ndarray:
            denoiser.settings = replace(denoiser.settings, stand_in_gain=gain)
            return denoiser.beside_stand_in(denoised, rgba, mask, *guides)[..., :3]

        for gain in GAINS:
            sigma = min(gain * noise, STAND_IN_MAX)
            print(f"  gain {gain:g} (σ {sigma:.2f}): {gain_db(delivered(gain))}")
        if noise == 0.0:
            print("  (nothing noisy round the post's pixels: every gain denoises once)")
            return 0
        for sigma in SIGMAS:  # a fixed σ: the gain that gives it on this frame
            print(f"  σ {sigma:g} fixed: {gain_db(delivered(min(sigma / noise, 100.0)))}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What denoising the subsurface pixels of an EEVEE frame buys (issue 44).

EEVEE's passes carry no noise; the post's samples bring the only noise of the
finished frame. For each scene of ``cvsss compare --engine EEVEE`` output
folders (COMPARE: its ``ground_truth/`` and ``renders/eevee_<n>/off_####.exr``),
this renders the scene's EEVEE passes of the same frames, posts them with
``--method`` (as_ccv by default, Apply on Render's) and scores, against the
ground truth (``core.eval.users_frame``: whole frame / subsurface pixels /
subsurface effect, dB):

=============  ==================================================================
none           the finished frame as it comes out of the post
rgb            OIDN on the whole frame, no guides
rgb_sss        the same, taken on the subsurface pixels only (what the add-on does)
albedo_sss     OIDN guided by EEVEE's Diffuse Color, on the subsurface pixels only
=============  ==================================================================

From the repository root, after ``cvsss compare BLEND --frames 21-22 --engine
EEVEE --out COMPARE``::

    python tools/measure/eevee_denoise.py BLEND COMPARE OUT --frames 21-22

(``python`` with ``bpy`` 5.0 and the ``cvsss`` package importable.)
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

from cvsss.core.eval.users_frame import frame_figures
from cvsss.core.io.exr import read_frame, read_result, read_rgb
from cvsss.sss_addon.blender.denoise_frame import DenoiseSettings, denoise_frame

VARIANTS = {
    "rgb": DenoiseSettings(prefilter="NONE", guides="RGB"),
    "rgb_sss": DenoiseSettings(prefilter="NONE", guides="RGB", subsurface_only=True),
    "albedo_sss": DenoiseSettings(prefilter="NONE", guides="RGB_ALBEDO", subsurface_only=True),
}


def _cvsss(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "cvsss.sss_addon.cli.main", *args], check=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blend", type=Path)
    parser.add_argument("compare", type=Path, help="a cvsss compare --engine EEVEE folder")
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", required=True, help="A-B, as the compare's")
    parser.add_argument("--method", default="as_ccv")
    args = parser.parse_args()
    passes = args.out / "passes"
    _cvsss(
        "render", str(args.blend), "--frames", args.frames, "--out", str(args.out),
        "--engine", "EEVEE", "--passes-only", "--no-ground-truth", "--no-reference",
        "--no-denoise", "--quiet",
    )  # fmt: skip
    _cvsss(
        "post", str(passes), "--out", str(args.out / "post"), "--method", args.method,
        "--no-denoise", "--quiet",
    )  # fmt: skip
    (renders,) = sorted((args.compare / "renders").glob("eevee_*"))
    scores: dict[str, list] = {}
    for path in sorted(passes.glob("*.exr")):
        number = path.stem
        frame = read_frame(path)
        result = read_result(args.out / "post" / args.method / f"{number}.exr")
        mask = result["Mask"] > 0
        finished = np.ones((*mask.shape, 4), np.float32)
        finished[..., :3] = result["Composite"][..., :3]
        images = {"none": finished}
        for name, settings in VARIANTS.items():
            images[name] = denoise_frame(finished, frame.albedo, None, settings, mask)
        truth = read_rgb(args.compare / "ground_truth" / "material" / f"{number}.exr")
        truth_off = read_rgb(args.compare / "ground_truth" / "off" / f"{number}.exr")
        off = read_rgb(renders / f"off_{number}.exr")
        for name, image in images.items():
            f = frame_figures(image, truth, truth_off, off)
            scores.setdefault(name, []).append((f.psnr_whole_db, f.psnr_subsurface_db, f.effect_db))
    table = {name: np.mean(rows, axis=0).round(2).tolist() for name, rows in scores.items()}
    for name, (whole, sss, effect) in table.items():
        print(f"{name:12s} whole {whole:6.2f}  subsurface {sss:6.2f}  effect {effect:6.2f} dB")
    (args.out / "eevee_denoise.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""What reading the mirror image for hidden surface buys (SSSParams.hidden_mirror).

For a scene already compared with ``cvsss compare`` (COMPARE: its
``ground_truth/`` and ``renders/<engine>_<n>/off_####.exr``), this renders the
scene's passes of the same frames with the compare's engine, posts them with
the mirror off and on, and scores each against the ground truth
(``core.eval.users_frame``: whole frame / subsurface pixels / subsurface
effect, dB, the mean over the frames):

- ``as_ccv`` (Apply on Render's method), on EEVEE with its subsurface pixels
  denoised as Apply on Render does (``EEVEE_DENOISE``), on Cycles as it comes
  out of the post (Cycles' finished-frame denoise needs the user's render);
- ``reference`` (1024 samples): the model's ceiling, not denoised.

From the repository root, after ``cvsss compare BLEND --frames 21-22 --engine
ENGINE --out COMPARE``::

    python tools/measure/hidden_mirror.py BLEND COMPARE OUT --frames 21-22 --engine EEVEE

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
from cvsss.sss_addon.blender.denoise_frame import EEVEE_DENOISE, denoise_frame

METHODS = ("as_ccv", "reference")


def _cvsss(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "cvsss.sss_addon.cli.main", *args], check=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("blend", type=Path)
    parser.add_argument("compare", type=Path, help="a cvsss compare folder of the same frames")
    parser.add_argument("out", type=Path)
    parser.add_argument("--frames", required=True, help="A-B, as the compare's")
    parser.add_argument("--engine", choices=("CYCLES", "EEVEE"), required=True)
    args = parser.parse_args()
    passes = args.out / "passes"
    _cvsss(
        "render", str(args.blend), "--frames", args.frames, "--out", str(args.out),
        "--engine", args.engine, "--passes-only", "--no-ground-truth", "--no-reference",
        "--no-denoise", "--quiet",
    )  # fmt: skip
    prefix = "eevee_" if args.engine == "EEVEE" else "cycles_"
    (renders,) = sorted((args.compare / "renders").glob(prefix + "*"))
    table = {}
    for mirror in ("false", "true"):
        post = args.out / f"mirror_{mirror}"
        _cvsss(
            "post", str(passes), "--out", str(post), "--method", ",".join(METHODS),
            "--hidden-mirror", mirror, "--no-denoise", "--quiet",
        )  # fmt: skip
        for method in METHODS:
            rows = []
            for path in sorted(passes.glob("*.exr")):
                number = path.stem
                result = read_result(post / method / f"{number}.exr")
                mask = result["Mask"] > 0
                image = np.ones((*mask.shape, 4), np.float32)
                image[..., :3] = result["Composite"][..., :3]
                if args.engine == "EEVEE" and method == "as_ccv":
                    image = denoise_frame(image, read_frame(path).albedo, None, EEVEE_DENOISE, mask)
                truth = read_rgb(args.compare / "ground_truth" / "material" / f"{number}.exr")
                truth_off = read_rgb(args.compare / "ground_truth" / "off" / f"{number}.exr")
                off = read_rgb(renders / f"off_{number}.exr")
                f = frame_figures(image, truth, truth_off, off)
                rows.append((f.psnr_whole_db, f.psnr_subsurface_db, f.effect_db))
            whole, sss, effect = np.mean(rows, axis=0).round(2).tolist()
            table[f"{method}, mirror {mirror}"] = [whole, sss, effect]
            print(
                f"{method:9s} mirror {mirror:5s}  whole {whole:6.2f}  subsurface {sss:6.2f}"
                f"  effect {effect:6.2f} dB"
            )
    (args.out / "hidden_mirror.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

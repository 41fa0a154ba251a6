"""What more samples per pixel buy Apply on Render on EEVEE (SSSParams.beta_max).

EEVEE's passes carry no noise: the post's samples bring all the noise of the
frame's subsurface pixels, and on a first frame (or a still) every pixel takes
``n_init`` = β_max of them (core.mc.adaptive). For a scene already compared with
``cvsss compare --engine EEVEE`` (COMPARE: its ``ground_truth/`` and
``renders/eevee_<n>/off_####.exr``), this renders the scene's EEVEE passes of
the same frames, posts them with ``as_ccv`` (Apply on Render's method) at each
β_max, denoises the subsurface pixels as Apply on Render does
(``EEVEE_DENOISE``) and scores each against the ground truth
(``core.eval.users_frame``: whole frame / subsurface pixels / subsurface
effect, dB, the mean over the frames). The post runs ``--rounds`` times per
β_max, alternating, and the time columns are the medians of the post's
``sampling_ms`` and ``frame_ms`` (``metrics.csv``) over rounds and frames.

From the repository root, after ``cvsss compare BLEND --frames 21-22 --engine
EEVEE --out COMPARE``::

    python tools/measure/eevee_samples.py BLEND COMPARE OUT --frames 21-22 \\
        --beta-max 64,128,256

(``python`` with ``bpy`` 5.0 and the ``cvsss`` package importable.)
"""

from __future__ import annotations

import csv
import json
import shutil

import numpy as np
from compared import Scorer, arguments, cvsss, render_passes, scored_post


def main() -> int:
    parser = arguments(__doc__, "a cvsss compare --engine EEVEE folder")
    parser.add_argument("--beta-max", default="64,128,256", help="comma-separated counts")
    parser.add_argument("--rounds", type=int, default=3, help="posts per count, alternating")
    args = parser.parse_args()
    counts = [int(v) for v in args.beta_max.split(",")]
    passes = render_passes(args.blend, args.frames, args.out, "EEVEE")
    score = Scorer(args.compare, "eevee_")
    times: dict[int, list[tuple[float, float]]] = {n: [] for n in counts}
    for _ in range(args.rounds):
        for n in counts:
            post = args.out / f"beta_max_{n}"
            shutil.rmtree(post, ignore_errors=True)
            cvsss(
                "post", str(passes), "--out", str(post), "--method", "as_ccv",
                "--beta-max", str(n), "--no-denoise", "--quiet",
            )  # fmt: skip
            with open(post / "metrics.csv", newline="") as handle:
                for row in csv.DictReader(handle):
                    times[n].append((float(row["sampling_ms"]), float(row["frame_ms"])))
    table = {}
    for n in counts:
        post = args.out / f"beta_max_{n}"
        whole, sss, effect = scored_post(post, "as_ccv", passes, score, denoise=True)
        sampling, frame = np.median(np.array(times[n]), axis=0).round(1).tolist()
        table[n] = {"whole": whole, "subsurface": sss, "effect": effect,
                    "sampling_ms": sampling, "frame_ms": frame}  # fmt: skip
        print(
            f"beta_max {n:4d}  whole {whole:6.2f}  subsurface {sss:6.2f}  effect {effect:6.2f} dB"
            f"  sampling {sampling:7.1f} ms  post {frame:7.1f} ms per frame"
        )
    (args.out / "eevee_samples.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

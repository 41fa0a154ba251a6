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

import json

from compared import Scorer, arguments, cvsss, render_passes, scored_post

METHODS = ("as_ccv", "reference")


def main() -> int:
    parser = arguments(__doc__, "a cvsss compare folder of the same frames")
    parser.add_argument("--engine", choices=("CYCLES", "EEVEE"), required=True)
    args = parser.parse_args()
    passes = render_passes(args.blend, args.frames, args.out, args.engine)
    score = Scorer(args.compare, "eevee_" if args.engine == "EEVEE" else "cycles_")
    table = {}
    for mirror in ("false", "true"):
        post = args.out / f"mirror_{mirror}"
        cvsss(
            "post", str(passes), "--out", str(post), "--method", ",".join(METHODS),
            "--hidden-mirror", mirror, "--no-denoise", "--quiet",
        )  # fmt: skip
        for method in METHODS:
            denoise = args.engine == "EEVEE" and method == "as_ccv"
            whole, sss, effect = scored_post(post, method, passes, score, denoise)
            table[f"{method}, mirror {mirror}"] = [whole, sss, effect]
            print(
                f"{method:9s} mirror {mirror:5s}  whole {whole:6.2f}  subsurface {sss:6.2f}"
                f"  effect {effect:6.2f} dB"
            )
    (args.out / "hidden_mirror.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

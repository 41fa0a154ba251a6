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
rgb_sss        the same, taken on the subsurface pixels only
albedo_sss     OIDN guided by EEVEE's Diffuse Color, on the subsurface pixels only
lighting_sss   OIDN on the post's lighting L (no albedo in it), no guides, the
               composite made again with it (what the add-on does,
               ``FrameDenoiser.finished``)
=============  ==================================================================

From the repository root, after ``cvsss compare BLEND --frames 21-22 --engine
EEVEE --out COMPARE``::

    python tools/measure/eevee_denoise.py BLEND COMPARE OUT --frames 21-22

(``python`` with ``bpy`` 5.0 and the ``cvsss`` package importable.)
"""

from __future__ import annotations

import json

from compared import Scorer, arguments, cvsss, finished, mean_row, render_passes

from cvsss.core.io.exr import read_frame
from cvsss.sss_addon.blender.denoise_frame import (
    EEVEE_DENOISE,
    DenoiseSettings,
    FrameDenoiser,
    denoise_frame,
)

VARIANTS = {
    "rgb": DenoiseSettings(prefilter="NONE", guides="RGB"),
    "rgb_sss": DenoiseSettings(prefilter="NONE", guides="RGB", subsurface_only=True),
    "albedo_sss": DenoiseSettings(prefilter="NONE", guides="RGB_ALBEDO", subsurface_only=True),
}


def main() -> int:
    parser = arguments(__doc__, "a cvsss compare --engine EEVEE folder")
    parser.add_argument("--method", default="as_ccv")
    args = parser.parse_args()
    passes = render_passes(args.blend, args.frames, args.out, "EEVEE")
    post = args.out / "post"
    cvsss(
        "post", str(passes), "--out", str(post), "--method", args.method, "--no-denoise", "--quiet"
    )
    score = Scorer(args.compare, "eevee_")
    scores: dict[str, list] = {}
    for path in sorted(passes.glob("*.exr")):
        number = path.stem
        frame = read_frame(path)
        image, result = finished(post, args.method, number)
        images = {"none": image}
        for name, settings in VARIANTS.items():
            images[name] = denoise_frame(image, frame.albedo, None, settings, result.mask)
        with FrameDenoiser(EEVEE_DENOISE) as denoiser:
            images["lighting_sss"] = denoiser.finished(image, result, frame, None)
        for name, each in images.items():
            scores.setdefault(name, []).append(score(each, number))
    table = {name: mean_row(rows) for name, rows in scores.items()}
    for name, (whole, sss, effect) in table.items():
        print(f"{name:12s} whole {whole:6.2f}  subsurface {sss:6.2f}  effect {effect:6.2f} dB")
    (args.out / "eevee_denoise.json").write_text(json.dumps(table, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

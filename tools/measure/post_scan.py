"""A post-process parameter scanned on pass files, against a ``cvsss compare`` run.

Apply on Render's frame is the post-process of its pass render, denoised as the
scene denoises (``cvsss post`` on the passes of ``cvsss render --passes-only
--denoise`` gives the same pixels). This script posts one scene's pass files
once per value of one ``cvsss post`` option (``--option contact --values
0.2,0.3``) and scores each finished frame the way ``cvsss compare`` scores the
user's frames (core.eval.users_frame: display space, the ground truth's
exposure, its subsurface mask) against that compare run's ground truth, beside
the run's plain render of the same frame. It prints, per value, the PSNR of the
whole frame and of the subsurface pixels (mean over the frames, dB) and their
gain over plain, and where the run kept each frame's Object Index
(``ground_truth/objects/``), the squared display error (mean over the channels)
summed over the subsurface pixels of ``--object`` within ``--ring`` px of any
other object, over the rest of that object, and over every other object.

A compare of frames 21-22 at 64 spp, then its passes and the scan, from the
repository root::

    .venv/bin/cvsss compare out/users/flash.blend --frames 21-22 --out out/cmp \\
        --engine CYCLES --samples 64
    (copy out/users/flash.blend with Cycles at 64 samples to out/flash64.blend)
    .venv/bin/cvsss render out/flash64.blend --frames 21-22 --out out/flash64 \\
        --passes-only --denoise --no-ground-truth --no-reference
    .venv/bin/python tools/measure/post_scan.py out/flash64/passes out/cmp \\
        --samples 64 --object "flash Marble Top" --option contact --values 0.2,0.3

EEVEE passes (``cvsss render --engine EEVEE``) are scored against the run's EEVEE
renders with ``--setting eevee_<samples>``. The method is ``--method`` (default
``as_ccv``); a temporal method's frames
after the first differ from Apply on Render's, which warms up before them.
``--hold name=value`` (repeatable) holds another option for every value, to scan
one option with another changed (``--hold hidden-mirror=false``).
``--backend numpy`` posts with the NumPy backend, where a rule not yet an
option can be tried in a scratch edit of ``core/mc/samples.py`` before its
twin in the compiled pass is written (the backends agree to float rounding).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from contact_bands import stored_objects
from scipy import ndimage

from cvsss.core.eval.users_frame import (
    display,
    effect_db,
    frame_exposure,
    lighting_scale,
    psnr_display,
    subsurface_mask,
)
from cvsss.core.io.exr import read_result, read_rgb


def post(
    passes: Path,
    out: Path,
    method: str,
    backend: str,
    option: str,
    value: str,
    hold: list[tuple[str, str]],
) -> Path:
    """Run ``cvsss post`` on ``passes`` with ``--option value`` and each held ``(name,
    value)``; the method's folder."""
    command = [sys.executable, "-m", "cvsss.sss_addon.cli.main", "post", str(passes),
               "--out", str(out), "--method", method, "--backend", backend, "--quiet",
               f"--{option}", value]  # fmt: skip
    for name, held_value in hold:
        command += [f"--{name}", held_value]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
    return out / method


def regions(compare: Path, frame: int, mask: np.ndarray, target: str, ring: int):
    """The subsurface pixels of ``target`` within ``ring`` px of another object, the rest
    of them, and those of every other object; None where the run kept no Object Index."""
    stored = stored_objects(compare, frame)
    if stored is None:
        return None
    index, names = stored
    number = next((n for n, name in names.items() if name == target), None)
    if number is None:
        raise SystemExit(f"error: {compare} shows no object {target!r}")
    mine = index == number
    near = ndimage.binary_dilation(~mine & (index != 0), iterations=ring)
    return mine & mask & near, mine & mask & ~near, mask & ~mine


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("passes", type=Path, help="the pass files (####.exr, ####.json)")
    parser.add_argument("compare", type=Path, help="the cvsss compare --out folder")
    parser.add_argument("--samples", type=int, help="the plain render's spp (Cycles)")
    parser.add_argument(
        "--setting", help="the compare's renders/<setting> (default cycles_<samples>_denoised)"
    )
    parser.add_argument("--option", required=True, help="a cvsss post option, without --")
    parser.add_argument("--values", required=True, help="comma-separated values")
    parser.add_argument(
        "--hold",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="another cvsss post option, without --, held at VALUE for every value (repeatable)",
    )
    parser.add_argument("--object", required=True, help="the object whose borders to score")
    parser.add_argument("--ring", type=int, default=4, help="px round the other objects")
    parser.add_argument("--method", default="as_ccv")
    parser.add_argument(
        "--backend", default="auto", help="cvsss post's; numpy runs a scratch change to core/mc/"
    )
    parser.add_argument("--variant", default="material", help="the compare's method variant")
    args = parser.parse_args()
    hold = []
    for held in args.hold:
        name, equals, held_value = held.partition("=")
        if not (name and equals):
            raise SystemExit(f"error: --hold takes NAME=VALUE, got {held!r}")
        hold.append((name, held_value))
    frames = sorted(int(p.stem) for p in args.passes.glob("[0-9]*.exr"))
    if not frames:
        raise SystemExit(f"error: no pass files in {args.passes}")
    if args.setting is None and args.samples is None:
        raise SystemExit("error: give --samples or --setting")
    renders = args.compare / "renders" / (args.setting or f"cycles_{args.samples}_denoised")
    truths = {}
    for f in frames:
        truth = read_rgb(args.compare / "ground_truth" / args.variant / f"{f:04d}.exr")
        truth_off = read_rgb(args.compare / "ground_truth" / "off" / f"{f:04d}.exr")
        k = frame_exposure(truth)
        mask = subsurface_mask(truth, truth_off, k)
        plain = read_rgb(renders / f"{args.variant}_plain_{f:04d}.exr")
        off = read_rgb(renders / f"off_{f:04d}.exr")
        parts = regions(args.compare, f, mask, args.object, args.ring)
        truths[f] = truth, k, mask, plain, parts, truth_off, off

    def score(images: dict[int, np.ndarray]) -> tuple[float, float, float, list[float]]:
        whole, sss, effect, sse = [], [], [], np.zeros(3)
        for f, image in images.items():
            truth, k, mask, _, parts, truth_off, off = truths[f]
            whole.append(psnr_display(image, truth, k))
            sss.append(psnr_display(image, truth, k, mask))
            s = lighting_scale(truth_off, off, mask)
            effect.append(effect_db(image, off, truth, truth_off, mask, k, s))
            if parts is not None:
                error = ((display(image, k) - display(truth, k))[..., :3] ** 2).mean(axis=-1)
                sse += [error[part].sum() for part in parts]
        return float(np.mean(whole)), float(np.mean(sss)), float(np.mean(effect)), list(sse)

    plain = score({f: t[3] for f, t in truths.items()})
    head = f"{'':>14s} {'whole dB':>9s} {'sss dB':>7s} {'gain':>13s} {'effect dB':>10s}"
    held = "".join(f", {h}" for h in args.hold)
    print(f"{args.passes}, frames {frames[0]}-{frames[-1]}; {args.option} scanned{held}")
    print(head + f"   SSE {args.object} <= {args.ring} px / rest / other objects")

    def row(label, figures):
        whole, sss, effect, sse = figures
        gain = f"{whole - plain[0]:+.2f} / {sss - plain[1]:+.2f}"
        regions_ = " / ".join(f"{v:.2f}" for v in sse) if truths[frames[0]][4] is not None else "—"
        print(f"{label:>14s} {whole:9.2f} {sss:7.2f} {gain:>13s} {effect:10.2f}   {regions_}")

    row("plain", plain)
    with tempfile.TemporaryDirectory() as folder:
        for value in args.values.split(","):
            out = Path(folder) / value
            result = post(args.passes, out, args.method, args.backend, args.option, value, hold)
            row(
                f"{value}",
                score({f: read_result(result / f"{f:04d}.exr")["Composite"] for f in frames}),
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

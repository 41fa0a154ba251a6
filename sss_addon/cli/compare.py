"""``cvsss compare``: the user's frame against what they had, on their own .blend.

    cvsss compare scene.blend --frames 1-3 --out out/compare \\
        [--engine CYCLES,EEVEE] [--samples 16,64] [--eevee-samples N] \\
        [--method-variants material,RANDOM_WALK,BURLEY] [--ground-truth-spp 4096]

renders the frames plain (the scene's engine as set, Cycles with its own
denoiser), with Apply on Render (the scene's add-on settings) and without
subsurface, and Cycles' ground truth with and without subsurface, and writes
``OUT/users_frame.json`` and ``OUT/users_frame.md``
(:mod:`..blender.compare`). The .blend is never saved.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from ...core.eval.users_frame import TRUTH_SAMPLES
from .params import UserError

ENGINES = ("CYCLES", "EEVEE")
VARIANTS = ("material", "RANDOM_WALK", "BURLEY")

#: Cycles' hard limit on samples per pixel.
MAX_SAMPLES = 2**24


def add_parser(subparsers: Any) -> None:
    """Add the ``compare`` subcommand to ``subparsers`` (of ``cvsss``)."""
    p = subparsers.add_parser(
        "compare",
        help="the user's frame against Cycles' ground truth: plain render, Apply on Render, "
        "seconds per frame (needs bpy)",
        description="Render a .blend's frames as its user would (the scene's engine, then "
        "with Apply on Render) and measure both against Cycles' ground truth with each "
        "material's own subsurface method: PSNR over the whole frame and the subsurface "
        "pixels, the subsurface effect, seconds per frame. Writes OUT/users_frame.json and "
        "OUT/users_frame.md.",
    )
    p.add_argument("blend", type=Path, help=".blend file to open (never saved)")
    p.add_argument(
        "--frames", required=True, help="frame range A-B or one frame A (rendered as one range)"
    )
    p.add_argument("--out", type=Path, required=True, help="output directory")
    p.add_argument(
        "--engine",
        default="CYCLES,EEVEE",
        help="comma-separated engines to render the user's frames with (default CYCLES,EEVEE)",
    )
    p.add_argument(
        "--samples",
        default=None,
        help="comma-separated Cycles samples per pixel, one setting each (default: the scene's)",
    )
    p.add_argument(
        "--eevee-samples",
        type=int,
        default=None,
        metavar="N",
        help="EEVEE's render samples (default: the scene's)",
    )
    p.add_argument(
        "--denoise",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="Cycles' own denoiser in the plain render (default on, as in Blender)",
    )
    p.add_argument(
        "--method-variants",
        default="material",
        help="comma-separated subsurface methods: material (the materials' own), "
        "RANDOM_WALK, BURLEY (every Principled BSDF switched, ground truth included); "
        "default material",
    )
    p.add_argument(
        "--ground-truth-spp",
        type=int,
        default=TRUTH_SAMPLES,
        metavar="N",
        help=f"samples per pixel of Cycles' ground truth (default {TRUTH_SAMPLES}: fewer "
        "leave noise that narrows the gap between the rows)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines")


def _names(flag: str, text: str, allowed: tuple[str, ...]) -> list[str]:
    """The comma-separated names of ``text``, spelt as in ``allowed`` (case ignored)."""
    spelling = {a.lower(): a for a in allowed}
    names = [spelling.get(n.strip().lower(), n.strip()) for n in text.split(",") if n.strip()]
    bad = [n for n in names if n not in allowed]
    if not names or bad:
        raise UserError(
            f"{flag} must be a comma-separated list of {', '.join(allowed)}; got {text!r}"
        )
    return list(dict.fromkeys(names))


def _samples(flag: str, value: int) -> int:
    if not 1 <= value <= MAX_SAMPLES:
        raise UserError(f"{flag} must be in [1, {MAX_SAMPLES}], got {value}")
    return value


def settings_from_args(args: argparse.Namespace) -> list:
    """The :class:`..blender.users_frame.Setting` list of ``--engine``, ``--samples``,
    ``--eevee-samples`` and ``--denoise`` (as plain tuples until Blender is there):
    ``(engine, samples or None, denoise)``."""
    engines = _names("--engine", args.engine, ENGINES)
    cycles = [None]
    if args.samples is not None:
        try:
            cycles = [int(s) for s in args.samples.split(",") if s.strip()]
        except ValueError:
            cycles = []
        if not cycles:
            raise UserError(
                f"--samples must be comma-separated whole numbers, got {args.samples!r}"
            )
        cycles = [_samples("--samples", s) for s in dict.fromkeys(cycles)]
    eevee = None if args.eevee_samples is None else _samples("--eevee-samples", args.eevee_samples)
    out = []
    for engine in engines:
        if engine == "CYCLES":
            out += [("CYCLES", s, bool(args.denoise)) for s in cycles]
        else:
            out.append(("EEVEE", eevee, False))
    return out


def run(args: argparse.Namespace, frames: tuple[int, int]) -> int:
    """``compare`` with ``frames`` parsed by the caller (``--frames``, as ``render`` parses it)."""
    settings = settings_from_args(args)
    variants = _names("--method-variants", args.method_variants, VARIANTS)
    _samples("--ground-truth-spp", args.ground_truth_spp)
    if not args.blend.is_file():
        raise UserError(f"{args.blend}: no such .blend file")
    try:
        import bpy
    except ImportError:
        raise UserError(
            "the compare command needs Blender: install bpy==5.0.1 or run it inside Blender "
            "(blender -b --python main.py -- compare …)"
        ) from None
    # Imported here: they import bpy, which every other command runs without.
    from ..blender.compare import compare_scene
    from ..blender.errors import RenderError
    from ..blender.standalone import ensure_registered
    from ..blender.users_frame import Setting

    unregister = ensure_registered()
    try:
        try:
            bpy.ops.wm.open_mainfile(filepath=str(args.blend.absolute()), load_ui=False)
        except RuntimeError as exc:
            reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unreadable"
            raise UserError(f"{args.blend}: not a readable .blend file ({reason})") from None
        try:
            report = compare_scene(
                bpy.context.scene,
                frames,
                args.out,
                [Setting(*s) for s in settings],
                variants,
                truth_samples=args.ground_truth_spp,
                log=None if args.quiet else print,
            )
        except RenderError as exc:
            raise UserError(str(exc)) from None
    finally:
        if unregister is not None:
            unregister()
    if not args.quiet:
        print((args.out / "users_frame.md").read_text(encoding="utf-8"))
        print(f"wrote {args.out / 'users_frame.json'} ({len(report['rows'])} rows)")
    return 0

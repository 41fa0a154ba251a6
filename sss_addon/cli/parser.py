"""The ``cvsss`` command line's parser: its subcommands, their flags, and the checks of
what argparse cannot check (frame ranges, method lists, counts).

Every algorithm parameter is a flag generated from its spec in core.params
(:mod:`.params`); :func:`build_parser` is also what ``tools/reference.py`` reads
to write docs/reference/cli.md.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from ...core.eval.users_frame import TRUTH_SAMPLES
from ...core.methods import METHODS
from ..blender.whole_parts import whole_parts_text
from . import bench, compare, studies
from .params import UserError, add_arguments

EXIT_USAGE = 2


def parse_methods(text: str) -> list[str]:
    names = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in names if m not in METHODS]
    if not names or bad:
        raise UserError(
            f"--method must be a comma-separated list of {', '.join(METHODS)}; got {text!r}"
        )
    return names


#: Blender's last frame number (MAXFRAME); also the largest side of a render (pixels).
MAX_FRAME = 1048574
MAX_SIDE = 65536


def parse_frames(text: str) -> tuple[int, int]:
    """``"A-B"`` or ``"A"`` -> inclusive (A, B) with 0 <= A <= B <= MAX_FRAME."""
    parts = text.strip().split("-")
    try:
        start, end = (int(parts[0]), int(parts[-1])) if len(parts) <= 2 else (None, None)
    except ValueError:
        start = end = None
    if start is None or start < 0 or end < start or end > MAX_FRAME:
        raise UserError(
            f"--frames must be A-B with 0 <= A <= B <= {MAX_FRAME} (Blender's last frame), "
            f"or one frame A; got {text!r}"
        )
    return start, end


def _farm_arguments(parser: argparse.ArgumentParser, split: str) -> None:
    """``--workers N | --scheduler ADDRESS`` and ``--tile`` (post) or ``--chunk`` (render)."""
    group = parser.add_argument_group(
        "distribution (Dask; needs the cvsss[farm] extra)",
        "post: each frame is split into tiles with a halo that run on the workers, with "
        "output identical bit for bit to the run without workers; render: the passes are "
        "rendered in frame chunks, one Blender process per chunk",
    )
    where = group.add_mutually_exclusive_group()
    where.add_argument(
        "--workers",
        type=int,
        default=None,
        metavar="N",
        help="start a local Dask cluster of N worker processes on 127.0.0.1",
    )
    where.add_argument(
        "--scheduler",
        default=None,
        metavar="tcp://HOST:PORT",
        help="use the running Dask scheduler at this address (workers with cvsss[farm] "
        "installed and the same paths)",
    )
    group.add_argument(
        "--tile",
        type=int,
        default=256,
        metavar="PX",
        help="tile side in pixels of the post (default 256); the halo is computed per frame",
    )
    if split == "chunk":
        group.add_argument(
            "--chunk",
            type=int,
            default=8,
            metavar="FRAMES",
            help="frames per pass-rendering task (default 8)",
        )


def wants_workers(args: argparse.Namespace) -> bool:
    """Whether workers were asked for (and the values are sane)."""
    if args.workers is not None:
        check_at_least_one("--workers", args.workers)
    for flag in ("tile", "chunk"):
        if getattr(args, flag, None) is not None:
            check_at_least_one(f"--{flag}", getattr(args, flag))
    if args.scheduler is not None and "://" not in args.scheduler:
        raise UserError(
            f"--scheduler must be an address like tcp://HOST:PORT, got {args.scheduler!r}"
        )
    return args.workers is not None or args.scheduler is not None


def _reference_every(parser: argparse.ArgumentParser, default: int, text: str) -> None:
    parser.add_argument("--reference-every", type=int, default=default, metavar="K", help=text)


def check_at_least_one(flag: str, value: int) -> None:
    if value < 1:
        raise UserError(f"{flag} must be >= 1, got {value}")


class _Parser(argparse.ArgumentParser):
    """argparse with its errors as one line (the usage is a ``--help`` away), like ours."""

    def error(self, message: str):
        self.exit(EXIT_USAGE, f"error: {self.prog}: {message} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="cvsss",
        description="Adaptive control-variate screen-space subsurface scattering.",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    methods = ", ".join(METHODS)

    post = sub.add_parser("post", help="post-process a directory of pass EXRs (no Blender)")
    post.add_argument("passes", type=Path, help="directory of per-frame pass EXRs (0001.exr …)")
    post.add_argument("--out", type=Path, required=True, help="output directory")
    post.add_argument(
        "--method",
        default="as_ccv",
        help=f"method or comma-separated methods: {methods} (default as_ccv)",
    )
    post.add_argument(
        "--reference",
        action="store_true",
        help="also compute the reference and report PSNR against it",
    )
    existing = post.add_mutually_exclusive_group()
    existing.add_argument(
        "--overwrite", action="store_true", help="replace existing results, checkpoints and metrics"
    )
    existing.add_argument(
        "--resume",
        action="store_true",
        help="continue an interrupted run after each method's checkpoint "
        "(<out>/<method>/.checkpoint.npz); results are bit-identical",
    )
    post.add_argument(
        "--allow-gaps",
        action="store_true",
        help="accept missing frame numbers (history runs across the gap)",
    )
    _reference_every(
        post,
        1,
        "with --reference: compute it (and PSNR) on every K-th frame only (default 1: every frame)",
    )
    post.add_argument(
        "--ground-truth",
        type=Path,
        default=None,
        metavar="DIR",
        help="folder of ground-truth EXRs (####.exr: Cycles' Combined with subsurface on, as "
        "`cvsss render --ground-truth` writes them) to measure against; default: "
        "PASSES/../ground_truth when it exists",
    )
    post.add_argument(
        "--denoise",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="denoise each method's finished frame as the pass files' sidecars record "
        '("denoise": the scene\'s Cycles denoiser settings, written by `cvsss render` when '
        "it denoises; the pass files then hold the denoiser's guides); needs Blender's "
        "OpenImageDenoise (bpy); default: when the sidecars record it",
    )
    post.add_argument("--quiet", action="store_true", help="no per-frame progress")
    _farm_arguments(post, "tile")
    post.add_argument(
        "--quality",
        default=None,
        help="target PSNR like 45dB or mean sample budget like 24spp; picks σ0² (and β_min, or "
        "N for fixed) from the bench's calibration (core/data/quality_calibration.json)",
    )
    add_arguments(post)

    demo = sub.add_parser("demo", help="the main job: passes, every method, report")
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory")
    demo.add_argument(
        "--source",
        choices=("blender", "synthetic"),
        default="blender",
        help="passes rendered from the demo_blend scenes with Blender (default) "
        "or generated analytically (no Blender)",
    )
    demo.add_argument(
        "--scenes",
        default=None,
        help="comma-separated scene names (default: all of the source: "
        "flash,regular,boids for blender; flash,regular for synthetic)",
    )
    demo.add_argument("--res", default="320x180", help="resolution WxH in pixels (default 320x180)")
    demo.add_argument(
        "--frames", type=int, default=120, help="frames per scene at 60 fps (default 120)"
    )
    _reference_every(
        demo,
        5,
        "reference (1024 spp) and PSNR on every K-th frame (default 5: coprime with the "
        "12-frame flash period, so every phase is measured)",
    )
    demo.add_argument(
        "--engine",
        choices=("CYCLES", "EEVEE"),
        default="CYCLES",
        help="render engine of the blender passes (default CYCLES)",
    )
    demo.add_argument(
        "--samples",
        type=int,
        default=16,
        help="render samples per pixel of the blender passes (default 16)",
    )
    demo.add_argument(
        "--ground-truth-every",
        type=int,
        default=20,
        metavar="K",
        help="render Cycles ground truth (subsurface on) on every K-th frame and measure "
        "every method against it, with the equal-time comparison (default 20; 0: off; "
        "blender source with Cycles only)",
    )
    demo.add_argument(
        "--ground-truth-spp",
        type=int,
        default=1024,
        help="samples per pixel of the ground truth (default 1024)",
    )
    demo.add_argument(
        "--compare-frames",
        type=int,
        default=2,
        metavar="K",
        help="frames (from frame 21) of the 'what you had / what you get' table: plain Cycles "
        "with its denoiser, plain EEVEE and Apply on Render on each against the ground truth, "
        "with seconds per frame (default 2; 0: off; with the ground truth only)",
    )
    demo.add_argument(
        "--compare-ground-truth-spp",
        type=int,
        default=TRUTH_SAMPLES,
        metavar="N",
        help="samples per pixel of that table's ground truth (default "
        f"{TRUTH_SAMPLES}, as cvsss compare's)",
    )
    demo.add_argument("--overwrite", action="store_true", help="make the passes again")
    add_arguments(demo)

    rnd = sub.add_parser(
        "render", help="render a .blend's passes with Blender and post-process them (needs bpy)"
    )
    rnd.add_argument(
        "blend",
        nargs="?",
        type=Path,
        default=None,
        help=".blend file to open, never saved (default: the file Blender has open)",
    )
    rnd.add_argument(
        "--frames", default=None, help="frame range A-B or one frame A (default: the scene's range)"
    )
    rnd.add_argument("--out", type=Path, required=True, help="output directory")
    rnd.add_argument(
        "--method",
        default=None,
        help=f"method or comma-separated methods: {methods} (default: the scene's cvsss setting)",
    )
    rnd.add_argument(
        "--engine",
        choices=("CYCLES", "EEVEE"),
        default=None,
        help="render engine of the passes (default: the scene's cvsss setting)",
    )
    rnd.add_argument(
        "--reference",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="compute the reference for PSNR (default: the scene's cvsss setting)",
    )
    rnd.add_argument(
        "--overwrite",
        action="store_true",
        help="render pass frames again even if their files exist, and start the "
        "post-process over (otherwise it resumes where a run with the same settings stopped)",
    )
    _reference_every(
        rnd,
        1,
        "with the reference: compute it (and PSNR) on every K-th frame only "
        "(default 1: every frame)",
    )
    rnd.add_argument(
        "--denoise",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="denoise each method's finished frame as the scene's Cycles denoiser would (its "
        "prefilter, quality and guides; OpenImageDenoise, guided by the pass render's "
        "Denoising Albedo and Normal, which the pass files keep; their sidecars record the "
        'settings as "denoise"); default: when the scene\'s render denoises and the '
        "passes are not denoised (--denoise-passes). EEVEE passes: the post's light on the "
        "subsurface pixels only, without guides, before the albedo multiplies it (EEVEE's "
        "passes carry no noise, the post's samples do); default: the scene's Denoise "
        "Subsurface",
    )
    rnd.add_argument(
        "--denoise-passes",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="denoise Combined and the Diffuse passes with Blender's OpenImageDenoise (guided "
        "by Cycles' Denoising Albedo and Normal) before the post reads them; Cycles passes "
        "only; pass files made with the other setting are rendered again; instead of "
        "--denoise (default: the scene's cvsss setting)",
    )
    rnd.add_argument(
        "--thin-walks",
        choices=("cycles", "post"),
        default=None,
        help=f"who renders the subsurface of objects {whole_parts_text()}, and of "
        "points near their own far side or an edge (ears, fins, rims) of both, on Cycles "
        "passes: cycles (as "
        "a plain render; its walk and its disk probes reach surface the post cannot see) or "
        "post; default: the scene's Thin Parts",
    )
    rnd.add_argument(
        "--warmup-frames",
        type=int,
        default=0,
        metavar="N",
        help="render and process N frames before the first one, without writing them, so the "
        "first result has a history (as Apply on Render does with the scene's Warm-up "
        "Frames; default 0)",
    )
    truth = rnd.add_argument_group("ground truth (Cycles with its own subsurface on)")
    truth.add_argument(
        "--ground-truth",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="also render the frames with Cycles' own subsurface on into OUT/ground_truth/"
        "####.exr and report PSNR against it in metrics.csv (psnr_gt_db, …); always rendered "
        "with Cycles, also when the passes use --engine EEVEE; denoising off, fixed seed "
        "(default: the scene's cvsss setting)",
    )
    truth.add_argument(
        "--ground-truth-spp",
        type=int,
        default=None,
        metavar="N",
        help="samples per pixel of the ground truth (default: the scene's cvsss setting, 1024)",
    )
    truth.add_argument(
        "--ground-truth-every",
        type=int,
        default=None,
        metavar="K",
        help="render the ground truth on the 1st, (K+1)-th, … frame of the range only "
        "(default: the scene's cvsss setting, 1)",
    )
    truth.add_argument(
        "--ground-truth-method",
        choices=("material", "burley", "random_walk"),
        default=None,
        help="Cycles' subsurface method of the ground truth: material (each material's own "
        "Subsurface Method: Christensen-Burley, Random Walk or Random Walk (Skin), which the "
        "post models per material), or burley or random_walk forced on every material "
        "(default: the scene's cvsss setting, material)",
    )
    scripts = rnd.add_argument_group(
        "Python in the .blend (drivers with Python expressions, registered text blocks)",
        "run as Blender runs them for the file: its Auto Run Python Scripts preference "
        "decides (off unless set), -y/-Y as blender -y/-Y; when they do not run, one "
        "warning line names them. With the file Blender opened (blender -b FILE --python "
        "main.py -- render …), Blender's own -y/-Y decides",
    ).add_mutually_exclusive_group()
    scripts.add_argument(
        "-y",
        "--enable-autoexec",
        dest="autoexec",
        action="store_const",
        const=True,
        default=None,
        help="run them (trust the file), as blender -y does",
    )
    scripts.add_argument(
        "-Y",
        "--disable-autoexec",
        dest="autoexec",
        action="store_const",
        const=False,
        help="never run them, whatever the preference, as blender -Y does",
    )
    rnd.add_argument("--quiet", action="store_true", help="no per-frame progress")
    rnd.add_argument(
        "--passes-only",
        action="store_true",
        help="render the passes (and the ground truth, when asked) only: no post-process, "
        "no results, no metrics (post them later with cvsss post OUT/passes)",
    )
    # Set by a distributed render on each chunk: the first frame of the whole range,
    # so the ground truth falls on every K-th frame of the range, not of the chunk.
    rnd.add_argument("--range-start", type=int, default=None, help=argparse.SUPPRESS)
    _farm_arguments(rnd, "chunk")
    add_arguments(rnd)

    bench.add_parser(sub)
    compare.add_parser(sub)
    studies.add_parsers(sub)
    return parser

"""The ``cvsss`` command line.

Subcommands
-----------
post    post-process a directory of pass EXRs (no Blender needed)
render  render a .blend's passes with Blender (bpy) and post-process them
demo    the main job end to end (passes, every method, summary + report)
cv1d    the coefficient study of SPEC §9 (writes out/cv1d.json + plot)
fig2    the 1D motivating example (writes out/fig2.json + plot)
bench   speed and the speed/accuracy trade, measured (writes out/bench/bench.json + plots)

Run inside Blender too: ``blender -b scene.blend --python sss_addon/cli/main.py --
<subcommand> …``; arguments after ``--`` are read.

User errors (bad parameters, missing or corrupt passes, unwritable folders)
print one ``error:`` line and exit with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.util
import sys
from pathlib import Path

if __package__ in (None, ""):
    # Run as a script (``blender --python cli.py`` or ``python cli.py``): load
    # the extension root as the package ``cvsss`` so relative imports work.
    _root = Path(__file__).resolve().parent.parent.parent
    if "cvsss" not in sys.modules:
        _spec = importlib.util.spec_from_file_location(
            "cvsss", _root / "__init__.py", submodule_search_locations=[str(_root)]
        )
        _mod = importlib.util.module_from_spec(_spec)
        sys.modules["cvsss"] = _mod
        _spec.loader.exec_module(_mod)
    __package__ = "cvsss.sss_addon.cli"

from ...core.methods import METHODS
from ...core.params import SSSParams

EXIT_USAGE = 2

#: CLI flag → SSSParams field, with the help text (units in brackets).
PARAM_FLAGS = {
    "eta": ("eta", float, "η, history exponential moving coefficient (0, 1]"),
    "target-variance": (
        "target_variance",
        float,
        "σ0², target variance of tracked luminance (> 0)",
    ),
    "eps-u": ("eps_u", float, "ε_u, zero samples where max γ < ε_u [0, 1]"),
    "eps-alpha": ("eps_alpha", float, "ε_α, CV coefficient suppressing constant (>= 0)"),
    "kappa": ("kappa", float, "κ, weight of the SPVG correction term [0, 1]"),
    "beta-min": ("beta_min", int, "β_min, minimum adaptive sample count (>= 1)"),
    "beta-max": ("beta_max", int, "β_max, maximum adaptive sample count (<= 4096)"),
    "eta-cv": ("eta_cv", float, "η_cv, CV covariance exponential moving coefficient (0, 1]"),
    "fixed-spp": ("fixed_spp", int, "samples per pixel of the 'fixed' method"),
    "reference-spp": ("reference_spp", int, "samples per pixel of the 'reference' method"),
    "seed": ("seed", int, "seed of the per-pixel hash (same seed ⇒ identical output)"),
    "history-precision": ("history_precision", str, "float32 or float16 history storage"),
    "exposure": ("exposure", float, "linear exposure applied before tracking and PSNR"),
    "burley-inverse": ("burley_inverse", str, "exact or fast Burley radius sampler"),
    "depth-slope": ("depth_slope", float, "follow-surface depth tolerance per unit radius"),
}


class UserError(Exception):
    """A problem the user can fix; printed as one line, exit status 2."""


def add_param_arguments(parser: argparse.ArgumentParser) -> None:
    """Add one ``--flag`` per SSSParams field (defaults: the paper's)."""
    group = parser.add_argument_group("algorithm parameters (defaults: the paper's)")
    for flag, (dest, typ, text) in PARAM_FLAGS.items():
        group.add_argument(f"--{flag}", dest=dest, type=typ, default=None, help=text)


def params_from_args(args: argparse.Namespace) -> SSSParams:
    """Build SSSParams from parsed flags (unset flags keep the defaults)."""
    values = {dest: getattr(args, dest) for _, (dest, _, _) in PARAM_FLAGS.items()}
    return SSSParams(**{k: v for k, v in values.items() if v is not None})


def parse_methods(text: str) -> list[str]:
    names = [m.strip() for m in text.split(",") if m.strip()]
    bad = [m for m in names if m not in METHODS]
    if not names or bad:
        raise UserError(
            f"--method must be a comma-separated list of {', '.join(METHODS)}; got {text!r}"
        )
    return names


def add_profile_arguments(parser: argparse.ArgumentParser) -> None:
    """Profile (P Table 2), measured-material and separable-SSS flags."""
    from ...core.profiles.factory import PROFILE_NAMES
    from ...core.profiles.presets import names
    from ...core.separable.kernels import KERNELS, TAP_COUNTS

    group = parser.add_argument_group("profiles and separable SSS")
    group.add_argument(
        "--profile",
        choices=PROFILE_NAMES,
        default=None,
        help="diffusion profile of every SSS material (default: each material's "
        "own, Burley from the Principled BSDF)",
    )
    group.add_argument(
        "--material",
        default=None,
        metavar="PRESET|SLOT=PRESET,...",
        help="measured material for every SSS slot, or per slot (1=skin1,2=marble): "
        f"{', '.join(names())}",
    )
    group.add_argument(
        "--mm-per-unit",
        type=float,
        default=1000.0,
        help="millimetres per scene unit for --material (default 1000: metres)",
    )
    group.add_argument(
        "--preset-scale",
        type=float,
        default=1.0,
        help="artist scale of --material scattering distances (default 1: real size)",
    )
    group.add_argument(
        "--kernel",
        choices=KERNELS,
        default="pre_integrated",
        help="separable-SSS kernel (method separable; default pre_integrated)",
    )
    group.add_argument(
        "--taps",
        type=int,
        choices=TAP_COUNTS,
        default=17,
        help="taps per 1D pass of method separable (default 17)",
    )
    group.add_argument(
        "--jitter",
        action="store_true",
        help="jitter the taps within 33%% of the separable kernel's range per pixel "
        "(against banding)",
    )
    group.add_argument(
        "--gaussians",
        type=int,
        default=4,
        help="N of --kernel gaussians, 1..6 (2N passes; default 4)",
    )
    group.add_argument(
        "--follow",
        choices=("slope", "exponential"),
        default="slope",
        help="separable follow-surface rule: the Monte Carlo estimator's "
        "(--depth-slope, default) or the supplementary's exponential",
    )
    group.add_argument(
        "--filter",
        choices=("nearest", "linear"),
        default="nearest",
        help="separable tap reads: nearest pixel (default) or linear",
    )


def processor_options(args: argparse.Namespace, methods: list[str]) -> dict:
    """SequenceProcessor keywords from the profile / separable flags (empty: defaults)."""
    from ...core.profiles.factory import ProfileChoice, make_profile_factory
    from ...core.separable.kernels import SeparableParams

    options = {}
    try:
        material, pairs = (
            (None, ()) if args.material is None else ProfileChoice.parse_material(args.material)
        )
        choice = ProfileChoice(
            profile=args.profile,
            material=material,
            slot_materials=pairs,
            mm_per_unit=args.mm_per_unit,
            scale=args.preset_scale,
        )
    except ValueError as exc:
        raise UserError(f"--material/--profile: {exc}") from None
    if not choice.is_default:
        options["profile_factory"] = make_profile_factory(choice)
        _check_first_frame(args.passes, choice)
    if "separable" in methods:
        options["separable"] = SeparableParams(
            kernel=args.kernel,
            taps=args.taps,
            jitter=args.jitter,
            gaussians=args.gaussians,
            follow=args.follow,
            filter=args.filter,
        )
    return options


def _check_first_frame(passes: Path, choice) -> None:
    """Refuse a profile choice the first frame's materials cannot take, before any output."""
    from ...core.io.exr import PassError, list_frames, read_sidecar
    from ...core.profiles.factory import check_materials

    try:
        first = list_frames(passes)[0][1]
        materials = read_sidecar(first.with_suffix(".json"), exr_path=first).materials
    except (PassError, IndexError):
        return  # post_process reports unusable passes itself
    check_materials(materials, choice)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cvsss",
        description="Adaptive control-variate screen-space subsurface scattering.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    post = sub.add_parser("post", help="post-process a directory of pass EXRs (no Blender)")
    post.add_argument("passes", type=Path, help="directory of per-frame pass EXRs (0001.exr …)")
    post.add_argument("--out", type=Path, required=True, help="output directory")
    post.add_argument(
        "--method",
        default="as_ccv",
        help=f"method or comma-separated methods: {', '.join(METHODS)} (default as_ccv)",
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
        "(<out>/<method>/.history.npz); results are bit-identical",
    )
    post.add_argument(
        "--allow-gaps",
        action="store_true",
        help="accept missing frame numbers (history runs across the gap)",
    )
    post.add_argument(
        "--reference-every",
        type=int,
        default=1,
        metavar="K",
        help="with --reference: compute it (and PSNR) on every K-th frame only "
        "(default 1: every frame)",
    )
    post.add_argument("--quiet", action="store_true", help="no per-frame progress")
    post.add_argument(
        "--quality",
        default=None,
        help="target PSNR like 45dB or mean sample budget like 24spp; picks σ0² (and β_min, or "
        "N for fixed) from the bench's calibration (core/data/quality_calibration.json)",
    )
    add_param_arguments(post)
    add_profile_arguments(post)

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
    demo.add_argument(
        "--reference-every",
        type=int,
        default=5,
        metavar="K",
        help="reference (1024 spp) and PSNR on every K-th frame (default 5: coprime with the 12-frame flash period, so every phase is measured)",
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
    demo.add_argument("--overwrite", action="store_true", help="make the passes again")
    add_param_arguments(demo)

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
        help=f"method or comma-separated methods: {', '.join(METHODS)} "
        "(default: the scene's cvsss setting)",
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
        help="render pass frames again even if their files exist",
    )
    rnd.add_argument(
        "--reference-every",
        type=int,
        default=1,
        metavar="K",
        help="with the reference: compute it (and PSNR) on every K-th frame only "
        "(default 1: every frame)",
    )
    rnd.add_argument("--quiet", action="store_true", help="no per-frame progress")
    add_param_arguments(rnd)

    from ...core.eval.bench import build_parser as bench_parser

    bench_parser(
        sub.add_parser(
            "bench",
            help="speed and the speed/accuracy trade, measured (no Blender)",
            description="Writes bench.json, quality_calibration.json and plots to --out.",
        )
    )

    for name, text in (
        ("cv1d", "the CV coefficient study (SPEC §9)"),
        ("fig2", "the 1D motivating example (P Fig. 2)"),
    ):
        p = sub.add_parser(name, help=text)
        p.add_argument("--out", type=Path, default=Path("out"), help="output directory")
        p.add_argument("--seeds", type=int, default=None, help="number of seeds / streams")
        p.add_argument("--seed", type=int, default=0, help="base seed")
    return parser


def _run_study(module: str, args: argparse.Namespace) -> int:
    mod = importlib.import_module(f"...core.studies.{module}", __package__)
    argv = ["--out", str(args.out), "--seed", str(args.seed)]
    if args.seeds is not None:
        argv += ["--seeds", str(args.seeds)]
    return mod.main(argv) or 0


def parse_frames(text: str) -> tuple[int, int]:
    """``"A-B"`` or ``"A"`` -> inclusive (A, B) with 0 <= A <= B."""
    parts = text.strip().split("-")
    try:
        start, end = (int(parts[0]), int(parts[-1])) if len(parts) <= 2 else (None, None)
    except ValueError:
        start = end = None
    if start is None or start < 0 or end < start:
        raise UserError(f"--frames must be A-B with 0 <= A <= B, or one frame A; got {text!r}")
    return start, end


def _render(args: argparse.Namespace) -> int:
    """``render``: parse, then call sss_addon.render.render_sequence."""
    frames = parse_frames(args.frames) if args.frames is not None else None
    methods = parse_methods(args.method) if args.method is not None else None
    overrides = {
        dest: getattr(args, dest)
        for _, (dest, _, _) in PARAM_FLAGS.items()
        if getattr(args, dest) is not None
    }
    SSSParams(**overrides)  # refuse bad values before Blender starts
    if args.reference_every < 1:
        raise UserError(f"--reference-every must be >= 1, got {args.reference_every}")
    if args.blend is not None and not args.blend.is_file():
        raise UserError(f"{args.blend}: no such .blend file")
    try:
        import bpy
    except ImportError:
        raise UserError(
            "the render command needs Blender: run it inside Blender "
            "(blender -b scene.blend --python cli.py -- render …) or install bpy==5.0.1"
        ) from None
    if args.blend is None and not bpy.data.filepath:
        raise UserError("no .blend file given and Blender has none open")
    from ..blender.render import RenderError, render_sequence

    try:
        render_sequence(
            args.blend,
            frames,
            args.out,
            methods,
            overrides,
            args.engine,
            args.overwrite,
            None if args.quiet else print,
            reference=args.reference,
            reference_every=args.reference_every,
        )
    except RenderError as exc:
        raise UserError(str(exc)) from None
    return 0


def post_params(args: argparse.Namespace, methods: list[str]) -> SSSParams:
    """SSSParams of ``post``; with ``--quality``, σ0² (or N) from the shipped calibration."""
    params = params_from_args(args)
    if args.quality is None:
        return params
    from ...core.eval import quality

    tuned = [m for m in methods if m not in ("none", "reference")]
    if len(tuned) != 1:
        raise UserError(
            "--quality picks the parameters of one method: give one method in --method "
            f"(plus 'reference' for PSNR), got {','.join(methods)!r}"
        )
    owned = ("target_variance", "beta_min", "fixed_spp")
    clash = [
        f"--{flag}"
        for flag, (dest, _, _) in PARAM_FLAGS.items()
        if dest in owned and getattr(args, dest) is not None
    ]
    if clash:
        raise UserError(f"--quality sets {', '.join(clash)} itself; drop one or the other")
    try:
        calibration = quality.load_calibration()
        params, choice = quality.apply(params, args.quality, tuned[0], calibration)
    except (ValueError, FileNotFoundError) as exc:
        raise UserError(f"--quality: {exc}") from None
    if not args.quiet:
        print(f"{choice.describe()} [calibrated on {calibration.describe()}]")
    return params


def run(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run; raises on errors (see :func:`main`)."""
    args = build_parser().parse_args(argv)
    if args.command == "post":
        from .post import post_process

        methods = parse_methods(args.method)
        if args.reference_every < 1:
            raise UserError(f"--reference-every must be >= 1, got {args.reference_every}")
        post_process(
            args.passes,
            args.out,
            methods,
            post_params(args, methods),
            reference=args.reference,
            overwrite=args.overwrite,
            resume=args.resume,
            allow_gaps=args.allow_gaps,
            log=None if args.quiet else print,
            processor_options=processor_options(args, methods),
            reference_every=args.reference_every,
        )
        return 0
    if args.command == "demo":
        from .demo import SOURCES, DemoError, run_demo

        offered = SOURCES[args.source]
        scenes = (
            offered
            if args.scenes is None
            else [x.strip() for x in args.scenes.split(",") if x.strip()]
        )
        bad = [x for x in scenes if x not in offered]
        if not scenes or bad:
            raise UserError(
                f"--scenes must be a list of {', '.join(offered)} (--source "
                f"{args.source}); got {args.scenes!r}"
            )
        for flag, value in (
            ("--reference-every", args.reference_every),
            ("--samples", args.samples),
        ):
            if value < 1:
                raise UserError(f"{flag} must be >= 1, got {value}")
        try:
            width, height = (int(v) for v in args.res.lower().split("x"))
            if width < 1 or height < 1:
                raise ValueError
        except ValueError:
            raise UserError(f"--res must be WIDTHxHEIGHT in pixels, got {args.res!r}") from None
        if args.frames < 1:
            raise UserError(f"--frames must be >= 1, got {args.frames}")
        try:
            run_demo(
                args.out,
                scenes=scenes,
                width=width,
                height=height,
                frames=args.frames,
                params=params_from_args(args),
                overwrite=args.overwrite,
                source=args.source,
                engine=args.engine,
                samples=args.samples,
                reference_every=args.reference_every,
            )
        except DemoError as exc:
            raise UserError(str(exc)) from None
        return 0
    if args.command == "render":
        return _render(args)
    if args.command == "bench":
        from ...core.eval import bench

        try:
            config = bench.config_from_args(args)
        except ValueError as exc:
            raise UserError(str(exc)) from None
        bench.run_bench(
            args.out,
            config,
            passes=args.passes,
            write_calibration=args.write_calibration,
            plots=not args.no_plots,
        )
        return 0
    if args.command in ("cv1d", "fig2"):
        return _run_study(args.command, args)
    raise UserError(f"unknown command {args.command!r}")


def main(argv: list[str] | None = None) -> int:
    """Entry point: turns user errors into one line on stderr and exit status 2."""
    from ...core.io.exr import OutputError, PassError
    from ...core.params import ParameterError
    from .post import CheckpointError

    if argv is None:
        argv = sys.argv[1:]
        if "--" in argv:  # blender -b … --python cli.py -- <args>
            argv = argv[argv.index("--") + 1 :]
    try:
        return run(argv)
    except ParameterError as exc:
        # The message starts with the parameter's field name: name the flag too.
        field = str(exc).split(" ", 1)[0]
        flags = [f"--{flag}" for flag, (dest, _, _) in PARAM_FLAGS.items() if dest == field]
        print(f"error: {flags[0] + ': ' if flags else ''}{exc}", file=sys.stderr)
        return EXIT_USAGE
    except (UserError, PassError, OutputError, FileExistsError, CheckpointError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(
            "error: interrupted; finished frames were kept (post: rerun with --resume "
            "to continue)",
            file=sys.stderr,
        )
        return 130


if __name__ == "__main__":
    sys.exit(main())

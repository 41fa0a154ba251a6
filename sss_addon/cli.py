"""The ``cvsss`` command line.

Subcommands
-----------
post    post-process a directory of pass EXRs (no Blender needed)
demo    the main job end to end (passes, every method, summary + report)
cv1d    the coefficient study of SPEC §9 (writes out/cv1d.json + plot)
fig2    the 1D motivating example (writes out/fig2.json + plot)

Run inside Blender too: ``blender -b scene.blend --python sss_addon/cli.py --
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
    _root = Path(__file__).resolve().parent.parent
    if "cvsss" not in sys.modules:
        _spec = importlib.util.spec_from_file_location(
            "cvsss", _root / "__init__.py", submodule_search_locations=[str(_root)]
        )
        _mod = importlib.util.module_from_spec(_spec)
        sys.modules["cvsss"] = _mod
        _spec.loader.exec_module(_mod)
    __package__ = "cvsss.sss_addon"

from ..core.methods import METHODS
from ..core.params import SSSParams

EXIT_USAGE = 2

#: CLI flag → SSSParams field, with the help text (units in brackets).
PARAM_FLAGS = {
    "eta": ("eta", float, "η, history exponential moving coefficient (0, 1]"),
    "target-variance": ("target_variance", float, "σ0², target variance of tracked luminance (> 0)"),
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
        "--method", default="as_ccv",
        help=f"method or comma-separated methods: {', '.join(METHODS)} (default as_ccv)",
    )
    post.add_argument("--reference", action="store_true",
                      help="also compute the reference and report PSNR against it")
    post.add_argument("--overwrite", action="store_true", help="replace existing outputs")
    post.add_argument("--quiet", action="store_true", help="no per-frame progress")
    add_param_arguments(post)

    demo = sub.add_parser("demo", help="the main job: passes, every method, report")
    demo.add_argument("--out", type=Path, default=Path("out/demo"), help="output directory")
    demo.add_argument("--scenes", default="flash,regular", help="comma-separated scene names")
    demo.add_argument("--res", default="160x90", help="resolution WxH in pixels")
    demo.add_argument("--frames", type=int, default=60, help="frames per scene (60 fps)")
    demo.add_argument("--overwrite", action="store_true", help="regenerate existing passes")
    add_param_arguments(demo)

    for name, text in (("cv1d", "the CV coefficient study (SPEC §9)"),
                       ("fig2", "the 1D motivating example (P Fig. 2)")):
        p = sub.add_parser(name, help=text)
        p.add_argument("--out", type=Path, default=Path("out"), help="output directory")
        p.add_argument("--seeds", type=int, default=None, help="number of seeds / streams")
        p.add_argument("--seed", type=int, default=0, help="base seed")
    return parser


def _run_study(module: str, args: argparse.Namespace) -> int:
    mod = importlib.import_module(f"..core.studies.{module}", __package__)
    argv = ["--out", str(args.out), "--seed", str(args.seed)]
    if args.seeds is not None:
        argv += ["--seeds", str(args.seeds)]
    return mod.main(argv) or 0


def run(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run; raises on errors (see :func:`main`)."""
    args = build_parser().parse_args(argv)
    if args.command == "post":
        from .post import post_process

        methods = parse_methods(args.method)
        post_process(
            args.passes, args.out, methods, params_from_args(args),
            reference=args.reference, overwrite=args.overwrite,
            log=None if args.quiet else print,
        )
        return 0
    if args.command == "demo":
        from .demo import SYNTHETIC_SCENES, run_demo

        scenes = [x.strip() for x in args.scenes.split(",") if x.strip()]
        bad = [x for x in scenes if x not in SYNTHETIC_SCENES]
        if not scenes or bad:
            raise UserError(f"--scenes must be a list of {', '.join(SYNTHETIC_SCENES)}; got {args.scenes!r}")
        try:
            width, height = (int(v) for v in args.res.lower().split("x"))
            if width < 1 or height < 1:
                raise ValueError
        except ValueError:
            raise UserError(f"--res must be WIDTHxHEIGHT in pixels, got {args.res!r}") from None
        if args.frames < 1:
            raise UserError(f"--frames must be >= 1, got {args.frames}")
        run_demo(args.out, scenes=scenes, width=width, height=height, frames=args.frames,
                 params=params_from_args(args), overwrite=args.overwrite)
        return 0
    if args.command in ("cv1d", "fig2"):
        return _run_study(args.command, args)
    raise UserError(f"unknown command {args.command!r}")


def main(argv: list[str] | None = None) -> int:
    """Entry point: turns user errors into one line on stderr and exit status 2."""
    from ..core.exr import OutputError, PassError
    from ..core.params import ParameterError

    if argv is None:
        argv = sys.argv[1:]
        if "--" in argv:  # blender -b … --python cli.py -- <args>
            argv = argv[argv.index("--") + 1:]
    try:
        return run(argv)
    except (UserError, ParameterError, PassError, OutputError, FileExistsError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print("error: interrupted; finished frames were kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

"""The ``cvsss`` command line.

Subcommands
-----------
post    post-process a directory of pass EXRs (no Blender needed)
render  render a .blend's passes with Blender (bpy) and post-process them
demo    the main job end to end (passes, every method, summary + report)
bench   speed and the speed/accuracy trade, measured (out/bench/bench.json + plots)
compare the user's frame against Cycles' ground truth: plain, Apply on Render (needs bpy)
cv1d, fig2, fp16, separable-kernels
        the studies (coefficient study, 1D motivating example, float16
        history, separable kernels)

The flags and their checks are :mod:`.parser`'s; every algorithm parameter is
a flag generated from its spec in core.params (:mod:`.params`). This module
runs the subcommands. Run inside Blender too: ``blender -b scene.blend
--python sss_addon/cli/main.py -- <subcommand> …``; arguments after ``--``
are read.

User errors (bad parameters, missing or corrupt passes, unwritable folders)
print one ``error:`` line and exit with status 2, without a traceback.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import sys
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

if __package__ in (None, ""):
    # Run as a script (``blender --python main.py`` or ``python main.py``): load
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

from ...core.eval import quality
from ...core.io.errors import CheckpointError, OutputError, PassError
from ...core.io.exr import list_frames
from ...core.io.sidecar import read_sidecar
from ...core.methods import make_processor
from ...core.params import ParameterError, SSSParams
from ...core.profiles.factory import check_materials
from ...core.run import RunSpec, run_folder
from ..blender.errors import RenderError
from ..farm.cluster import FarmError, open_cluster
from ..farm.passes import PassRenderError, render_chunks
from ..farm.post import post_distributed, tiled_processors
from ..precompile import before_first_frame
from ..progress import printer
from . import bench, compare, studies
from .demo import SOURCES, DemoError, run_demo
from .heap import keep_freed_memory
from .params import (
    UserError,
    flag_for_field,
    options_from_args,
    overrides,
    params_from_args,
)
from .parser import (
    EXIT_USAGE,
    MAX_SIDE,
    build_parser,
    check_at_least_one,
    parse_frames,
    parse_methods,
    wants_workers,
)
from .truth import TruthPlan


def _check_first_frame(passes: Path, options) -> None:
    """Refuse a profile choice the first frame's materials cannot take, before any output."""
    if options.profile is None:
        return
    try:
        first = list_frames(passes)[0][1]
        materials = read_sidecar(first.with_suffix(".json"), exr_path=first).materials
    except (PassError, IndexError):
        return  # the run reports unusable passes itself
    check_materials(materials, options.profile)


def post_params(args: argparse.Namespace, methods: list[str]) -> SSSParams:
    """SSSParams of ``post``; with ``--quality``, σ0² (or N) from the shipped calibration."""
    params = params_from_args(args)
    if args.quality is None:
        return params
    tuned = [m for m in methods if m not in ("none", "reference")]
    if len(tuned) != 1:
        raise UserError(
            "--quality picks the parameters of one method: give one method in --method "
            f"(plus 'reference' for PSNR), got {','.join(methods)!r}"
        )
    owned = ("target_variance", "beta_min", "fixed_spp")
    clash = [flag_for_field(name) for name in owned if name in overrides(args, "params")]
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


@contextlib.contextmanager
def background_writer() -> Iterator:
    """``submit`` of a one-thread executor, for core.run's ``submit`` (the core starts
    no threads): each frame's files are written while the next frame is read. On the
    way out it waits for the files still being written."""
    with ThreadPoolExecutor(1, thread_name_prefix="cvsss-write") as pool:
        yield pool.submit


def _post(args: argparse.Namespace) -> int:
    methods = parse_methods(args.method)
    check_at_least_one("--reference-every", args.reference_every)
    options = options_from_args(args)
    _check_first_frame(args.passes, options)
    spec = RunSpec(
        tuple(methods),
        post_params(args, methods),
        options,
        reference=args.reference,
        reference_every=args.reference_every,
    )
    existing = "overwrite" if args.overwrite else "resume" if args.resume else "error"
    ground_truth = args.ground_truth
    if ground_truth is None and (args.passes.parent / "ground_truth").is_dir():
        ground_truth = args.passes.parent / "ground_truth"
    elif ground_truth is not None and not ground_truth.is_dir():
        raise UserError(f"--ground-truth {ground_truth}: no such folder")
    denoised = _post_denoise(args.passes, args.denoise, args.quiet)
    common = {
        "existing": existing,
        "allow_gaps": args.allow_gaps,
        "log": None if args.quiet else print,
        "warn": lambda text: print(text, file=sys.stderr),
        "ground_truth": ground_truth,
    }
    with background_writer() as submit:
        common["submit"] = submit
        if wants_workers(args):
            try:
                post_distributed(
                    args.passes,
                    args.out,
                    spec,
                    workers=args.workers,
                    scheduler=args.scheduler,
                    tile=args.tile,
                    wrap=denoised,
                    **common,
                )
            except FarmError as exc:
                raise UserError(str(exc)) from None
            return 0
        kernels = before_first_frame(spec.params.backend, spec.order, common["log"])
        if denoised is not None:
            common["processors"] = denoised(make_processor)
        run_folder(
            args.passes,
            args.out,
            spec,
            before_first=kernels,
            **{**common, "log": printer(common["log"])},
        )
    return 0


def _post_denoise(passes: Path, asked: bool | None, quiet: bool):
    """``processors`` -> the same, their results denoised as the pass files' sidecars
    record (``"denoise"``); None when the finished frames are not denoised.

    ``asked`` None follows the sidecars; False never denoises; True needs them to
    record it (only such pass files hold the guides).
    """
    if asked is False:
        return None
    try:
        frames = list_frames(passes)
    except PassError:
        return None  # the run reports unusable passes itself
    records = {}
    for number, path in frames:
        try:
            sidecar = read_sidecar(path.with_suffix(".json"), exr_path=path)
        except PassError:
            return None
        records[number] = (sidecar.raw.get("denoise"), sidecar.view_layer or "ViewLayer")
    recorded = [n for n, (record, _) in records.items() if isinstance(record, dict)]
    if not recorded and not asked:
        return None
    if len(recorded) != len(records):
        missing = next(n for n in records if n not in recorded)
        raise UserError(
            f"--denoise: frame {missing}'s pass file holds no denoiser guides (its sidecar "
            'records no "denoise"); render the passes with `cvsss render --denoise`, or '
            "pass --no-denoise"
        )
    try:
        # Imported here: Blender's OpenImageDenoise; every other post runs without bpy.
        from ..blender.denoise_frame import DenoiseSettings, denoising, read_guides
    except ImportError:
        raise UserError(
            "the pass files' sidecars ask for the finished frames to be denoised (their scene "
            "denoises), which needs Blender's OpenImageDenoise: install bpy==5.0.1, or pass "
            "--no-denoise"
        ) from None
    paths = dict(frames)
    settings = DenoiseSettings.from_dict(records[recorded[0]][0])
    if not quiet:
        why = "on EEVEE passes" if settings.subsurface_only else "as the passes' scene asks"
        print(f"the finished frames are denoised {why}: {settings.describe()}")

    def guides(number: int):
        return read_guides(paths[number], records[number][1]) if number in paths else None

    return lambda processors: denoising(processors, settings, guides)


def _render(args: argparse.Namespace) -> int:
    """``render``: parse, then call sss_addon.blender.standalone.render_sequence."""
    frames = parse_frames(args.frames) if args.frames is not None else None
    methods = parse_methods(args.method) if args.method is not None else None
    params = overrides(args, "params")
    SSSParams(**params)  # refuse bad values before Blender starts
    options = options_from_args(args)  # refused before Blender starts, too
    option_overrides = {"separable": overrides(args, "separable")}
    if overrides(args, "profile"):
        option_overrides["profile"] = options.profile
    check_at_least_one("--reference-every", args.reference_every)
    if args.warmup_frames < 0:
        raise UserError(f"--warmup-frames must be >= 0, got {args.warmup_frames}")
    if args.ground_truth_every is not None:
        check_at_least_one("--ground-truth-every", args.ground_truth_every)
    if args.ground_truth_spp is not None and not 1 <= args.ground_truth_spp <= 2**24:
        raise UserError(f"--ground-truth-spp must be in [1, {2**24}], got {args.ground_truth_spp}")
    if args.denoise_passes and args.engine == "EEVEE":
        raise UserError(
            "--denoise-passes needs Cycles passes: EEVEE writes no Denoising Albedo and Normal "
            "passes to guide the denoiser"
        )
    if args.denoise and args.denoise_passes:
        raise UserError(
            "--denoise (the finished frames) and --denoise-passes (the passes): choose one"
        )
    if args.blend is not None and not args.blend.is_file():
        raise UserError(f"{args.blend}: no such .blend file")
    try:
        import bpy
    except ImportError:
        raise UserError(
            "the render command needs Blender: run it inside Blender "
            "(blender -b scene.blend --python main.py -- render …) or install bpy==5.0.1"
        ) from None
    if args.blend is None and not bpy.data.filepath:
        raise UserError("no .blend file given and Blender has none open")
    if args.blend is None and args.autoexec is not None:
        raise UserError(
            "--enable-autoexec/--disable-autoexec apply to the .blend this command opens; "
            "for the file Blender opened, give Blender -y or -Y (blender -b -y FILE --python …)"
        )
    # Imported here: it imports bpy, which every other command runs without.
    from ..blender.standalone import render_sequence

    if wants_workers(args):
        if args.range_start is not None:
            raise UserError("--range-start is set by a distributed render on its chunks only")
        blend = args.blend if args.blend is not None else Path(bpy.data.filepath)
        return _render_distributed(
            args, blend, render_sequence, RenderError, frames, methods, params, option_overrides
        )
    try:
        render_sequence(
            args.blend,
            log=None if args.quiet else print,
            **_sequence_options(args, frames, methods, params, option_overrides),
            warmup_frames=args.warmup_frames,
            range_start=args.range_start,
        )
    except RenderError as exc:
        raise UserError(str(exc)) from None
    return 0


def _sequence_options(args: argparse.Namespace, frames, methods, params, option_overrides) -> dict:
    """The ``render_sequence`` keywords that a local and a distributed render share."""
    method = args.ground_truth_method
    return {
        "frames": frames,
        "out": args.out,
        "methods": methods,
        "params": params,
        "engine": args.engine,
        "overwrite": args.overwrite,
        "reference": args.reference,
        "reference_every": args.reference_every,
        "options": option_overrides,
        "denoise_passes": args.denoise_passes,
        "denoise": args.denoise,
        "thin_walks": None if args.thin_walks is None else args.thin_walks.upper(),
        "ground_truth": args.ground_truth,
        "ground_truth_samples": args.ground_truth_spp,
        "ground_truth_every": args.ground_truth_every,
        "ground_truth_method": None if method is None else method.upper(),
        "passes_only": args.passes_only,
        "autoexec": args.autoexec,
    }


def _render_distributed(
    args, blend, render_sequence, render_error, frames, methods, params, option_overrides
) -> int:
    """``render --workers/--scheduler``: pass chunks on the cluster, then the tiled post."""
    log = None if args.quiet else print
    try:
        with open_cluster(args.workers, args.scheduler, log=log) as executor:
            render_sequence(
                args.blend,
                log=log,
                **_sequence_options(args, frames, methods, params, option_overrides),
                render_passes=False,
                processors=tiled_processors(
                    executor, args.tile, log=lambda text: print(text, file=sys.stderr)
                ),
                on_job=lambda job: render_chunks(executor, blend, job, args.chunk, log),
            )
    except FarmError as exc:
        raise UserError(str(exc)) from None
    except (render_error, PassRenderError) as exc:
        raise UserError(str(exc)) from None
    return 0


def _demo(args: argparse.Namespace) -> int:
    offered = SOURCES[args.source]
    scenes = (
        offered if args.scenes is None else [x.strip() for x in args.scenes.split(",") if x.strip()]
    )
    bad = [x for x in scenes if x not in offered]
    if not scenes or bad:
        raise UserError(
            f"--scenes must be a list of {', '.join(offered)} (--source "
            f"{args.source}); got {args.scenes!r}"
        )
    check_at_least_one("--reference-every", args.reference_every)
    check_at_least_one("--samples", args.samples)
    check_at_least_one("--frames", args.frames)
    check_at_least_one("--ground-truth-spp", args.ground_truth_spp)
    check_at_least_one("--compare-ground-truth-spp", args.compare_ground_truth_spp)
    if args.ground_truth_every < 0:
        raise UserError(f"--ground-truth-every must be >= 0, got {args.ground_truth_every}")
    if args.compare_frames < 0:
        raise UserError(f"--compare-frames must be >= 0, got {args.compare_frames}")
    truth = TruthPlan(
        every=args.ground_truth_every,
        samples=args.ground_truth_spp,
        users_frames=args.compare_frames,
        users_samples=args.compare_ground_truth_spp,
    )
    try:
        width, height = (int(v) for v in args.res.lower().split("x"))
        if not (1 <= width <= MAX_SIDE and 1 <= height <= MAX_SIDE):
            raise ValueError
    except ValueError:
        raise UserError(
            f"--res must be WIDTHxHEIGHT in pixels, 1 to {MAX_SIDE} each, got {args.res!r}"
        ) from None
    try:
        run_demo(
            args.out,
            scenes=scenes,
            width=width,
            height=height,
            frames=args.frames,
            params=params_from_args(args),
            options=options_from_args(args),
            overwrite=args.overwrite,
            source=args.source,
            engine=args.engine,
            samples=args.samples,
            reference_every=args.reference_every,
            truth=truth,
        )
    except DemoError as exc:
        raise UserError(str(exc)) from None
    return 0


def run(argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run; raises on errors (see :func:`main`)."""
    args = build_parser().parse_args(argv)
    if args.command == "post":
        return _post(args)
    if args.command == "demo":
        return _demo(args)
    if args.command == "render":
        return _render(args)
    if args.command == "compare":
        return compare.run(args, parse_frames(args.frames))
    if args.command == "bench":
        try:
            return bench.run(args)
        except ValueError as exc:
            raise UserError(str(exc)) from None
    return studies.run(args)


def main(argv: list[str] | None = None) -> int:
    """Entry point: turns user errors into one line on stderr and exit status 2."""
    if argv is None:
        argv = sys.argv[1:]
        if "--" in argv:  # blender -b … --python main.py -- <args>
            argv = argv[argv.index("--") + 1 :]
    # A frame's large arrays reuse the last frame's freed memory (glibc; see .heap).
    keep_freed_memory()
    try:
        return run(argv)
    except ParameterError as exc:
        # The message starts with the parameter's field name: name the flag too.
        flag = flag_for_field(str(exc).split(" ", 1)[0])
        print(f"error: {flag + ': ' if flag else ''}{exc}", file=sys.stderr)
        return EXIT_USAGE
    except (UserError, PassError, OutputError, FileExistsError, CheckpointError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except MemoryError as exc:
        detail = str(exc) or "the allocation failed"
        print(f"error: not enough memory ({detail}); use a smaller size", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        return _interrupted()
    except SystemError as exc:
        # Ctrl-C inside a compiled (numba) kernel surfaces as a SystemError whose context
        # is the KeyboardInterrupt.
        if not _from_interrupt(exc):
            raise
        return _interrupted()


def _from_interrupt(exc: BaseException) -> bool:
    """Whether ``exc`` was raised while a KeyboardInterrupt was being handled."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        if isinstance(exc, KeyboardInterrupt):
            return True
        seen.add(id(exc))
        exc = exc.__cause__ or exc.__context__
    return False


def _interrupted() -> int:
    print(
        "error: interrupted; finished frames were kept (post: rerun with --resume to continue)",
        file=sys.stderr,
    )
    return 130


if __name__ == "__main__":
    sys.exit(main())

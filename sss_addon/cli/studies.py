"""The studies' command lines and figures: ``cvsss cv1d | fig2 | fp16 | separable-kernels``.

The computations are in :mod:`cvsss.core.studies`; each subcommand here
parses its flags, runs one, writes its files (atomically) and prints its
table followed by a ``wrote …`` line:

``cv1d``
    coefficient study of the CV residual (P Fig. 5): ``OUT/cv1d.json``
    (summary), ``cv1d_curves.json`` and ``cv1d.png``;
``fig2``
    motivating example of P Fig. 2: ``OUT/fig2.json``, ``fig2_curves.json``
    and ``fig2.png``;
``fp16``
    drift of counts and α with a float16 history: ``OUT/fp16.json``;
``separable-kernels``
    separable kernels' error and cost: ``OUT/separable_kernels.json`` and
    ``separable_kernels.md``.
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...core.io.atomic import write_text
from ...core.params import ParameterError, SSSParams
from ...core.studies import cv1d, fig2, fp16, separable_kernels
from .params import UserError
from .plots import COLOURS, pyplot, save


@dataclass(frozen=True)
class Study:
    """One study subcommand.

    Attributes
    ----------
    name : str, the subcommand
    help : str, one line in ``cvsss --help``
    description : str, the subcommand's ``--help`` description
    out : str, default ``--out``
    arguments : callable (parser) -> None, the study's own flags
    write : callable (args, out) -> (table, files), runs the study and writes
        its files into ``out``; ``files`` ends the ``wrote …`` line
    """

    name: str
    help: str
    description: str
    out: str
    arguments: Callable[[argparse.ArgumentParser], None]
    write: Callable[[argparse.Namespace, Path], tuple[str, str]]


def _resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` -> (W, H), both >= 1 (an argparse type)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, got {text!r}") from None
    if w < 1 or h < 1:
        raise argparse.ArgumentTypeError(f"expected a positive WIDTHxHEIGHT, got {text!r}")
    return w, h


def _json(data: Any, indent: int | None = None) -> str:
    return json.dumps(data, indent=indent) + "\n"


# -- cv1d and fig2: summary, curves and a figure -----------------------------------------
def _seeds_arguments(seeds: int, seeds_help: str, seed_help: str):
    def arguments(parser: argparse.ArgumentParser) -> None:
        parser.add_argument(
            "--seeds", type=int, default=seeds, help=f"{seeds_help} (default {seeds})"
        )
        parser.add_argument("--seed", type=int, default=0, help=f"{seed_help} (default 0)")

    return arguments


def _curves_writer(name: str, module: Any, plot: Callable[[dict, Path], Path]):
    """Writer of a study with ``run(seeds, seed)``: NAME.json, NAME_curves.json, NAME.png."""

    def write(args: argparse.Namespace, out: Path) -> tuple[str, str]:
        result = module.run(seeds=args.seeds, seed=args.seed)
        summary = {k: v for k, v in result.items() if k != "curves"}
        write_text(out / f"{name}.json", _json(summary, indent=2))
        write_text(out / f"{name}_curves.json", _json(result["curves"]))
        plot(result, out / f"{name}.png")
        return module.format_table(
            result
        ), f"{out / f'{name}.json'}, {name}_curves.json, {name}.png"

    return write


def plot_cv1d(result: dict[str, Any], path: str | Path) -> Path:
    """α and ReMSE per frame and configuration, static and dynamic side by side."""
    plt = pyplot()
    curves = result["curves"]
    frame = np.asarray(curves["frame"])
    fig, axes = plt.subplots(2, 2, figsize=(11, 7), sharex=True)
    for col, scenario in enumerate(cv1d.SCENARIOS):
        for name, label in cv1d.CONFIGS.items():
            style = {"color": COLOURS[name], "label": label, "lw": 1.2}
            if name == "gt":
                style["ls"] = "--"
            if name != "no_cv":
                axes[0, col].plot(frame, curves[scenario]["alpha"][name], **style)
            axes[1, col].plot(frame, curves[scenario]["remse"][name], **style)
        axes[0, col].set_title(
            f"{scenario} lighting: h(t) = " + ("1" if scenario == "static" else "1 + 3 sin(t/10)")
        )
        axes[0, col].set_ylabel("CV coefficient α (mean over seeds)")
        axes[1, col].set_ylabel("ReMSE = sqrt(moving Var(Res)), η = 0.2")
        axes[1, col].set_xlabel("frame t")
        axes[1, col].set_yscale("log")
        axes[1, col].axvspan(*result["settings"]["report_frames"], color="0.93", zorder=0)
    axes[0, 1].axhline(math.log(4), color="0.5", lw=0.8, ls=":", label="ln 4")
    axes[0, 0].legend(fontsize=7, loc="best")
    axes[1, 0].legend(fontsize=7, loc="best")
    return save(fig, path)


def plot_fig2(result: dict[str, Any], path: str | Path) -> Path:
    """Lighting, intensity and sample counts per pixel and per frame."""
    plt = pyplot()
    c = result["curves"]
    x = np.asarray(c["x"])
    vis = np.asarray(c["visibility"])
    dyn = np.asarray(c["intensity"]["dynamic"])
    fig, axes = plt.subplots(2, 2, figsize=(11, 7))

    ax = axes[0, 0]
    ax.plot(x, vis, color="black", label="static, I = 1")
    for frame in (1, 3, 9):
        if frame < dyn.size:
            ax.plot(
                x,
                dyn[frame] * vis,
                lw=0.9,
                ls="--",
                label=f"dynamic, frame {frame} (I = {dyn[frame]:.1f})",
            )
    ax.set_xlabel("surface position x")
    ax.set_ylabel("lighting B(x, t)")
    ax.set_title("(a) lighting on the 1D surface")
    ax.legend(fontsize=7)

    ax = axes[0, 1]
    frames = np.arange(dyn.size)
    ax.plot(frames, c["intensity"]["static"], color="black", label="static")
    ax.plot(frames, dyn, color="tab:purple", label="dynamic: sin(2π·5t) + 1")
    ax.set_xlabel("frame (60 fps)")
    ax.set_ylabel("light intensity I(t)")
    ax.set_title("(b) intensity over time")
    ax.legend(fontsize=7)

    for config, label in fig2.CONFIGS.items():
        for scenario, ls in (("static", ":"), ("dynamic", "-")):
            key = f"{config}_{scenario}"
            style = {
                "color": COLOURS[config],
                "ls": ls,
                "lw": 1.2,
                "label": f"{label.split(':')[0]} {scenario} ({result[key]:.1f} spp)",
            }
            axes[1, 0].plot(x, c["counts_per_pixel"][key], **style)
            axes[1, 1].plot(frames, c["counts_per_frame"][key], **style)
    axes[1, 0].set_xlabel("surface position x")
    axes[1, 0].set_ylabel("sample count m (mean over frames)")
    axes[1, 0].set_title("(c) sample count per pixel")
    axes[1, 1].set_xlabel("frame (60 fps)")
    axes[1, 1].set_ylabel("sample count m (mean over pixels)")
    axes[1, 1].set_title("(d) sample count per frame")
    for ax in axes[1]:
        ax.set_ylim(0, result["settings"]["params"]["beta_max"] * 1.05)
    axes[1, 1].legend(fontsize=7, loc="lower right")
    return save(fig, path)


# -- fp16 -------------------------------------------------------------------------------
def _fp16_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=300, help="frames (default 300)")
    parser.add_argument("--res", type=_resolution, default=(96, 54), help="WxH (default 96x54)")
    parser.add_argument(
        "--methods",
        default=",".join(fp16.METHODS),
        help=f"comma-separated subset of {', '.join(fp16.METHODS)}",
    )
    parser.add_argument("--seed", type=int, default=0, help="sampling seed (default 0)")
    parser.add_argument(
        "--long-frames",
        type=int,
        default=6000,
        help="frames of the long α-drift run, 0 to skip (default 6000)",
    )


def _fp16_write(args: argparse.Namespace, out: Path) -> tuple[str, str]:
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    if not methods or any(m not in fp16.METHODS for m in methods):
        raise UserError(
            f"--methods must be a subset of {', '.join(fp16.METHODS)}, got {args.methods!r}"
        )
    long_frames = max(args.long_frames, 0)
    w, h = args.res
    # The full command, so the file says how to reproduce it.
    command = (
        f"cvsss fp16 --out {out} --frames {args.frames} --res {w}x{h} "
        f"--methods {','.join(methods)} --seed {args.seed} --long-frames {long_frames}"
    )
    result = fp16.measure(
        frames=args.frames,
        width=w,
        height=h,
        methods=methods,
        params=SSSParams(seed=args.seed),
        long_frames=long_frames,
    )
    result = {"command": command, **result}
    write_text(out / "fp16.json", _json(result, indent=1))
    return fp16.format_table(result), f"{out / 'fp16.json'} ({result['seconds']} s)"


# -- separable kernels -----------------------------------------------------------------
def _separable_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--res", type=_resolution, default=(640, 360), help="resolution WxH (default 640x360)"
    )
    parser.add_argument("--frames", type=int, default=3, help="frames timed (default 3)")
    parser.add_argument("--gaussians", type=int, default=4, help="N of the gaussians kernel")
    parser.add_argument(
        "--reference-spp",
        type=int,
        default=256,
        help="samples per pixel of the Monte Carlo reference (default 256)",
    )
    parser.add_argument("--no-presets", action="store_true", help="skip the preset error table")


def _separable_write(args: argparse.Namespace, out: Path) -> tuple[str, str]:
    t0 = time.perf_counter()
    result = separable_kernels.run(
        *args.res,
        args.frames,
        gaussians=args.gaussians,
        reference_spp=args.reference_spp,
        presets_table=not args.no_presets,
        machine=f"{platform.machine()} {platform.processor() or ''}".strip(),
    )
    text = separable_kernels.format_tables(result)
    write_text(out / "separable_kernels.json", _json(result, indent=2))
    write_text(out / "separable_kernels.md", text + "\n")
    return text, (
        f"{out / 'separable_kernels.json'} and separable_kernels.md "
        f"({time.perf_counter() - t0:.0f} s)"
    )


#: The study subcommands, in ``cvsss --help`` order.
STUDIES: dict[str, Study] = {
    s.name: s
    for s in (
        Study(
            "cv1d",
            "coefficient study of the CV residual (P Fig. 5): out/cv1d.json + cv1d.png",
            "Coefficient study of the CV residual (P Fig. 5).",
            "out",
            _seeds_arguments(1000, "sequences to average", "base seed"),
            _curves_writer("cv1d", cv1d, plot_cv1d),
        ),
        Study(
            "fig2",
            "motivating example of P Fig. 2 (1D surface): out/fig2.json + fig2.png",
            "Motivating example of P Fig. 2 (1D surface).",
            "out",
            _seeds_arguments(8, "sample streams to average", "seed of the pixel hash"),
            _curves_writer("fig2", fig2, plot_fig2),
        ),
        Study(
            "fp16",
            "drift of counts and α with a float16 history: out/fp16.json",
            "Drift of counts and α with a float16 history (flash sequence).",
            "out",
            _fp16_arguments,
            _fp16_write,
        ),
        Study(
            "separable-kernels",
            "separable kernels' error and cost: out/separable_kernels/separable_kernels.json",
            (separable_kernels.__doc__ or "").splitlines()[0],
            "out/separable_kernels",
            _separable_arguments,
            _separable_write,
        ),
    )
}


def add_parsers(subparsers: Any) -> None:
    """Add the study subcommands (:data:`STUDIES`) to ``subparsers`` (of ``cvsss``)."""
    for study in STUDIES.values():
        parser = subparsers.add_parser(study.name, help=study.help, description=study.description)
        parser.add_argument(
            "--out",
            type=Path,
            default=Path(study.out),
            help=f"output directory (default {study.out})",
        )
        study.arguments(parser)
        parser.set_defaults(study=study.name)


def run(args: argparse.Namespace) -> int:
    """Run the study ``args.study`` (set by :func:`add_parsers`); returns the exit status.

    Prints the study's table, a blank line and ``wrote …``.

    Raises
    ------
    UserError
        Bad arguments (e.g. ``--seeds 1``); ParameterError passes through, so
        the command line names the flag.
    """
    study = STUDIES[args.study]
    out = Path(args.out)
    try:
        table, files = study.write(args, out)
    except ParameterError:
        raise
    except ValueError as exc:
        raise UserError(str(exc)) from None
    print(table)
    print(f"\nwrote {files}")
    return 0

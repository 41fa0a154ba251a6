"""The main job: render (or generate) passes, post-process every method, report.

``cvsss demo --out out/demo`` writes, per scene, ``passes/``, one folder per
method and ``metrics.csv``, then ``summary.json``, ``report.md`` and PNG
plots at the top.

Sources of the passes
---------------------
blender (default)
    The scenes of :mod:`cvsss.demo_blend.scenes` (flash, regular, boids) are
    built in a fresh Blender file (bpy module, or inside Blender), a copy is
    saved as ``<out>/<scene>/<scene>.blend``, and their passes are rendered
    with Cycles (or EEVEE) by the add-on's sequence renderer. Pass frames
    already on disk are reused when the render settings are the same
    (``<out>/<scene>/demo.json``); changed settings or ``overwrite``
    render them again.
synthetic
    The analytic scenes of :mod:`cvsss.core.synthetic` (flash, regular),
    written as real multi-part EXR files and read back like rendered ones;
    no Blender needed.

Every method's results continue where a run with the same passes, methods
and parameters stopped (core.run, ``existing="continue"``) and are computed
again otherwise. The 1024-spp reference, as costly as all other methods
together, is computed on every k-th frame (``reference_every``; the first,
the (k+1)-th, …) and PSNR is averaged over those frames.
"""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ...core.eval.metrics import median3
from ...core.io.atomic import make_folder, write_text
from ...core.io.exr import write_passes
from ...core.methods import MethodOptions
from ...core.params import SSSParams
from ...core.run import RunSpec, format_clock, run_folder
from ...core.synthetic import sequence
from . import report as plots

#: Methods compared by the demo, in report order.
DEMO_METHODS = ("as", "as_ocv", "as_ccv", "fixed", "separable", "reference")
SYNTHETIC_SCENES = ("flash", "regular")
BLENDER_SCENES = ("flash", "regular", "boids")
#: Where the passes come from -> the scenes it offers.
SOURCES = {"blender": BLENDER_SCENES, "synthetic": SYNTHETIC_SCENES}
#: Cycles samples per pixel of the demo passes (the same noisy input for every method).
CYCLES_SAMPLES = 16

#: Targets of the demo issue: (min spp ratio AS / AS+CCV, max PSNR loss dB).
TARGETS = {"flash": (1.8, 2.0), "regular": (1.3, 1.5), "boids": (1.3, 1.5)}
#: Worst frame's spp under CV at most this times its median.
STEADY = 1.5

#: The paper's Table 3 (UE4, 2560×1440, RTX 2080 Ti), for orientation.
PAPER_TABLE3 = {
    "flash": {
        "spp": (61.97, 29.58, 26.88),
        "pass_ms": (1.47, 0.80, 0.75),
        "psnr_db": (51.19, 49.55, 49.43),
    },
    "regular": {
        "spp": (26.51, 18.32, 17.82),
        "pass_ms": (3.39, 2.55, 2.58),
        "psnr_db": (47.85, 47.57, 47.55),
    },
    "dynamic": {
        "spp": (22.01, 14.70, 14.13),
        "pass_ms": (2.02, 1.54, 1.52),
        "psnr_db": (50.62, 49.11, 49.11),
    },
}


def summarize(rows: Sequence[dict]) -> dict:
    """``{method: {"spp", "pass_ms", "psnr_db", "spp_max", "spp_median"}}`` from metric rows.

    ``pass_ms`` is the mean of the 3rd-order median-filtered per-frame times
    (P Sec. 7); PSNR means skip frames without a reference.
    """
    by = defaultdict(list)
    for r in rows:
        by[r["method"]].append(r)
    out = {}
    for method, rs in by.items():
        spp = np.array([float(r["spp"]) for r in rs])
        ms = median3(np.array([float(r["pass_ms"]) for r in rs]))
        ps = [float(r["psnr_db"]) for r in rs if r.get("psnr_db") not in ("", None)]
        out[method] = {
            "spp": float(spp.mean()),
            "spp_max": float(spp.max()),
            "spp_median": float(np.median(spp)),
            "pass_ms": float(ms.mean()),
            "psnr_db": float(np.mean(ps)) if ps else math.nan,
        }
    return out


def _table(summary: dict) -> str:
    lines = [
        "| scene | method | mean spp | max spp | pass ms | PSNR dB |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    for scene, methods in summary.items():
        for m, v in methods.items():
            lines.append(
                f"| {scene} | {m} | {v['spp']:.2f} | {v['spp_max']:.2f} | "
                f"{v['pass_ms']:.2f} | {v['psnr_db']:.2f} |"
            )
    return "\n".join(lines)


def check_targets(summary: dict) -> list[dict]:
    """Measured against the demo targets: CV saves samples, costs little PSNR, is steady."""
    rows = []
    for scene, s in summary.items():
        if not {"as", "as_ccv"} <= set(s):
            continue
        min_ratio, max_loss = TARGETS.get(scene, TARGETS["regular"])
        ratio = s["as"]["spp"] / max(s["as_ccv"]["spp"], 1e-12)
        loss = s["as"]["psnr_db"] - s["as_ccv"]["psnr_db"]
        rows.append(
            {
                "scene": scene,
                "check": f"spp AS / AS+CCV >= {min_ratio}",
                "value": ratio,
                "met": bool(ratio >= min_ratio),
            }
        )
        rows.append(
            {
                "scene": scene,
                "check": f"PSNR loss AS -> AS+CCV <= {max_loss} dB",
                "value": loss,
                "met": bool(loss <= max_loss),
            }
        )
        for m in ("as_ocv", "as_ccv", "as"):
            if m in s:
                steady = s[m]["spp_max"] / max(s[m]["spp_median"], 1e-12)
                rows.append(
                    {
                        "scene": scene,
                        "check": f"{m}: max spp / median spp <= {STEADY}",
                        "value": steady,
                        "met": bool(steady <= STEADY) if m != "as" else None,
                    }
                )
    return rows


def write_report(out: Path, summary: dict, header: list[str], beta_max: int) -> Path:
    """report.md with the table beside the paper's, targets, and the plots."""
    lines = [
        "# cvsss demo report",
        "",
        *header,
        "",
        "## Measured",
        "",
        _table(summary),
        "",
        "## The paper's Table 3 (UE4, 2560×1440, RTX 2080 Ti), AS / +OCV / +CCV",
        "",
        "| scene | spp | pass ms | PSNR dB |",
        "| --- | --- | --- | --- |",
    ]
    for scene, v in PAPER_TABLE3.items():
        lines.append(
            f"| {scene} | {' / '.join(map(str, v['spp']))} | "
            f"{' / '.join(map(str, v['pass_ms']))} | {' / '.join(map(str, v['psnr_db']))} |"
        )
    lines += [
        "",
        "## Targets",
        "",
        "| scene | check | measured | met |",
        "| --- | --- | ---: | --- |",
    ]
    for r in check_targets(summary):
        met = {True: "yes", False: "**no**", None: "(reference: AS alone)"}[r["met"]]
        lines.append(f"| {r['scene']} | {r['check']} | {r['value']:.2f} | {met} |")
    lines += ["", "## Plots", ""]
    for scene in summary:
        for name, text in (
            (f"{scene}_frames.png", f"{scene}: per frame (cf. the paper's Fig. 8)"),
            (f"{scene}_strip_as.png", f"{scene}: AS sample counts"),
            (f"{scene}_strip_as_ccv.png", f"{scene}: AS + CCV sample counts"),
        ):
            if (out / name).exists():
                lines += [f"### {text}", "", f"![{text}]({name})", ""]
    if (out / "pareto.png").exists():
        lines += [
            "### PSNR against sampling-pass time, every method",
            "",
            "![pareto](pareto.png)",
            "",
        ]
    lines += [
        "Sample-count maps share the colour scale [0, β_max = "
        f"{beta_max}]; grey is outside the SSS materials."
    ]
    path = out / "report.md"
    write_text(path, "\n".join(lines) + "\n")
    return path


def make_plots(out: Path, scene: str, rows_frames: list[int], beta_max: int) -> None:
    """Per-scene plots and previews from the files already written."""
    scene_dir = out / scene
    metrics = plots.read_metrics(scene_dir / "metrics.csv")
    plots.plot_frames(metrics, out / f"{scene}_frames.png", scene)
    picks = sorted(set(np.linspace(rows_frames[0], rows_frames[-1], 5).round().astype(int)))
    for method in ("as", "as_ccv"):
        if (scene_dir / method).is_dir():
            plots.plot_strip(
                scene_dir, method, picks, out / f"{scene}_strip_{method}.png", beta_max
            )
    mid = picks[len(picks) // 2]
    plots.plot_preview(scene_dir, "as_ccv", mid, out / f"{scene}_preview_{mid:04d}.png", beta_max)


def _pass_cache(
    scene_dir: Path, stamp: dict, overwrite: bool, log: Callable[[str], None] | None
) -> Path:
    """Keep the pass frames of ``scene_dir`` only if they were made with ``stamp``'s settings.

    Frames made with other (or unknown) settings, or all with ``overwrite``,
    are deleted; the new stamp is written before any frame is made, so an
    interrupted run continues with the same settings.
    """
    passes = scene_dir / "passes"
    stamp_path = scene_dir / "demo.json"
    try:
        old = json.loads(stamp_path.read_text())
    except (OSError, ValueError):
        old = None
    frames = (
        [p for p in passes.iterdir() if p.suffix in (".exr", ".json")] if passes.is_dir() else []
    )
    if frames and (overwrite or old != stamp):
        if log:
            why = (
                "--overwrite"
                if overwrite
                else (f"made with other settings ({stamp_path})" if old else "of unknown origin")
            )
            log(f"{stamp['scene']}: removing {len(frames)} pass file(s) {why}; making them again")
        for path in frames:
            path.unlink()
    make_folder(passes)
    write_text(stamp_path, json.dumps(stamp, indent=2))
    return passes


def _synthetic_passes(
    scene: str,
    scene_dir: Path,
    width: int,
    height: int,
    frames: int,
    overwrite: bool,
    log: Callable[[str], None] | None,
) -> None:
    stamp = {
        "source": "synthetic",
        "scene": scene,
        "width": width,
        "height": height,
        "frames": frames,
    }
    passes = _pass_cache(scene_dir, stamp, overwrite, log)
    for frame in sequence(scene, frames, width, height):
        path = passes / f"{frame.number:04d}.exr"
        if not path.exists():
            write_passes(path, frame, overwrite=True)


def blender_passes(
    scene_name: str,
    scene_dir: Path,
    width: int,
    height: int,
    frames: int,
    *,
    engine: str = "CYCLES",
    samples: int = CYCLES_SAMPLES,
    overwrite: bool = False,
    log: Callable[[str], None] | None = print,
) -> Path:
    """Build the demo ``scene_name`` in a fresh file and render its passes.

    Parameters
    ----------
    scene_name : a key of ``demo_blend.scenes.SCENES``
    scene_dir : folder of this scene; passes go to ``scene_dir/passes``
    width, height : render size in pixels
    frames : frames 1..frames at 60 fps
    engine : ``"CYCLES"`` or ``"EEVEE"``
    samples : Cycles samples per pixel (EEVEE: its render samples)
    overwrite : render every frame again

    Returns
    -------
    Path of the pass folder. The current Blender file is replaced by an
    empty one with the built scene (it is never saved over a user's file;
    a copy goes to ``scene_dir/<scene_name>.blend``).
    """
    import bpy

    from ...demo_blend import scenes
    from ..blender import render

    scene_dir = Path(scene_dir)
    stamp = {
        "source": "blender",
        "scene": scene_name,
        "width": width,
        "height": height,
        "frames": frames,
        "engine": engine,
        "samples": samples,
        "blender": bpy.app.version_string,
    }
    _pass_cache(scene_dir, stamp, overwrite, log)
    unregister = render._ensure_registered()
    try:
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scenes.build(scene_name, scene, frames=frames)
        scene.render.resolution_x, scene.render.resolution_y = width, height
        scene.render.resolution_percentage = 100
        if getattr(scene, "cycles", None) is not None:
            scene.cycles.device = "CPU"
            scene.cycles.samples = samples
        if hasattr(scene, "eevee"):
            scene.eevee.taa_render_samples = samples
        bpy.ops.wm.save_as_mainfile(filepath=str(scene_dir / f"{scene_name}.blend"), copy=True)
        job = render.prepare(
            scene, (1, frames), scene_dir, methods=("as_ccv",), engine=engine, log=log
        )
        for _ in render.iter_passes(job):
            pass
    except (render.RenderError, ValueError) as exc:
        raise DemoError(f"{scene_name}: {exc}") from None
    except RuntimeError as exc:  # a Blender operator failed (save, bake, render)
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise DemoError(f"{scene_name}: Blender failed: {reason}") from None
    finally:
        if unregister is not None:
            unregister()
    return scene_dir / "passes"


class DemoError(RuntimeError):
    """A demo run that cannot go on (bad option, Blender missing, render refused)."""


def run_demo(
    out: Path,
    *,
    scenes: Sequence[str] | None = None,
    width: int = 320,
    height: int = 180,
    frames: int = 120,
    params: SSSParams | None = None,
    options: MethodOptions | None = None,
    overwrite: bool = False,
    source: str = "blender",
    engine: str = "CYCLES",
    samples: int = CYCLES_SAMPLES,
    reference_every: int = 5,
    log: Callable[[str], None] | None = print,
) -> dict:
    """Make passes, post-process every demo method, write summary and report.

    Parameters
    ----------
    out : output folder (``out/demo``)
    scenes : scene names of ``source`` (default: all of them)
    width, height : pass size in pixels
    frames : frames per scene at 60 fps
    params : SSSParams of every method (paper defaults)
    options : MethodOptions (profile choice, separable kernel; defaults)
    overwrite : make the passes again even if they exist
    source : ``"blender"`` (Cycles/EEVEE renders of demo_blend) or ``"synthetic"``
    engine, samples : render engine and its samples per pixel (blender only)
    reference_every : reference and PSNR on every k-th frame
    log : progress printer, or None

    Returns
    -------
    summary : ``{scene: {method: {...}}}`` as written to ``summary.json``.

    Raises
    ------
    DemoError
        Unknown source or scene, Blender missing, or a scene it cannot render.
    """
    if source not in SOURCES:
        raise DemoError(f"source must be one of {', '.join(SOURCES)}, got {source!r}")
    scenes = list(SOURCES[source] if scenes is None else scenes)
    bad = [x for x in scenes if x not in SOURCES[source]]
    if not scenes or bad:
        raise DemoError(
            f"scenes of source {source!r} are {', '.join(SOURCES[source])}; "
            f"got {', '.join(scenes) or 'none'}"
        )
    if source == "blender":
        try:
            import bpy  # noqa: F401
        except ImportError:
            raise DemoError(
                "the Blender demo needs bpy==5.0.1 (make demo installs it) or "
                "running inside Blender; --source synthetic needs neither"
            ) from None
    out = Path(out)
    params = params or SSSParams()
    summary = {}
    start = time.perf_counter()

    def stamp(text: str) -> str:
        return f"[{format_clock(time.perf_counter() - start)}] {text}"

    for n, scene in enumerate(scenes, 1):
        scene_dir = out / scene
        passes = scene_dir / "passes"
        if log:
            log(
                stamp(
                    f"scene {n}/{len(scenes)} {scene}: passes ({source}, {width}x{height}, "
                    f"{frames} frames)"
                )
            )
        if source == "blender":
            blender_passes(
                scene,
                scene_dir,
                width,
                height,
                frames,
                engine=engine,
                samples=samples,
                overwrite=overwrite,
                log=(lambda text, scene=scene: log(stamp(f"{scene}: {text}"))) if log else None,
            )
        else:
            _synthetic_passes(scene, scene_dir, width, height, frames, overwrite, log)
        if log:
            log(
                stamp(
                    f"scene {n}/{len(scenes)} {scene}: post-process {', '.join(DEMO_METHODS)} "
                    f"(reference every {reference_every} frame(s))"
                )
            )

        def progress(text: str, scene=scene) -> None:
            if " as_ccv:" in text:  # one line per frame, with elapsed and ETA
                log(stamp(f"{scene}: {text}"))

        rows = run_folder(
            passes,
            scene_dir,
            RunSpec(
                DEMO_METHODS,
                params,
                options or MethodOptions(),
                reference=True,
                reference_every=reference_every,
            ),
            existing="continue",
            log=progress if log else None,
        )
        summary[scene] = summarize(rows)
        if log:
            s = summary[scene]
            log(
                stamp(
                    f"{scene}: "
                    + ", ".join(
                        f"{m} {s[m]['spp']:.1f} spp / {s[m]['psnr_db']:.1f} dB"
                        for m in DEMO_METHODS
                    )
                )
            )
    # JSON has no NaN: a mean without any frame (no reference) is null.
    plain = {
        sc: {
            m: {
                k: (None if isinstance(v, float) and math.isnan(v) else v)
                for k, v in fields.items()
            }
            for m, fields in methods.items()
        }
        for sc, methods in summary.items()
    }
    write_text(out / "summary.json", json.dumps(plain, indent=2))
    for scene in summary:
        make_plots(out, scene, [1, frames], params.beta_max)
    plots.plot_pareto(summary, out / "pareto.png")
    if source == "blender":
        what = f"{engine.title()} passes of the demo_blend scenes ({samples} samples per pixel" + (
            ", fixed seed), " if engine == "CYCLES" else "), "
        )
    else:
        what = "Synthetic passes (core.synthetic), "
    header = [
        f"{what}{width}x{height}, {frames} frames at 60 fps, parameters "
        f"(σ0²={params.target_variance:g}, η={params.eta:g}, η_cv={params.eta_cv:g}, "
        f"κ={params.kappa:g}, ε_u={params.eps_u:g}, β=[{params.beta_min}, {params.beta_max}], "
        f"fixed N={params.fixed_spp}, separable: pre-integrated kernel, 17 taps).",
        f"PSNR: luminance over SSS pixels against the {params.reference_spp}-spp reference, "
        "computed on every "
        + (
            "frame"
            if reference_every == 1
            else f"{_ordinal(reference_every)} frame (frames 1, {1 + reference_every}, …)"
        )
        + ", display-referred.",
        "pass ms: the NumPy sampling step on this machine, 3rd-order median over frames.",
    ]
    write_report(out, summary, header, params.beta_max)
    if log:
        log(_table(summary))
        log(stamp(f"wrote {out / 'summary.json'} and {out / 'report.md'}"))
    return summary


def _ordinal(k: int) -> str:
    if 10 <= k % 100 <= 20:
        return f"{k}th"
    return f"{k}" + {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")

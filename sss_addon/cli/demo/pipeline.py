"""The demo run: passes per scene, every method post-processed, the ground-truth extras,
then the summary, the plots and the report."""

from __future__ import annotations

import csv
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ....core.method import MethodOptions
from ....core.params import SSSParams
from ....core.run import RunSpec, run_folder
from ...precompile import before_first_frame
from ...progress import format_clock, progress_text
from ..truth import TruthPlan, equal_time_rows, format_equal_time
from . import figures
from .analysis import (
    HALF_WEIGHT_MATERIAL,
    conclusion,
    floats,
    material_psnr_gt,
    nanmean,
    shadow_band_psnr,
    summarize,
)
from .passes import CYCLES_SAMPLES, SOURCES, DemoError, blender_passes, synthetic_passes
from .report import header_lines, measured_table, write_report, write_summary, write_truth
from .users import users_frame

#: Methods compared by the demo, in report order.
DEMO_METHODS = (
    "none",
    "as",
    "as_ocv",
    "as_ccv",
    "as_t",
    "as_ccv_t",
    "fixed",
    "separable",
    "reference",
)


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
    truth: TruthPlan | None = None,
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
    truth : TruthPlan (blender source): Cycles ground truth, denoised passes and
        the equal-time comparison (default :class:`TruthPlan`; None with
        ``every=0`` turns them off)

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
    options = options or MethodOptions()
    if truth is None:
        truth = TruthPlan()
    if source != "blender" or engine != "CYCLES" or truth.every < 1:
        truth = None
    summary = {}
    extras: dict = {}
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
                truth=truth,
            )
        else:
            synthetic_passes(scene, scene_dir, width, height, frames, overwrite, log)
        if log:
            log(
                stamp(
                    f"scene {n}/{len(scenes)} {scene}: post-process {', '.join(DEMO_METHODS)} "
                    f"(reference every {reference_every} frame(s))"
                )
            )

        def progress(event, scene=scene) -> None:
            if event.kind == "frame" and event.method == "as_ccv":  # a line per frame, with ETA
                log(stamp(f"{scene}: {progress_text(event)}"))

        ground_truth = scene_dir / "ground_truth" if truth is not None else None
        rows = run_folder(
            passes,
            scene_dir,
            RunSpec(
                DEMO_METHODS,
                params,
                options,
                reference=True,
                reference_every=reference_every,
            ),
            existing="continue",
            log=progress if log else None,
            ground_truth=ground_truth,
            before_first=before_first_frame(params.backend, DEMO_METHODS, log),
        )
        summary[scene] = summarize(rows)
        if truth is not None:
            extras[scene] = truth_extras(
                scene, scene_dir, frames, truth, params, options, samples, log
            )
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
    write_summary(out, summary)
    for scene in summary:
        figures.make_plots(out, scene, [1, frames], params.beta_max)
    figures.plot_pareto(summary, out / "pareto.png")
    header = header_lines(
        source=source,
        engine=engine,
        samples=samples,
        width=width,
        height=height,
        frames=frames,
        params=params,
        reference_every=reference_every,
        truth=truth,
    )
    write_truth(out, extras)
    write_report(out, summary, header, params.beta_max, extras)
    if log:
        log(measured_table(summary))
        log(stamp(f"wrote {out / 'summary.json'} and {out / 'report.md'}"))
    return summary


def truth_extras(
    scene: str,
    scene_dir: Path,
    frames: int,
    truth: TruthPlan,
    params: SSSParams,
    options: MethodOptions,
    samples: int,
    log: Callable[[str], None] | None,
) -> dict:
    """Equal-time table, half-weight material, moving-shadow figures and the "what you had
    / what you get" table (:mod:`.users`) of one scene."""
    table = truth.table_frames(frames)
    extra: dict = {"equal_time_frames": table}
    denoised = scene_dir / "denoised" / "passes"
    if table and denoised.is_dir():
        run_folder(
            denoised,
            scene_dir / "denoised",
            RunSpec(truth.methods, params, options),
            existing="continue",
            ground_truth=scene_dir / "ground_truth",
            before_first=before_first_frame(params.backend, truth.methods, log),
        )
    extra["equal_time"] = equal_time_rows(scene_dir, frames, truth, samples)
    extra["quality"] = quality_against_truth(scene_dir, params, options, log)
    extra["half_weight"] = material_psnr_gt(
        scene_dir, truth.ground_truth_frames(frames), ("none", "as_ccv"), HALF_WEIGHT_MATERIAL
    )
    extra["shadow_band"] = shadow_band_psnr(scene_dir, frames, ("as_ccv", "as_ccv_t"))
    extra["conclusion"] = conclusion(extra["equal_time"])
    if log and extra["equal_time"]:
        log(format_equal_time(extra["equal_time"]))
    users = users_frame(scene, scene_dir, frames, truth.users_frames, truth.users_samples, log)
    if users is not None:
        extra["users_frame"] = users
    return extra


#: σ0² of the quality sweep against ground truth (the default, 1e-4, is the demo's own run).
QUALITY_SIGMAS = (1e-2, 1e-3, 1e-5)


def quality_against_truth(
    scene_dir: Path,
    params: SSSParams,
    options: MethodOptions,
    log: Callable[[str], None] | None,
) -> list[dict]:
    """What the quality knob buys against Cycles: as_ccv at several σ0² on the same passes.

    Each σ0² runs the whole sequence (its history needs every frame) into
    ``<scene>/quality/<σ0²>/``; a row holds the mean spp over all frames, the
    sampling time and the mean PSNR against the ground truth on the
    ground-truth frames after the first (warm history), next to the demo's own
    as_ccv run at the default σ0². Sorted by σ0², largest first.
    """
    rows = []
    ground_truth = scene_dir / "ground_truth"

    def row(sigma: float, metrics: Sequence[dict]) -> dict:
        mine = [r for r in metrics if r["method"] == "as_ccv"]
        gt = [r for r in mine if r.get("psnr_gt_db")][1:]
        return {
            "sigma0_sq": sigma,
            "spp": nanmean(floats(mine, "spp")),
            "sampling_ms": nanmean(floats(mine, "sampling_ms")),
            "psnr_gt_warm_db": nanmean(floats(gt, "psnr_gt_db")),
        }

    for sigma in QUALITY_SIGMAS:
        if log:
            log(f"{scene_dir.name}: quality against ground truth, as_ccv at σ0² = {sigma:g}")
        metrics = run_folder(
            scene_dir / "passes",
            scene_dir / "quality" / f"{sigma:g}",
            RunSpec(("as_ccv",), params.replace(target_variance=sigma), options),
            existing="continue",
            ground_truth=ground_truth,
            before_first=before_first_frame(params.backend, ("as_ccv",), log),
        )
        rows.append(row(sigma, metrics))
    own = scene_dir / "metrics.csv"
    if own.is_file():
        with open(own, newline="", encoding="utf-8") as f:
            rows.append(row(params.target_variance, list(csv.DictReader(f))))
    return sorted(rows, key=lambda r: -r["sigma0_sq"])

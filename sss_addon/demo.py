"""The main job: render (or generate) passes, post-process every method, report.

``cvsss demo --out out/demo`` writes, per scene, ``passes/``, one folder per
method and ``metrics.csv``, then ``summary.json`` and ``report.md`` at the
top. With ``--source synthetic`` (the default until the Blender demo scenes
land) the passes are the analytic scenes of :mod:`cvsss.core.synthetic`,
written as real multi-part EXR files and read back like rendered ones.
"""

from __future__ import annotations

import json
import math
import time
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..core.exr import list_frames, write_passes
from ..core.metrics import median3
from ..core.params import SSSParams
from ..core.synthetic import sequence
from . import report as plots
from .post import post_process, write_text_atomic

#: Methods compared by the demo, in report order.
DEMO_METHODS = ("as", "as_ocv", "as_ccv", "fixed", "reference")
SYNTHETIC_SCENES = ("flash", "regular")

#: Targets of the demo issue: (min spp ratio AS / AS+CCV, max PSNR loss dB).
TARGETS = {"flash": (1.8, 2.0), "regular": (1.3, 1.5), "boids": (1.3, 1.5)}
#: Worst frame's spp under CV at most this times its median.
STEADY = 1.5

#: The paper's Table 3 (UE4, 2560×1440, RTX 2080 Ti), for orientation.
PAPER_TABLE3 = {
    "flash": {"spp": (61.97, 29.58, 26.88), "pass_ms": (1.47, 0.80, 0.75),
              "psnr_db": (51.19, 49.55, 49.43)},
    "regular": {"spp": (26.51, 18.32, 17.82), "pass_ms": (3.39, 2.55, 2.58),
                "psnr_db": (47.85, 47.57, 47.55)},
    "dynamic": {"spp": (22.01, 14.70, 14.13), "pass_ms": (2.02, 1.54, 1.52),
                "psnr_db": (50.62, 49.11, 49.11)},
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
    lines = ["| scene | method | mean spp | max spp | pass ms | PSNR dB |",
             "| --- | --- | ---: | ---: | ---: | ---: |"]
    for scene, methods in summary.items():
        for m, v in methods.items():
            lines.append(f"| {scene} | {m} | {v['spp']:.2f} | {v['spp_max']:.2f} | "
                         f"{v['pass_ms']:.2f} | {v['psnr_db']:.2f} |")
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
        rows.append({"scene": scene, "check": f"spp AS / AS+CCV >= {min_ratio}",
                     "value": ratio, "met": bool(ratio >= min_ratio)})
        rows.append({"scene": scene, "check": f"PSNR loss AS -> AS+CCV <= {max_loss} dB",
                     "value": loss, "met": bool(loss <= max_loss)})
        for m in ("as_ocv", "as_ccv", "as"):
            if m in s:
                steady = s[m]["spp_max"] / max(s[m]["spp_median"], 1e-12)
                rows.append({"scene": scene, "check": f"{m}: max spp / median spp <= {STEADY}",
                             "value": steady, "met": bool(steady <= STEADY) if m != "as" else None})
    return rows


def write_report(out: Path, summary: dict, header: list[str], beta_max: int) -> Path:
    """report.md with the table beside the paper's, targets, and the plots."""
    lines = ["# cvsss demo report", "", *header, "", "## Measured", "", _table(summary), "",
             "## The paper's Table 3 (UE4, 2560×1440, RTX 2080 Ti), AS / +OCV / +CCV", "",
             "| scene | spp | pass ms | PSNR dB |", "| --- | --- | --- | --- |"]
    for scene, v in PAPER_TABLE3.items():
        lines.append(f"| {scene} | {' / '.join(map(str, v['spp']))} | "
                     f"{' / '.join(map(str, v['pass_ms']))} | {' / '.join(map(str, v['psnr_db']))} |")
    lines += ["", "## Targets", "", "| scene | check | measured | met |", "| --- | --- | ---: | --- |"]
    for r in check_targets(summary):
        met = {True: "yes", False: "**no**", None: "(reference: AS alone)"}[r["met"]]
        lines.append(f"| {r['scene']} | {r['check']} | {r['value']:.2f} | {met} |")
    lines += ["", "## Plots", ""]
    for scene in summary:
        for name, text in ((f"{scene}_frames.png", f"{scene}: per frame (cf. the paper's Fig. 8)"),
                           (f"{scene}_strip_as.png", f"{scene}: AS sample counts"),
                           (f"{scene}_strip_as_ccv.png", f"{scene}: AS + CCV sample counts")):
            if (out / name).exists():
                lines += [f"### {text}", "", f"![{text}]({name})", ""]
    if (out / "pareto.png").exists():
        lines += ["### PSNR against sampling-pass time, every method", "", "![pareto](pareto.png)", ""]
    lines += ["Sample-count maps share the colour scale [0, β_max = "
              f"{beta_max}]; grey is outside the SSS materials."]
    path = out / "report.md"
    write_text_atomic(path, "\n".join(lines) + "\n")
    return path


def make_plots(out: Path, scene: str, rows_frames: list[int], beta_max: int) -> None:
    """Per-scene plots and previews from the files already written."""
    scene_dir = out / scene
    metrics = plots.read_metrics(scene_dir / "metrics.csv")
    plots.plot_frames(metrics, out / f"{scene}_frames.png", scene)
    picks = sorted(set(np.linspace(rows_frames[0], rows_frames[-1], 5).round().astype(int)))
    for method in ("as", "as_ccv"):
        if (scene_dir / method).is_dir():
            plots.plot_strip(scene_dir, method, picks, out / f"{scene}_strip_{method}.png", beta_max)
    mid = picks[len(picks) // 2]
    plots.plot_preview(scene_dir, "as_ccv", mid, out / f"{scene}_preview_{mid:04d}.png", beta_max)


def run_demo(
    out: Path,
    *,
    scenes: Sequence[str] = SYNTHETIC_SCENES,
    width: int = 160,
    height: int = 90,
    frames: int = 60,
    params: SSSParams | None = None,
    overwrite: bool = False,
    log: Callable[[str], None] | None = print,
) -> dict:
    """Generate passes, post-process every demo method, write summary and report.

    Returns
    -------
    summary : ``{scene: {method: {...}}}`` as written to ``summary.json``.
    """
    out = Path(out)
    params = params or SSSParams()
    summary = {}
    start = time.perf_counter()
    for scene in scenes:
        passes = out / scene / "passes"
        have = {n for n, _ in list_frames(passes)} if passes.is_dir() and any(passes.glob("*.exr")) else set()
        for frame in sequence(scene, frames, width, height):
            if frame.number not in have or overwrite:
                write_passes(passes / f"{frame.number:04d}.exr", frame, overwrite=True)
        if log:
            log(f"[{time.perf_counter() - start:6.1f} s] {scene}: {frames} frames of passes "
                f"({width}x{height}) in {passes}")
        rows = post_process(passes, out / scene, DEMO_METHODS, params, reference=True,
                            overwrite=True, log=None)
        summary[scene] = summarize(rows)
        if log:
            s = summary[scene]
            log(f"[{time.perf_counter() - start:6.1f} s] {scene}: " + ", ".join(
                f"{m} {s[m]['spp']:.1f} spp / {s[m]['psnr_db']:.1f} dB" for m in DEMO_METHODS))
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=2))
    for scene in summary:
        make_plots(out, scene, [1, frames], params.beta_max)
    plots.plot_pareto(summary, out / "pareto.png")
    header = [
        f"Synthetic passes, {width}x{height}, {frames} frames at 60 fps, paper defaults "
        f"(σ0²={params.target_variance:g}, η={params.eta:g}, η_cv={params.eta_cv:g}, "
        f"κ={params.kappa:g}, ε_u={params.eps_u:g}, β=[{params.beta_min}, {params.beta_max}]).",
        "PSNR: luminance over SSS pixels against the 1024-spp reference (every frame), "
        "display-referred.",
        "pass ms: the NumPy sampling step on this machine, 3rd-order median over frames.",
    ]
    write_report(out, summary, header, params.beta_max)
    if log:
        log(_table(summary))
        log(f"wrote {out / 'summary.json'} and {out / 'report.md'}")
    return summary

"""What the demo writes at the top of its output folder: ``summary.json``,
``truth.json`` and ``report.md`` (the measured table beside the paper's, the
targets, the plots)."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path

from ....core.backends import select as mc_backend
from ....core.io.atomic import write_text
from ....core.params import SSSParams
from ..truth import TruthPlan, format_equal_time
from .analysis import SWITCH
from .targets import check_targets, check_temporal_targets, check_truth_targets, truth_reasons
from .users import format_users_frame

#: The paper's Table 3 (UE4, 2560×1440, RTX 2080 Ti), for orientation.
PAPER_TABLE3 = {
    "flash": {
        "spp": (61.97, 29.58, 26.88),
        "sampling_ms": (1.47, 0.80, 0.75),
        "psnr_db": (51.19, 49.55, 49.43),
    },
    "regular": {
        "spp": (26.51, 18.32, 17.82),
        "sampling_ms": (3.39, 2.55, 2.58),
        "psnr_db": (47.85, 47.57, 47.55),
    },
    "dynamic": {
        "spp": (22.01, 14.70, 14.13),
        "sampling_ms": (2.02, 1.54, 1.52),
        "psnr_db": (50.62, 49.11, 49.11),
    },
}


def measured_table(summary: dict) -> str:
    lines = [
        "| scene | method | mean spp | max spp | sampling ms | PSNR dB (self) "
        "| PSNR dB (vs Cycles GT) | GT whole image | rim ratio (outer / contact) | flicker |",
        "| --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: |",
    ]
    for scene, methods in summary.items():
        for m, v in methods.items():
            lines.append(
                f"| {scene} | {m} | {v['spp']:.2f} | {v['spp_max']:.2f} | "
                f"{v['sampling_ms']:.2f} | {v['psnr_db']:.2f} | {v.get('psnr_gt_db', math.nan):.2f} | "
                f"{v.get('psnr_gt_full_db', math.nan):.2f} | {v.get('rim_ratio', math.nan):.3f} "
                f"({v.get('rim_outer_ratio', math.nan):.3f} / "
                f"{v.get('rim_contact_ratio', math.nan):.3f}) | "
                f"{v.get('flicker', math.nan):.5f} |"
            )
    return "\n".join(lines)


def _targets_table(rows: list[dict]) -> list[str]:
    lines = ["| scene | check | measured | met |", "| --- | --- | ---: | --- |"]
    for r in rows:
        met = {True: "yes", False: "**no**", None: "(reported)"}[r["met"]]
        lines.append(f"| {r['scene']} | {r['check']} | {r['value']:.3f} | {met} |")
    return lines


def write_report(
    out: Path,
    summary: dict,
    header: list[str],
    beta_max: int,
    extras: dict | None = None,
) -> Path:
    """report.md with the table beside the paper's, targets, and the plots."""
    lines = [
        "# cvsss demo report",
        "",
        *header,
        "",
        "## Measured",
        "",
        measured_table(summary),
        "",
        "## The paper's Table 3 (UE4, 2560×1440, RTX 2080 Ti), AS / +OCV / +CCV",
        "",
        "| scene | spp | sampling ms | PSNR dB |",
        "| --- | --- | --- | --- |",
    ]
    for scene, v in PAPER_TABLE3.items():
        lines.append(
            f"| {scene} | {' / '.join(map(str, v['spp']))} | "
            f"{' / '.join(map(str, v['sampling_ms']))} | {' / '.join(map(str, v['psnr_db']))} |"
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
    extras = extras or {}
    truth = check_truth_targets(summary, extras)
    if truth:
        lines += [
            "",
            "## Against Cycles ground truth",
            "",
            "Self-referenced PSNR measures our Monte Carlo noise against our own 1024-spp "
            "estimate on the same passes; PSNR against Cycles ground truth (its own "
            "Christensen-Burley subsurface, path traced) is what a Blender user sees: model "
            "error, pass noise and Cycles' own noise included. Both are in the table above, "
            "labelled.",
            "",
            *_targets_table(truth),
            *truth_reasons(summary, extras, truth),
        ]
        for scene, e in extras.items():
            if e.get("equal_time"):
                lines += [
                    "",
                    f"### {scene}: equal time (frames {e['equal_time_frames']})",
                    "",
                    format_equal_time(e["equal_time"]),
                ]
        for scene, e in extras.items():
            if e.get("users_frame"):
                reference = summary.get(scene, {}).get("reference")
                lines += format_users_frame(scene, e["users_frame"], reference)
        for scene, e in extras.items():
            if e.get("quality"):
                lines += [
                    "",
                    f"### {scene}: the quality knob against Cycles (as_ccv, σ0² swept)",
                    "",
                    format_quality(e["quality"]),
                ]
        if any(e.get("conclusion") for e in extras.values()):
            lines += ["", "### Conclusion", ""]
            lines += [
                f"- {scene}: {e['conclusion']}"
                for scene, e in extras.items()
                if e.get("conclusion")
            ]
    temporal = check_temporal_targets(summary, extras)
    if temporal:
        lines += [
            "",
            "## Temporal reuse",
            "",
            "as_t accumulates plainly (the ghosting baseline); as_ccv_t is guided by the "
            "control and a noise-free separable proxy. Frames after a flash or switch: "
            f"mean lighting changed by >= {SWITCH:.0%} since the previous frame.",
            "",
            *_targets_table(temporal),
        ]
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
            "### PSNR against sampling time, every method",
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


def format_quality(rows: Sequence[dict]) -> str:
    """Markdown table of :func:`quality_against_truth`."""
    lines = [
        "| σ0² | mean spp | sampling ms | PSNR vs Cycles GT, warm frames (dB) |",
        "| ---: | ---: | ---: | ---: |",
    ]
    for r in rows:
        lines.append(
            f"| {r['sigma0_sq']:g} | {r['spp']:.1f} | {r['sampling_ms']:.1f} | "
            f"{r['psnr_gt_warm_db']:.2f} |"
        )
    return "\n".join(lines)


def _json_ready(obj):
    """``obj`` with NaN replaced by None (JSON has no NaN)."""
    if isinstance(obj, dict):
        return {k: _json_ready(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_json_ready(v) for v in obj]
    if isinstance(obj, float) and math.isnan(obj):
        return None
    return obj


def _ordinal(k: int) -> str:
    if 10 <= k % 100 <= 20:
        return f"{k}th"
    return f"{k}" + {1: "st", 2: "nd", 3: "rd"}.get(k % 10, "th")


def write_summary(out: Path, summary: dict) -> Path:
    """``summary.json``: :func:`.analysis.summarize` of every scene."""
    # JSON has no NaN: a mean without any frame (no reference) is null.
    path = out / "summary.json"
    write_text(path, json.dumps(_json_ready(summary), indent=2))
    return path


def write_truth(out: Path, extras: dict) -> Path:
    """``truth.json``: the ground-truth figures of every scene (without the conclusion)."""
    plain_extras = {
        sc: {k: v for k, v in e.items() if k != "conclusion"} for sc, e in extras.items()
    }
    path = out / "truth.json"
    write_text(path, json.dumps(_json_ready(plain_extras), indent=2))
    return path


def header_lines(
    *,
    source: str,
    engine: str,
    samples: int,
    width: int,
    height: int,
    frames: int,
    params: SSSParams,
    reference_every: int,
    truth: TruthPlan | None,
) -> list[str]:
    """The lines at the top of report.md: where the passes came from, the parameters, and
    how PSNR and the sampling time were measured."""
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
        f"sampling ms: the Monte Carlo sampling step on this machine ({mc_backend.describe(params.backend)}), "
        f"3rd-order median over frames; sample kernel: {params.distance}.",
    ]
    if truth is not None:
        header.append(
            f"Ground truth: Cycles, Christensen-Burley subsurface, {truth.samples} spp, "
            f"denoising off, on every {_ordinal(truth.every)} frame; PSNR against it is RGB "
            "over SSS pixels (and the whole image), exposure 1/p99 of the ground truth's "
            "brightest channel, sRGB, clipped (core.eval.metrics)."
        )
    return header

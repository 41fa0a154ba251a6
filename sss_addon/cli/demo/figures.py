"""Plots and previews of a demo run (matplotlib, Agg backend; no Blender).

Reads ``<scene>/metrics.csv`` and the result EXRs written by ``cvsss post`` /
``cvsss demo`` and writes PNGs next to the report:

- ``<scene>_frames.png``: spp, sampling time and PSNR per frame for AS,
  AS+OCV and AS+CCV (the paper's Fig. 8);
- ``<scene>_strip.png``: a strip of frames, composite above sample-count map;
- ``pareto.png``: PSNR against sampling time of every method and scene;
- ``<scene>_preview_####.png``: composite and sample-count map side by side.

Composites are shown display-referred (exposure, sRGB, clipped); sample-count
maps use a fixed colour scale [0, β_max] so frames and methods compare.
"""

from __future__ import annotations

import csv
from collections import defaultdict
from pathlib import Path

import numpy as np

from ....core.color import srgb_encode
from ....core.eval.metrics import median3
from ....core.io.exr import read_result

ADAPTIVE = (
    ("as", "AS"),
    ("as_ocv", "AS + OCV"),
    ("as_ccv", "AS + CCV"),
    ("as_ccv_t", "AS + CCV + temporal"),
)
#: Methods also drawn in the PSNR panels (no sample-count curve of interest).
BASELINES = (("none", "no SSS"), ("separable", "separable"))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def read_metrics(path: Path) -> dict[str, dict[str, np.ndarray]]:
    """``{method: {"frame", "spp", "sampling_ms", "psnr_db", "psnr_gt_db"}}`` arrays (NaN: absent)."""
    cols: dict[str, dict[str, list]] = defaultdict(lambda: defaultdict(list))
    with open(path, newline="", encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            c = cols[row["method"]]
            c["frame"].append(int(row["frame"]))
            c["spp"].append(float(row["spp"]))
            c["sampling_ms"].append(float(row["sampling_ms"]))
            for key in ("psnr_db", "psnr_gt_db"):
                c[key].append(float(row[key]) if row.get(key) else np.nan)
    return {m: {k: np.asarray(v) for k, v in c.items()} for m, c in cols.items()}


def plot_frames(metrics: dict, path: Path, title: str) -> Path:
    """Per-frame spp, sampling time (3rd-order median), PSNR against our reference and
    (when rendered) against Cycles ground truth, of the adaptive methods and baselines."""
    plt = _pyplot()
    with_gt = any(np.isfinite(m["psnr_gt_db"]).any() for m in metrics.values())
    rows = 4 if with_gt else 3
    fig, axes = plt.subplots(rows, 1, figsize=(7.5, 2.4 * rows), sharex=True)
    for name, label in ADAPTIVE + BASELINES:
        if name not in metrics:
            continue
        m = metrics[name]
        if (name, label) in ADAPTIVE:
            axes[0].plot(m["frame"], m["spp"], label=label)
            axes[1].plot(m["frame"], median3(m["sampling_ms"]), label=label)
        ok = np.isfinite(m["psnr_db"])
        style = "--" if (name, label) in BASELINES else ".-"
        axes[2].plot(m["frame"][ok], m["psnr_db"][ok], style, label=label)
        if with_gt:
            ok = np.isfinite(m["psnr_gt_db"])
            axes[3].plot(m["frame"][ok], m["psnr_gt_db"][ok], style.replace(".", "o"), label=label)
    axes[0].set_ylabel("mean spp (SSS pixels)")
    axes[1].set_ylabel("sampling pass (ms)")
    axes[2].set_ylabel("PSNR vs our reference (dB)")
    if with_gt:
        axes[3].set_ylabel("PSNR vs Cycles GT (dB)")
        axes[3].legend(loc="lower right", fontsize=7)
    axes[-1].set_xlabel("frame (60 fps)")
    axes[0].legend(loc="upper right")
    axes[0].set_title(title)
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _display(rgb: np.ndarray, exposure: float = 1.0) -> np.ndarray:
    return srgb_encode(np.asarray(rgb) * exposure)


def plot_strip(
    scene_dir: Path,
    method: str,
    frames: list[int],
    path: Path,
    beta_max: int = 64,
    exposure: float = 1.0,
) -> Path:
    """Composite (top) and sample-count map (bottom) for a few frames."""
    plt = _pyplot()
    n = len(frames)
    fig, axes = plt.subplots(2, n, figsize=(2.6 * n, 3.4), squeeze=False)
    im = None
    for j, number in enumerate(frames):
        res = read_result(scene_dir / method / f"{number:04d}.exr")
        axes[0, j].imshow(_display(res["Composite"], exposure))
        axes[0, j].set_title(f"frame {number}", fontsize=9)
        counts = np.where(res["Mask"] > 0, res["SampleCount"], np.nan)
        im = axes[1, j].imshow(counts, vmin=0, vmax=beta_max, cmap="viridis")
        for ax in axes[:, j]:
            ax.set_xticks([])
            ax.set_yticks([])
    axes[0, 0].set_ylabel("composite")
    axes[1, 0].set_ylabel(f"{method} spp")
    if im is not None:
        fig.colorbar(im, ax=axes[1, :].tolist(), shrink=0.8, label="samples")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_preview(
    scene_dir: Path, method: str, number: int, path: Path, beta_max: int = 64, exposure: float = 1.0
) -> Path:
    """One frame: composite and sample-count map side by side."""
    plt = _pyplot()
    res = read_result(scene_dir / method / f"{number:04d}.exr")
    fig, axes = plt.subplots(1, 2, figsize=(8, 2.6))
    axes[0].imshow(_display(res["Composite"], exposure))
    axes[0].set_title(f"{method} composite, frame {number}", fontsize=9)
    im = axes[1].imshow(
        np.where(res["Mask"] > 0, res["SampleCount"], np.nan), vmin=0, vmax=beta_max, cmap="viridis"
    )
    axes[1].set_title("samples per pixel", fontsize=9)
    for ax in axes:
        ax.set_xticks([])
        ax.set_yticks([])
    fig.colorbar(im, ax=axes[1], shrink=0.8)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def plot_pareto(summary: dict, path: Path) -> Path:
    """PSNR against mean sampling time for every method and scene."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 4.2))
    markers = "os^vDP*X"
    methods = sorted({m for s in summary.values() for m in s if m != "reference"})
    for i, scene in enumerate(summary):
        for j, method in enumerate(methods):
            v = summary[scene].get(method)
            if v is None or not np.isfinite(v["psnr_db"]):
                continue
            ax.scatter(
                v["sampling_ms"],
                v["psnr_db"],
                marker=markers[j % len(markers)],
                color=f"C{i}",
                label=f"{scene}: {method}",
            )
    ax.set_xscale("log")
    ax.set_xlabel("mean sampling pass (ms, log)")
    ax.set_ylabel("mean PSNR vs reference (dB)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def make_plots(out: Path, scene: str, rows_frames: list[int], beta_max: int) -> None:
    """Per-scene plots and previews from the files already written."""
    scene_dir = out / scene
    metrics = read_metrics(scene_dir / "metrics.csv")
    plot_frames(metrics, out / f"{scene}_frames.png", scene)
    picks = sorted(set(np.linspace(rows_frames[0], rows_frames[-1], 5).round().astype(int)))
    for method in ("as", "as_ccv"):
        if (scene_dir / method).is_dir():
            plot_strip(scene_dir, method, picks, out / f"{scene}_strip_{method}.png", beta_max)
    mid = picks[len(picks) // 2]
    plot_preview(scene_dir, "as_ccv", mid, out / f"{scene}_preview_{mid:04d}.png", beta_max)

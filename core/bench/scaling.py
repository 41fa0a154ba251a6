"""Sections ``coverage`` and ``resolution``: time against SSS coverage and resolution."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from ..frame import Frame
from ..methods import make_processor
from ..params import SSSParams
from ..synthetic import scene_frame
from .config import BenchConfig, Log, Size, progress, size_key
from .jobs import Job, median_of, run_jobs, steady, synthetic_frames


def _scaling_row(records: list[dict], size: Size) -> dict:
    sss = median_of(records, "sss_pixels")
    distant = float(np.median([r["sss_pixels"] * r["distant_share"] for r in records]))
    total, pss = median_of(records, "total_ms"), median_of(records, "sampling_ms")
    samples = median_of(records, "samples")
    return {
        "size": size_key(size),
        "pixels": size[0] * size[1],
        "sss_pixels": sss,
        "distant_pixels": distant,
        "samples": samples,
        "spp": median_of(records, "spp"),
        "total_ms": total,
        "sampling_ms": pss,
        "ns_per_sss_pixel": total * 1e6 / sss if sss else math.nan,
        "ns_per_sample": pss * 1e6 / samples if samples else math.nan,
    }


def _scaling_rows(
    cfg: BenchConfig,
    method: str,
    runs: Sequence[tuple[str, SSSParams, Callable[[int], Frame], Size]],
    count: int,
) -> list[dict]:
    """Run ``(label, params, frame source, size)`` configurations interleaved over
    ``count`` frames; one :func:`_scaling_row` each (frames after the first)."""
    jobs = run_jobs(
        [
            Job(label, method, params, source, repeats=cfg.repeats)
            for label, params, source, _ in runs
        ],
        count,
    )
    return [_scaling_row(steady(job.records), run[3]) for job, run in zip(jobs, runs)]


def section_coverage(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Time against SSS coverage, and against the share of pixels above ε_u."""
    method = cfg.scaling_method
    base = SSSParams(seed=cfg.seed)
    size, count = cfg.coverage_size, cfg.scaling_frames
    seqs = {cov: synthetic_frames(cfg.scene, size, count, coverage=cov) for cov in cfg.coverages}
    rows = _scaling_rows(
        cfg,
        method,
        [(f"{cov:.0%}", base, seqs[cov].__getitem__, size) for cov in cfg.coverages],
        count,
    )
    for cov, row in zip(cfg.coverages, rows):
        row["coverage"] = cov
        progress(
            log,
            start,
            f"coverage {cov:4.0%}: {row['total_ms']:7.1f} ms/frame, "
            f"{row['ns_per_sss_pixel']:7.1f} ns per SSS pixel",
        )
    ref = max(rows, key=lambda r: r["coverage"])
    for row in rows:
        row["time_ratio"] = row["total_ms"] / ref["total_ms"]
        row["pass_ratio"] = row["sampling_ms"] / ref["sampling_ms"]
        row["sss_ratio"] = row["sss_pixels"] / ref["sss_pixels"]
    out = {
        "size": size_key(size),
        "method": method,
        "rows": rows,
        "ns_per_sss_pixel_spread": (
            max(r["ns_per_sss_pixel"] for r in rows) / min(r["ns_per_sss_pixel"] for r in rows)
        ),
    }
    # ε_u: the scene's own objects (γ varies with depth over the sphere); ε_u at the
    # median max γ leaves about half of the SSS pixels without distant samples.
    del seqs
    frames = synthetic_frames(cfg.scene, size, count)
    probe = make_processor(method, base).process(frames[0])
    eps = float(np.median(probe.gamma.astype(np.float64).max(axis=-1)[probe.mask]))
    del probe
    if 0.0 < eps <= 1.0:
        a, b = _scaling_rows(
            cfg,
            method,
            [
                ("default ε_u", base, frames.__getitem__, size),
                ("median ε_u", base.replace(eps_u=eps), frames.__getitem__, size),
            ],
            count,
        )
        out["eps_u"] = e = {
            "scene": f"synthetic {cfg.scene}",
            "eps_u": eps,
            "default_eps_u": base.eps_u,
            "default": a,
            "raised": b,
            "distant_ratio": b["distant_pixels"] / a["distant_pixels"],
            "samples_ratio": b["samples"] / a["samples"],
            "pass_ratio": b["sampling_ms"] / a["sampling_ms"],
            "time_ratio": b["total_ms"] / a["total_ms"],
        }
        progress(
            log,
            start,
            f"ε_u {eps:.3f} vs {base.eps_u:g}: distant pixels × "
            f"{e['distant_ratio']:.2f}, samples × {e['samples_ratio']:.2f}, "
            f"sampling time × {e['pass_ratio']:.2f}",
        )
    return out


def section_resolution(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Time per frame over resolution, divided by the pixel count."""
    method = cfg.scaling_method
    base = SSSParams(seed=cfg.seed)

    def source(size: Size) -> Callable[[int], Frame]:
        return lambda i: scene_frame(cfg.scene, i + 1, size[0], size[1])

    rows = _scaling_rows(
        cfg,
        method,
        [(size_key(sz), base, source(sz), sz) for sz in cfg.scaling_sizes],
        cfg.scaling_frames,
    )
    for size, row in zip(cfg.scaling_sizes, rows):
        row["ns_per_pixel"] = row["total_ms"] * 1e6 / row["pixels"]
        row["pass_ns_per_pixel"] = row["sampling_ms"] * 1e6 / row["pixels"]
        progress(
            log,
            start,
            f"resolution {size_key(size)}: {row['total_ms']:8.1f} ms/frame, "
            f"{row['ns_per_pixel']:6.1f} ns/pixel, {row['spp']:5.1f} spp",
        )
    per_px = [r["ns_per_pixel"] for r in rows]
    per_sample = [r["ns_per_sample"] for r in rows]
    return {
        "method": method,
        "frames": cfg.scaling_frames,
        "rows": rows,
        "ns_per_pixel_spread": max(per_px) / min(per_px),
        "ns_per_sample_spread": max(per_sample) / min(per_sample),
    }

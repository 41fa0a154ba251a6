"""Section ``fit``: the linear fit of sampling time against samples taken."""

from __future__ import annotations

import math

import numpy as np

from ..params import SSSParams
from .config import ADAPTIVE, BenchConfig, Log, progress, size_key
from .jobs import Job, median_of, run_jobs, steady, synthetic_frames


def linear_fit(x: np.ndarray, y: np.ndarray) -> dict:
    """Least-squares ``y = a + b·x`` with R² (nan when x or y is constant).

    >>> f = linear_fit(np.array([1.0, 2.0, 3.0]), np.array([3.0, 5.0, 7.0]))
    >>> round(f["slope"], 6), round(f["intercept"], 6), round(f["r2"], 6)
    (2.0, 1.0, 1.0)
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    if x.size < 2 or np.ptp(x) == 0:
        return {"slope": math.nan, "intercept": math.nan, "r2": math.nan}
    b, a = np.polyfit(x, y, 1)
    ss_res = float(np.sum((y - (a + b * x)) ** 2))
    ss_tot = float(np.sum((y - y.mean()) ** 2))
    return {
        "slope": float(b),
        "intercept": float(a),
        "r2": 1.0 - ss_res / ss_tot if ss_tot > 0 else math.nan,
    }


def section_fit(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Sampling-step time against samples across fixed N and the adaptive methods."""
    frames = synthetic_frames(cfg.scene, cfg.fit_size, cfg.fit_frames)
    base = SSSParams(seed=cfg.seed)
    jobs = [
        Job(
            f"fixed N={n}",
            "fixed",
            base.replace(fixed_spp=n),
            frames.__getitem__,
            repeats=cfg.repeats,
        )
        for n in cfg.fit_fixed_spp
    ]
    jobs += [Job(m, m, base, frames.__getitem__, repeats=cfg.repeats) for m in ADAPTIVE]
    run_jobs(jobs, len(frames))
    points, configs = [], {}
    for job in jobs:
        st = steady(job.records)
        points += [[r["samples"], r["sampling_ms"], job.label] for r in st]
        configs[job.label] = {
            "samples": median_of(st, "samples"),
            "sampling_ms": median_of(st, "sampling_ms"),
            "overhead_fraction": median_of(st, "update_ms") / median_of(st, "total_ms"),
        }
    fit = linear_fit(np.array([p[0] for p in points]), np.array([p[1] for p in points]))
    progress(
        log,
        start,
        f"fit {size_key(cfg.fit_size)}: R² = {fit['r2']:.4f} over "
        f"{len(points)} frames, {fit['slope'] * 1e6:.1f} ns/sample",
    )
    return {
        "size": size_key(cfg.fit_size),
        "value": fit["r2"],
        "slope_ns_per_sample": fit["slope"] * 1e6,
        "intercept_ms": fit["intercept"],
        "configs": configs,
        "points": points,
    }

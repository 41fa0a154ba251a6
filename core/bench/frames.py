"""Section ``frames``: whole-frame time per backend, size and method, and the steady
frames of the temporal method against ``as_ccv``."""

from __future__ import annotations

from typing import Any

import numpy as np

from ..backends import select as mc_backend
from ..params import SSSParams
from .config import BenchConfig, Log, progress, size_key
from .cost import available_backends
from .jobs import Job, run_jobs, synthetic_frames


def section_frames(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Whole-frame time (ms) per backend, size and method: ``{backend: {size: {method: ms}}}``,
    and ``steady``: :func:`steady_frames` (with ``cfg.steady_size``).

    Each configuration processes ``frame_frames`` frames and the last one is
    recorded. The default, 1, records the first frame: no history yet, so
    the adaptive methods take n_init = β_max samples per pixel, as they still
    do on the second frame — an upper bound of a steady frame's time at half
    the cost of timing the second.
    """
    backends = available_backends(cfg)
    out: dict[str, Any] = {
        "frames": cfg.frame_frames,
        "backend_default": mc_backend.resolve("auto"),
    }
    out.update({b: {} for b in backends})
    base = SSSParams(seed=cfg.seed)
    for size in cfg.frame_sizes:
        frames = synthetic_frames(cfg.scene, size, cfg.frame_frames)
        jobs = [
            Job(f"{m}@{b}", m, base.replace(backend=b), frames.__getitem__)
            for b in backends
            for m in cfg.frame_methods
        ]
        for job in jobs:
            job.record_from = len(frames) - 1  # the last frame processed
        run_jobs(jobs, len(frames))
        for job in jobs:
            (rec,) = job.records
            b = job.params.backend
            out[b].setdefault(size_key(size), {})[job.method] = rec["total_ms"]
            progress(
                log,
                start,
                f"frame {size_key(size)} {b:>5} {job.method:>6}: {rec['total_ms']:8.1f} ms "
                f"({rec['spp']:.1f} spp, sampling {rec['sampling_ms']:.1f} ms)",
            )
        del frames, jobs
    if cfg.steady_size is not None:
        out["steady"] = steady_frames(cfg, log, start)
    return out


def steady_frames(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Seconds per steady frame of ``cfg.steady_methods`` at ``cfg.steady_size`` on the
    default backend.

    Each method's history is warmed up over ``steady_warmup`` frames of the sequence,
    then ``steady_runs`` more frames are timed (the whole ``process()`` call,
    ``FrameResult.total_ms``), one frame of every method in turn (run_jobs), so a slow
    spell of the machine lands on all of them alike. A still scene's later frames reuse
    its Geometry and what is kept with it, as a rendered sequence's do.

    Returns
    -------
    dict with ``size``, ``backend``, ``warmup``, ``runs`` and ``methods``: per method
    ``median_s``, ``min_s``, ``max_s``, ``runs_s`` (each frame's seconds, in order) and
    ``cpu_share`` (median; below ~0.9 the machine was busy with other processes)
    """
    backend = mc_backend.resolve("auto")
    params = SSSParams(seed=cfg.seed, backend=backend)
    count = cfg.steady_warmup + cfg.steady_runs
    frames = synthetic_frames(cfg.scene, cfg.steady_size, count)
    jobs = [Job(m, m, params, frames.__getitem__) for m in cfg.steady_methods]
    for job in jobs:
        job.record_from = cfg.steady_warmup
    run_jobs(jobs, count)
    out: dict[str, Any] = {
        "size": size_key(cfg.steady_size),
        "backend": backend,
        "warmup": cfg.steady_warmup,
        "runs": cfg.steady_runs,
        "methods": {},
    }
    for job in jobs:
        runs = [r["total_ms"] / 1e3 for r in job.records]
        out["methods"][job.method] = {
            "median_s": float(np.median(runs)),
            "min_s": min(runs),
            "max_s": max(runs),
            "runs_s": runs,
            "cpu_share": float(np.median([r["cpu_share"] for r in job.records])),
        }
        row = out["methods"][job.method]
        progress(
            log,
            start,
            f"steady {out['size']} {backend} {job.method:>8}: {row['median_s']:.3f} s "
            f"({row['min_s']:.3f}-{row['max_s']:.3f}, {len(runs)} frames)",
        )
    return out

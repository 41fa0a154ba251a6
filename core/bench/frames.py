"""Section ``frames``: whole-frame time per backend, size and method."""

from __future__ import annotations

from typing import Any

from ..backends import select as mc_backend
from ..params import SSSParams
from .config import BenchConfig, Log, progress, size_key
from .cost import available_backends
from .jobs import Job, run_jobs, synthetic_frames


def section_frames(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Whole-frame time (ms) per backend, size and method: ``{backend: {size: {method: ms}}}``.

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
    return out

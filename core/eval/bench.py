"""Speed and the speed/accuracy trade, measured: ``cvsss bench`` (``make bench``).

Every figure is a ratio or a fit of quantities measured side by side in one
run on this machine, so it means something on any machine:

``ns_per_sample``
    Wall time of the Monte Carlo sampling step (``FrameResult.pass_ms``)
    divided by the samples it took, at 640×360 and 1280×720 (median over
    frames 2…n of the flashing-light sequence; frame 1 has no history).
``gather_ns_per_sample``
    The roofline it is held against: the same number of random local
    gathers (3 float32 per sample, offsets uniform in a ±16-pixel square
    around the same SSS pixels) from the same lighting image with
    ``np.take``, best of three.
``samples_time_r2``
    R² of a linear fit of sampling-step time against samples taken over the
    frames of ``fixed`` N ∈ {8, 16, 32, 64}, ``as``, ``as_ocv``, ``as_ccv``.
``overhead_fraction``
    History update + CV bookkeeping (``update_ms``) over the whole frame
    (``total_ms``), per method.
``coverage_scaling`` / ``resolution_scaling``
    Time per frame against SSS coverage (10/50/100 % of the same image, plus
    an ε_u that leaves half of the SSS pixels without distant samples) and
    against resolution (time / pixel count should be flat).
``peak_rss_mb``
    Peak resident memory of one process post-processing one frame, per
    method and history precision (one subprocess per configuration, VmHWM).
``pareto``
    Mean spp, mean pass ms (3rd-order median over frames, P Sec. 7) and mean
    PSNR against the 1024-spp reference on the flashing-light sequence for
    ``fixed`` N ∈ {1…64}, the adaptive methods over σ0² ∈ {1e-2…1e-6} (and
    the extra σ0²/β_min of the quality calibration), and every separable
    kernel when the ``separable`` method exists.

The reference
-------------
A 1024-spp reference per frame is the expensive part. When every frame's
lighting is an affine function of one scalar, ``B_t = B_a + s_t·(B_b − B_a)``
with the same geometry (true of the synthetic flash sequence, where one light
changes intensity; checked numerically on the frames, not assumed), the
estimator is linear in B for a fixed set of samples, so the reference of
every frame is the same combination of two references computed with one
sample pattern (frame number 0, the reference's own seed). Otherwise the
reference is computed frame by frame.

The shipped quality calibration (``core/data/quality_calibration.json``) is
the calibration this bench writes; ``--write-calibration`` replaces it.
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import gc
import json
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..frame import Frame
from ..mc.processor import SequenceProcessor
from ..methods import METHODS
from ..params import PAPER_DEFAULTS, SSSParams
from ..synthetic import scene_frame
from . import quality
from .metrics import median3, psnr

Size = tuple[int, int]
Log = Callable[[str], None] | None

ADAPTIVE = ("as", "as_ocv", "as_ccv")
COST_METHODS = ("fixed", "as", "as_ocv", "as_ccv")
REGENERATE = "cvsss bench --out out/bench"


@dataclass(frozen=True)
class BenchConfig:
    """What the bench measures and at which sizes (defaults: ``make bench``).

    Sizes are (width, height) in pixels; frame counts are frames of the
    60 fps synthetic sequence ``scene``.
    """

    scene: str = "flash"
    seed: int = 0
    #: Repetitions of each timed frame (minimum taken; the Pareto sweep too, not the
    #: calibration-only points whose PSNR and spp are deterministic).
    repeats: int = 2
    # ns_per_sample, gather roofline, overhead fraction
    cost_sizes: tuple[Size, ...] = ((640, 360), (1280, 720))
    cost_frames: int = 3
    cost_fixed_spp: int = 16
    # samples → time fit
    fit_size: Size = (640, 360)
    fit_fixed_spp: tuple[int, ...] = (8, 16, 32, 64)
    fit_frames: int = 4
    # coverage and resolution scaling
    coverage_size: Size = (640, 360)
    coverages: tuple[float, ...] = (0.1, 0.5, 1.0)
    scaling_sizes: tuple[Size, ...] = ((320, 180), (640, 360), (1280, 720), (2560, 1440))
    scaling_frames: int = 4
    scaling_method: str = "as_ccv"
    # memory
    rss_sizes: tuple[Size, ...] = ((1280, 720), (2560, 1440))
    rss_methods: tuple[str, ...] = COST_METHODS
    rss_workers: int = 2
    rss_separable: bool = True
    # Pareto front and quality calibration
    pareto_size: Size = (320, 180)
    pareto_frames: int = 24
    warmup: int = 6
    fixed_spp: tuple[int, ...] = (1, 2, 4, 8, 16, 32, 64)
    sigmas: tuple[float, ...] = (1e-2, 1e-3, 1e-4, 1e-5, 1e-6)
    calib_extra_sigmas: tuple[float, ...] = (1e-7,)
    calib_families: tuple[tuple[int, tuple[float, ...]], ...] = (
        (4, (1e-2, 1e-3, 1e-4)),
        (2, (1e-2, 1e-3)),
    )
    check_psnr_db: float = 45.0
    check_spp: float = 16.0
    check_method: str = "as_ccv"
    check_seed: int = 0x5EED
    transfer_size: Size | None = (160, 90)
    sections: tuple[str, ...] = ("cost", "fit", "coverage", "resolution", "rss", "pareto")

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: A seconds-long configuration for the smoke test.
QUICK = BenchConfig(
    cost_sizes=((32, 18),),
    cost_frames=2,
    cost_fixed_spp=4,
    fit_size=(32, 18),
    fit_fixed_spp=(2, 8),
    fit_frames=2,
    coverage_size=(32, 18),
    coverages=(0.5, 1.0),
    scaling_sizes=((32, 18), (64, 36)),
    scaling_frames=2,
    rss_sizes=((32, 18),),
    rss_methods=("as_ocv",),
    rss_workers=1,
    rss_separable=False,
    pareto_size=(32, 18),
    pareto_frames=3,
    warmup=1,
    fixed_spp=(1, 4, 16),
    sigmas=(1e-2, 1e-4),
    calib_extra_sigmas=(),
    calib_families=((4, (1e-2, 1e-3)),),
    check_spp=8.0,
    transfer_size=None,
)


def size_key(size: Size) -> str:
    return f"{size[0]}x{size[1]}"


def _progress(log: Log, start: float, text: str) -> None:
    if log:
        log(f"[{time.perf_counter() - start:7.1f} s] {text}")


# -- running sequences --------------------------------------------------------------
def _frames(kind: str, size: Size, count: int, start: int = 1, **kw) -> list[Frame]:
    return [scene_frame(kind, n, size[0], size[1], **kw) for n in range(start, start + count)]


@dataclass
class Job:
    """One configuration run over a sequence (see :func:`run_jobs`).

    Attributes
    ----------
    label : str
    method : str, a name of core.methods.METHODS
    params : SSSParams
    frame : callable i -> Frame, the i-th frame of the sequence (0-based)
    reference : callable i -> (H, W, 3) reference composite, optional (PSNR)
    first : int, first frame index processed (methods without history skip warm-up)
    record_from : int, first frame index recorded (history warm-up before it)
    separable : core.separable.SeparableParams, kernel of the ``separable`` method
    keep_last : bool, keep the last FrameResult
    repeats : int, times each frame is processed from the same state (a copy of
        the processor for all but the last); timings are the minimum, which
        discards a slow spell of the machine that hit one repetition
    """

    label: str
    method: str
    params: SSSParams
    frame: Callable[[int], Frame]
    reference: Callable[[int], np.ndarray] | None = None
    first: int = 0
    record_from: int = 0
    separable: Any = None
    keep_last: bool = False
    repeats: int = 1
    records: list = dataclasses.field(default_factory=list)
    last: Any = None


#: (wall s, thread CPU s) of every ``process()`` call since the last reset.
CPU_LEDGER: list[tuple[float, float]] = []


def run_jobs(jobs: Sequence[Job], count: int) -> list[Job]:
    """Advance every job frame by frame in lockstep; fill ``job.records``.

    Configurations are interleaved (frame i of every job, in an order rotated
    each frame, before frame i + 1 of any) so that a slow spell of the
    machine — another process, a frequency change — lands on all of them
    alike instead of on whichever ran at that moment: the figures are
    ratios measured side by side. Each record holds ``frame, spp, samples,
    pass_ms, update_ms, total_ms, sss_pixels, distant_share`` and
    ``psnr_db`` (None without a reference) and ``cpu_share``: the CPU time
    this thread got during ``process()`` over its wall time (below ~0.9 the
    machine was busy with other processes and wall times are inflated; the
    run's overall share is reported per section, see :data:`CPU_LEDGER`).
    """
    procs = []
    for job in jobs:
        kw = {} if job.separable is None else {"separable": job.separable}
        procs.append(SequenceProcessor(job.method, job.params, **kw))
    gc.collect()
    n = len(jobs)
    for i in range(count):
        for j in (list(range(i % n, n)) + list(range(i % n))) if n else []:
            job, proc = jobs[j], procs[j]
            if i < job.first:
                continue
            frame = job.frame(i)
            record = i >= job.record_from
            times = []
            for r in range(job.repeats if record else 1):
                run = copy.deepcopy(proc) if r < job.repeats - 1 and record else proc
                w0, c0 = time.perf_counter(), time.thread_time()
                res = run.process(frame)
                wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
                CPU_LEDGER.append((wall, cpu))
                times.append((res.pass_ms, res.update_ms, res.total_ms, cpu / wall))
            if not record:
                continue
            best = min(times, key=lambda t: t[2])
            pass_ms, update_ms, total_ms = (min(t[k] for t in times) for k in range(3))
            job.records.append(
                {
                    "frame": frame.number,
                    "spp": res.spp,
                    "samples": int(res.samples),
                    "pass_ms": pass_ms,
                    "update_ms": update_ms,
                    "total_ms": total_ms,
                    "sss_pixels": int(np.count_nonzero(res.mask)),
                    "distant_share": res.distant_share,
                    "cpu_share": best[3],
                    "psnr_db": None
                    if job.reference is None
                    else psnr(res.composite, job.reference(i), res.mask, job.params.exposure),
                }
            )
            job.last = res if job.keep_last else None
    return list(jobs)


def run_sequence(
    frames: Sequence[Frame],
    method: str,
    params: SSSParams,
    *,
    reference: Callable[[int], np.ndarray] | None = None,
    skip: int = 0,
    keep_last: bool = False,
    separable: Any = None,
) -> tuple[list[dict], Any]:
    """Process ``frames`` in order with one method: ``(records, last FrameResult)``."""
    job = Job(
        method,
        method,
        params,
        frames.__getitem__,
        reference,
        record_from=skip,
        separable=separable,
        keep_last=keep_last,
    )
    run_jobs([job], len(frames))
    return job.records, job.last


def _median(records: Sequence[dict], key: str) -> float:
    return float(np.median([r[key] for r in records])) if records else math.nan


def _steady(records: list[dict]) -> list[dict]:
    """Frames after the first (history present, caches warm) when there are any."""
    return records[1:] if len(records) > 1 else records


def _summary(records: Sequence[dict]) -> dict:
    """Mean spp, pass ms (median-3 filtered, P Sec. 7), total ms and PSNR of records."""
    out = {
        "frames": len(records),
        "spp": float(np.mean([r["spp"] for r in records])),
        "samples": float(np.mean([r["samples"] for r in records])),
        "pass_ms": float(np.mean(median3(np.array([r["pass_ms"] for r in records])))),
        "update_ms": float(np.mean([r["update_ms"] for r in records])),
        "total_ms": float(np.mean(median3(np.array([r["total_ms"] for r in records])))),
    }
    ps = [r["psnr_db"] for r in records if r.get("psnr_db") is not None]
    out["psnr_db"] = float(np.mean(ps)) if ps else math.nan
    out["cpu_share"] = float(np.mean([r.get("cpu_share", math.nan) for r in records]))
    return out


# -- the gather roofline and a cost breakdown --------------------------------------
def _best_of(fn: Callable[[], Any], repeats: int = 3) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def gather_ns_per_sample(
    lighting: np.ndarray, counts: np.ndarray, seed: int = 0, radius: int = 16
) -> float:
    """Cost of ``counts.sum()`` random local gathers from ``lighting`` with ``np.take``.

    Parameters
    ----------
    lighting : (H, W, 3) float32
    counts : (H, W) int, samples per pixel (the sampling step's counts)
    radius : int, offsets are uniform in ``[−radius, radius]²`` pixels

    Returns
    -------
    float, ns per gathered sample (best of 3); nan when no samples.
    """
    h, w = counts.shape
    c = counts.reshape(-1)
    centre = np.repeat(np.flatnonzero(c > 0), c[c > 0])
    n = centre.size
    if n == 0:
        return math.nan
    rng = np.random.default_rng(seed)
    y, x = np.divmod(centre, w)
    qy = np.clip(y + rng.integers(-radius, radius + 1, n), 0, h - 1)
    qx = np.clip(x + rng.integers(-radius, radius + 1, n), 0, w - 1)
    q = qy * w + qx
    del y, x, qy, qx, centre
    light = np.ascontiguousarray(lighting.reshape(-1, 3), dtype=np.float32)
    return _best_of(lambda: np.take(light, q, axis=0)) * 1e9 / n


def cost_breakdown(frame: Frame, params: SSSParams, n: int = 1 << 21) -> dict:
    """Per-sample cost of the sampling step's building blocks, measured in isolation.

    What bounds the sampling step: each block is timed on ``n`` samples of
    the same frame through the public functions the estimator calls
    (best of 3), next to one float64 elementwise multiply (the cost of one
    pass over a per-sample array: NumPy dispatch + memory traffic). A block
    whose API changed is reported as unavailable instead of failing.
    """
    from ..mc.estimator import prepare
    from ..mc.processor import default_profile
    from ..profiles.burley import BurleyProfile
    from ..sampling.sequence import pixel_offsets, r2_points

    out: dict[str, Any] = {"samples": n}
    rng = np.random.default_rng(1)
    profile = default_profile(frame, params)
    geom = prepare(frame.depth, frame.material, frame.camera, profile)
    if geom.size == 0:
        return out
    fast = BurleyProfile(frame.d_table(), truncate=params.truncate, inverse="fast")
    p = rng.integers(0, geom.size, n)
    k = rng.integers(1, 65, n)
    a, b = rng.random(n), rng.random(n)
    blocks: dict[str, Callable[[], Any]] = {
        "stream_multiply_f64": lambda: a * b,
        "log_f64": lambda: np.log(a),
        # Hashed once per active pixel (not per sample) by the estimator.
        "hash_offsets_per_pixel": lambda: pixel_offsets(geom.x[p], geom.y[p], 1, params.seed),
        "r2_points": lambda: r2_points(a, b, k),
        "profile_sample": lambda: profile.sample(
            a, geom.lo[p, 0], geom.hi[p, 0], geom.mat[p], np.zeros(n, np.int64)
        ),
        "profile_sample_fast_inverse": lambda: fast.sample(
            a, geom.lo[p, 0], geom.hi[p, 0], geom.mat[p], np.zeros(n, np.int64)
        ),
        "profile_pdf": lambda: profile.pdf(a * geom.r0[p], geom.mat[p]),
        "gather_take": lambda: np.take(
            np.ascontiguousarray(frame.lighting.reshape(-1, 3)), geom.index[p], axis=0
        ),
        "bincount_3ch": lambda: [np.bincount(p, weights=a, minlength=geom.size) for _ in range(3)],
    }
    for name, fn in blocks.items():
        try:
            out[name] = _best_of(fn) * 1e9 / n
        except Exception as exc:  # the lead may change an API under us: report it
            out[name] = None
            out.setdefault("unavailable", {})[name] = f"{type(exc).__name__}: {exc}"
    return out


# -- sections -------------------------------------------------------------------------
def section_cost(cfg: BenchConfig, log: Log, start: float) -> dict:
    """ns per sample, the gather roofline and the overhead fraction at ``cost_sizes``."""
    out: dict[str, Any] = {"frames": cfg.cost_frames, "fixed_spp": cfg.cost_fixed_spp, "sizes": {}}
    base = SSSParams(seed=cfg.seed, fixed_spp=cfg.cost_fixed_spp)
    for size in cfg.cost_sizes:
        frames = _frames(cfg.scene, size, cfg.cost_frames)
        jobs = run_jobs(
            [
                Job(m, m, base, frames.__getitem__, keep_last=True, repeats=cfg.repeats)
                for m in COST_METHODS
            ],
            len(frames),
        )
        rows = {}
        for job in jobs:
            st = _steady(job.records)
            samples, pass_ms = _median(st, "samples"), _median(st, "pass_ms")
            total_ms, update_ms = _median(st, "total_ms"), _median(st, "update_ms")
            ns = pass_ms * 1e6 / samples if samples else math.nan
            gather = gather_ns_per_sample(frames[-1].lighting, job.last.counts, cfg.seed)
            job.last = None
            rows[job.method] = {
                "samples": samples,
                "spp": _median(st, "spp"),
                "pass_ms": pass_ms,
                "update_ms": update_ms,
                "total_ms": total_ms,
                "ns_per_sample": ns,
                "gather_ns_per_sample": gather,
                "ratio_to_gather": ns / gather,
                "overhead_fraction": update_ms / total_ms,
                "non_sampling_fraction": (total_ms - pass_ms) / total_ms,
            }
            _progress(
                log,
                start,
                f"cost {size_key(size)} {job.method:>6}: {ns:7.1f} ns/sample "
                f"(gather {gather:5.1f}), update {update_ms:6.1f} of "
                f"{total_ms:7.1f} ms",
            )
        out["sizes"][size_key(size)] = rows
        if size == cfg.cost_sizes[-1]:
            out["breakdown"] = cost_breakdown(frames[-1], base)
            out["breakdown"]["size"] = size_key(size)
        del frames, jobs
    return out


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


def section_fit(cfg: BenchConfig, log: Log, start: float) -> dict:
    """Sampling-step time against samples across fixed N and the adaptive methods."""
    frames = _frames(cfg.scene, cfg.fit_size, cfg.fit_frames)
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
        st = _steady(job.records)
        points += [[r["samples"], r["pass_ms"], job.label] for r in st]
        configs[job.label] = {
            "samples": _median(st, "samples"),
            "pass_ms": _median(st, "pass_ms"),
            "overhead_fraction": _median(st, "update_ms") / _median(st, "total_ms"),
        }
    fit = linear_fit(np.array([p[0] for p in points]), np.array([p[1] for p in points]))
    _progress(
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


def section_coverage(cfg: BenchConfig, log: Log, start: float) -> dict:
    """Time against SSS coverage, and against the share of pixels above ε_u."""
    method = cfg.scaling_method
    base = SSSParams(seed=cfg.seed)
    size, count = cfg.coverage_size, cfg.scaling_frames
    seqs = {cov: _frames(cfg.scene, size, count, coverage=cov) for cov in cfg.coverages}
    jobs = run_jobs(
        [
            Job(f"{cov:.0%}", method, base, seqs[cov].__getitem__, repeats=cfg.repeats)
            for cov in cfg.coverages
        ],
        count,
    )
    rows = []
    for cov, job in zip(cfg.coverages, jobs):
        row = _scaling_row(_steady(job.records), size)
        row["coverage"] = cov
        rows.append(row)
        _progress(
            log,
            start,
            f"coverage {cov:4.0%}: {row['total_ms']:7.1f} ms/frame, "
            f"{row['ns_per_sss_pixel']:7.1f} ns per SSS pixel",
        )
    ref = max(rows, key=lambda r: r["coverage"])
    for row in rows:
        row["time_ratio"] = row["total_ms"] / ref["total_ms"]
        row["pass_ratio"] = row["pass_ms"] / ref["pass_ms"]
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
    frames = _frames(cfg.scene, size, count)
    probe = SequenceProcessor(method, base).process(frames[0])
    gmax = probe.gamma.astype(np.float64).max(axis=-1)[probe.mask]
    eps = float(np.median(gmax))
    del probe
    if 0.0 < eps <= 1.0:
        jobs = run_jobs(
            [
                Job("default ε_u", method, base, frames.__getitem__, repeats=cfg.repeats),
                Job(
                    "median ε_u",
                    method,
                    base.replace(eps_u=eps),
                    frames.__getitem__,
                    repeats=cfg.repeats,
                ),
            ],
            count,
        )
        a, b = (_scaling_row(_steady(j.records), size) for j in jobs)
        out["eps_u"] = {
            "scene": f"synthetic {cfg.scene}",
            "eps_u": eps,
            "default_eps_u": base.eps_u,
            "default": a,
            "raised": b,
            "distant_ratio": b["distant_pixels"] / a["distant_pixels"],
            "samples_ratio": b["samples"] / a["samples"],
            "pass_ratio": b["pass_ms"] / a["pass_ms"],
            "time_ratio": b["total_ms"] / a["total_ms"],
        }
        e = out["eps_u"]
        _progress(
            log,
            start,
            f"ε_u {eps:.3f} vs {base.eps_u:g}: distant pixels × "
            f"{e['distant_ratio']:.2f}, samples × {e['samples_ratio']:.2f}, "
            f"sampling time × {e['pass_ratio']:.2f}",
        )
    return out


def _scaling_row(records: list[dict], size: Size) -> dict:
    sss = _median(records, "sss_pixels")
    distant = float(np.median([r["sss_pixels"] * r["distant_share"] for r in records]))
    total, pss = _median(records, "total_ms"), _median(records, "pass_ms")
    samples = _median(records, "samples")
    return {
        "size": size_key(size),
        "pixels": size[0] * size[1],
        "sss_pixels": sss,
        "distant_pixels": distant,
        "samples": samples,
        "spp": _median(records, "spp"),
        "total_ms": total,
        "pass_ms": pss,
        "ns_per_sss_pixel": total * 1e6 / sss if sss else math.nan,
        "ns_per_sample": pss * 1e6 / samples if samples else math.nan,
    }


def section_resolution(cfg: BenchConfig, log: Log, start: float) -> dict:
    """Time per frame over resolution, divided by the pixel count."""
    method = cfg.scaling_method
    base = SSSParams(seed=cfg.seed)

    def source(size: Size) -> Callable[[int], Frame]:
        return lambda i: scene_frame(cfg.scene, i + 1, size[0], size[1])

    jobs = run_jobs(
        [
            Job(size_key(sz), method, base, source(sz), repeats=cfg.repeats)
            for sz in cfg.scaling_sizes
        ],
        cfg.scaling_frames,
    )
    rows = []
    for size, job in zip(cfg.scaling_sizes, jobs):
        row = _scaling_row(_steady(job.records), size)
        row["ns_per_pixel"] = row["total_ms"] * 1e6 / row["pixels"]
        row["pass_ns_per_pixel"] = row["pass_ms"] * 1e6 / row["pixels"]
        rows.append(row)
        _progress(
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


# -- memory ------------------------------------------------------------------------
def _proc_status(field_name: str) -> float | None:
    """A ``/proc/self/status`` field in MiB (Linux), else None."""
    try:
        with open("/proc/self/status", encoding="ascii") as fh:
            for line in fh:
                if line.startswith(field_name + ":"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def _reset_peak() -> bool:
    """Reset VmHWM to the current RSS (Linux ≥ 4.0); False when unsupported."""
    try:
        with open("/proc/self/clear_refs", "w", encoding="ascii") as fh:
            fh.write("5")
        return True
    except OSError:
        return False


def _max_rss_mb() -> float:
    import resource

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024.0


def rss_worker(spec: dict) -> dict:
    """Post-process frames of one configuration and report this process's memory.

    Run in a fresh subprocess per configuration (``python -m cvsss.core.eval.bench
    --rss-worker JSON``) so configurations do not contaminate each other.
    Reports the peak over the whole process (interpreter, inputs, post-process)
    and, where Linux allows resetting the high-water mark, the peak while
    post-processing with the frame already in memory.
    """
    w, h = spec["size"]
    params = SSSParams(history_precision=spec["precision"], seed=spec.get("seed", 0))
    proc = SequenceProcessor(spec["method"], params)
    baseline = _proc_status("VmRSS")
    peak_input = 0.0
    post_peak = None
    input_mb = history_mb = 0.0
    for n in range(1, spec["frames"] + 1):
        frame = scene_frame(spec["scene"], n, w, h)
        input_mb = (
            sum(
                a.nbytes
                for a in (frame.lighting, frame.albedo, frame.combined, frame.depth, frame.material)
            )
            / 2**20
        )
        peak_input = max(peak_input, _proc_status("VmHWM") or 0.0)
        reset = _reset_peak()
        result = proc.process(frame)
        del result, frame
        if reset:
            post_peak = max(post_peak or 0.0, _proc_status("VmHWM") or 0.0)
    if proc.history is not None:
        history_mb = proc.history.nbytes() / 2**20
    peak = max(peak_input, post_peak or 0.0, 0.0)
    if peak == 0.0:
        peak = _max_rss_mb()
    return {
        "peak_rss_mb": peak,
        "post_process_peak_mb": post_peak,
        "baseline_mb": baseline,
        "input_mb": input_mb,
        "history_mb": history_mb,
        "source": ("VmHWM" if baseline is not None else "ru_maxrss"),
    }


def _spawn_rss(spec: dict) -> dict:
    cmd = [sys.executable, "-m", f"{__package__}.bench", "--rss-worker", json.dumps(spec)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=1800, check=False)
    if proc.returncode != 0:
        return {"error": (proc.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def section_rss(cfg: BenchConfig, log: Log, start: float) -> dict:
    """Peak RSS per size, method and history precision, one subprocess each."""
    specs = []
    methods = list(cfg.rss_methods)
    if cfg.rss_separable and "separable" not in methods and separable_kernels()[0]:
        methods.append("separable")  # its default kernel
    for size in cfg.rss_sizes:
        for method in methods:
            precisions = ("float32", "float16") if METHODS[method].adaptive else ("float32",)
            for prec in precisions:
                specs.append(
                    {
                        "size": list(size),
                        "method": method,
                        "precision": prec,
                        "frames": 1,
                        "scene": cfg.scene,
                        "seed": cfg.seed,
                    }
                )
    # One frame suffices: the first frame allocates every buffer (the history,
    # its reprojected copy, sample batches bounded by chunk_samples); the check
    # below measures a second frame at the smallest size.
    check = dict(specs[0], frames=2) if specs else None
    if check is not None and METHODS[check["method"]].adaptive is False:
        ad = next((s for s in specs if METHODS[s["method"]].adaptive), None)
        check = dict(ad, frames=2) if ad else None
    jobs = [*specs, check] if check else specs
    with ThreadPoolExecutor(max_workers=max(1, cfg.rss_workers)) as pool:
        results = list(pool.map(_spawn_rss, jobs))
    table: dict[str, dict] = {}
    rows = []
    for spec, res in zip(specs, results):
        row = {
            "size": size_key(spec["size"]),
            "method": spec["method"],
            "precision": spec["precision"],
            **res,
        }
        rows.append(row)
        table.setdefault(row["size"], {}).setdefault(row["method"], {})[spec["precision"]] = (
            res.get("peak_rss_mb")
        )
        _progress(
            log,
            start,
            f"rss {row['size']} {row['method']:>6} {row['precision']}: "
            f"{res.get('peak_rss_mb', float('nan')):8.1f} MB "
            f"{res.get('error', '')}",
        )
    out = {**table, "rows": rows, "frames": 1}
    if check:
        one = next(r for r, s in zip(rows, specs) if s == dict(check, frames=1))
        out["second_frame_check"] = {
            "size": size_key(check["size"]),
            "method": check["method"],
            "precision": check["precision"],
            "one_frame_mb": one.get("peak_rss_mb"),
            "two_frames_mb": results[-1].get("peak_rss_mb"),
        }
    return out


# -- reference ---------------------------------------------------------------------
def _affine_coefficients(frames: Sequence[Frame], tol: float = 1e-5):
    """``(a, b, s)`` with ``B_t = B_a + s_t (B_b − B_a)`` for every frame, or None.

    Also requires the same geometry, albedo and materials in every frame and
    the same relation for Combined.
    """
    if len(frames) < 3:
        return None
    f0 = frames[0]
    for f in frames[1:]:
        if (
            f.shape != f0.shape
            or f.camera != f0.camera
            or f.materials != f0.materials
            or f.motion is not None
            or not np.array_equal(f.depth, f0.depth)
            or not np.array_equal(f.material, f0.material)
            or not np.array_equal(f.albedo, f0.albedo)
        ):
            return None
    total = np.array([float(f.lighting.sum(dtype=np.float64)) for f in frames])
    a, b = int(np.argmin(total)), int(np.argmax(total))
    base = frames[a].lighting.astype(np.float64)
    dirn = frames[b].lighting.astype(np.float64) - base
    cbase = frames[a].combined.astype(np.float64)
    cdir = frames[b].combined.astype(np.float64) - cbase
    norm = float(np.sum(dirn * dirn))
    if norm == 0.0:
        return None
    scale = max(float(np.abs(frames[b].lighting).max()), 1e-30)
    cscale = max(float(np.abs(frames[b].combined).max()), 1e-30)
    s = []
    for f in frames:
        st = float(np.sum((f.lighting - base) * dirn)) / norm
        if np.abs(f.lighting - (base + st * dirn)).max() > tol * scale:
            return None
        if np.abs(f.combined - (cbase + st * cdir)).max() > tol * cscale:
            return None
        s.append(st)
    return a, b, np.array(s)


def reference_composites(
    frames: Sequence[Frame], params: SSSParams, log: Log = None, start: float = 0.0
) -> tuple[Callable[[int], np.ndarray], dict]:
    """The reference composite of each frame (see module docstring) and how it was made.

    Returns
    -------
    ref : callable i -> (H, W, 3) float32 composite of ``frames[i]``
    info : dict (``mode``: ``"affine"`` or ``"per_frame"``, ``spp``, ``seconds``)
    """
    t0 = time.perf_counter()
    proc = SequenceProcessor("reference", params)
    affine = _affine_coefficients(frames)
    if affine is not None:
        a, b, s = affine
        ra = proc.process(dataclasses.replace(frames[a], number=0)).composite
        rb = proc.process(dataclasses.replace(frames[b], number=0)).composite
        diff = rb - ra

        def ref(i: int) -> np.ndarray:
            return np.maximum(ra + np.float32(s[i]) * diff, 0.0)

        info = {"mode": "affine", "basis_frames": [frames[a].number, frames[b].number]}
    else:
        comps = [proc.process(f).composite for f in frames]
        ref = comps.__getitem__
        info = {"mode": "per_frame"}
    info.update(spp=params.reference_spp, seconds=time.perf_counter() - t0)
    _progress(
        log,
        start,
        f"reference ({info['mode']}, {params.reference_spp} spp) in " f"{info['seconds']:.1f} s",
    )
    return ref, info


# -- separable kernels (issue #6 includes them when the method exists) --------------
def separable_kernels() -> tuple[list[tuple[str, Any]], str]:
    """``[(kernel name, SeparableParams)]`` of every separable kernel, and a note.

    Empty (with the reason) while ``separable`` is not in the method table or
    core/separable.py does not expose its kernels to SequenceProcessor.
    """
    import inspect

    if "separable" not in METHODS:
        return [], "core.methods.METHODS has no 'separable' method yet; separable kernels skipped"
    try:
        from ..separable import kernels as sep
    except ImportError as exc:
        return [], f"core/separable.py is not importable ({exc}); separable kernels skipped"
    kernels = getattr(sep, "KERNELS", None)
    sep_params = getattr(sep, "SeparableParams", None)
    if not kernels or sep_params is None:
        return [], "core/separable.py exposes no KERNELS / SeparableParams; separable skipped"
    if "separable" not in inspect.signature(SequenceProcessor).parameters:
        return [], "SequenceProcessor takes no separable parameters yet; separable skipped"
    runs = [(name, sep_params(kernel=name)) for name in kernels]
    taps = runs[0][1].taps if runs else 0
    return runs, f"{len(runs)} separable kernels ({taps} taps, no jitter)"


# -- the Pareto front and the quality calibration ---------------------------------
def pareto_front(points: Sequence[dict]) -> list[int]:
    """Indices of points no other point beats in both pass time and PSNR."""
    order = sorted(range(len(points)), key=lambda i: (points[i]["pass_ms"], -points[i]["psnr_db"]))
    front, best = [], -math.inf
    for i in order:
        if points[i]["psnr_db"] > best:
            front.append(i)
            best = points[i]["psnr_db"]
    return front


def fixed_time_at(points: Sequence[dict], psnr_db: float) -> tuple[float, bool]:
    """Pass time of ``fixed`` at ``psnr_db``, interpolating log(time) over PSNR.

    Returns (ms, extrapolated). The fixed curve is made monotone (best time
    for at least that PSNR) before interpolating.
    """
    fx = sorted((p for p in points if p["method"] == "fixed"), key=lambda p: p["psnr_db"])
    ps = np.array([p["psnr_db"] for p in fx])
    lt = np.log([p["pass_ms"] for p in fx])
    lt = np.minimum.accumulate(lt[::-1])[::-1]
    if len(ps) < 2:
        return math.nan, True
    if ps[0] <= psnr_db <= ps[-1]:
        return float(np.exp(np.interp(psnr_db, ps, lt))), False
    i = (0, 1) if psnr_db < ps[0] else (-2, -1)
    slope = (lt[i[1]] - lt[i[0]]) / (ps[i[1]] - ps[i[0]])
    return float(np.exp(lt[i[0]] + slope * (psnr_db - ps[i[0]]))), True


def section_pareto(cfg: BenchConfig, log: Log, start: float, passes: Path | None = None) -> dict:
    """Pareto points, the quality calibration and the quality checks."""
    base = SSSParams(seed=cfg.seed)
    if passes is not None:
        from ..io.exr import list_frames, read_frame

        listed = list_frames(passes)[: cfg.warmup + cfg.pareto_frames]
        frames = [read_frame(p, number=n) for n, p in listed]
        scene = f"pass directory {passes}"
        size = (frames[0].shape[1], frames[0].shape[0])
    else:
        size = cfg.pareto_size
        frames = _frames(cfg.scene, size, cfg.warmup + cfg.pareto_frames)
        scene = f"synthetic {cfg.scene}"
    warm = min(cfg.warmup, max(len(frames) - 1, 0))
    ref, ref_info = reference_composites(frames, base, log, start)
    measured = frames[warm:]
    refs = [ref(i) for i in range(len(frames))]  # PSNR of every job compares with these
    jobs: list[Job] = []
    meta: list[dict] = []

    def add(
        method: str,
        params: SSSParams,
        label: str,
        family: str,
        param: str,
        value: Any,
        separable: Any = None,
    ) -> None:
        # Methods without history skip the warm-up frames: they would only cost time.
        first = 0 if METHODS[method].adaptive else warm
        jobs.append(
            Job(
                label,
                method,
                params,
                frames.__getitem__,
                refs.__getitem__,
                first=first,
                record_from=warm,
                separable=separable,
                # The swept points carry the timing figures; the extra calibration
                # points only need PSNR and spp (deterministic), so run them once.
                repeats=cfg.repeats if family == "sweep" else 1,
            )
        )
        meta.append(
            {
                "label": label,
                "method": method,
                "family": family,
                "param": param,
                "value": value,
                "beta_min": params.beta_min if METHODS[method].adaptive else None,
            }
        )

    for n in cfg.fixed_spp:
        add("fixed", base.replace(fixed_spp=n), f"fixed N={n}", "sweep", "fixed_spp", n)
    for method in ADAPTIVE:
        for s0 in cfg.sigmas:
            add(
                method,
                base.replace(target_variance=s0),
                f"{method} σ0²={s0:g}",
                "sweep",
                "target_variance",
                s0,
            )
        for s0 in cfg.calib_extra_sigmas:
            add(
                method,
                base.replace(target_variance=s0),
                f"{method} σ0²={s0:g}",
                "calibration",
                "target_variance",
                s0,
            )
        for beta_min, sig in cfg.calib_families:
            for s0 in sig:
                add(
                    method,
                    base.replace(target_variance=s0, beta_min=beta_min),
                    f"{method} σ0²={s0:g} β_min={beta_min}",
                    "calibration",
                    "target_variance",
                    s0,
                )
    sep_runs, sep_note = separable_kernels()
    for name, sparams in sep_runs:
        try:  # another engineer's kernel failing is reported, not fatal
            SequenceProcessor("separable", base, separable=sparams).process(frames[0])
        except Exception as exc:
            sep_note += f"; separable {name} failed: {type(exc).__name__}: {exc}"
            continue
        add("separable", base, f"separable {name}", "sweep", "kernel", name, separable=sparams)
    _progress(
        log,
        start,
        f"{sep_note}; running {len(jobs)} configurations interleaved over " f"{len(frames)} frames",
    )
    run_jobs(jobs, len(frames))
    points: list[dict] = []
    for job, m in zip(jobs, meta):
        s = _summary(job.records)
        points.append(
            {
                **m,
                **s,
                "per_frame": [[r["samples"], r["pass_ms"], r["psnr_db"]] for r in job.records],
            }
        )
        _progress(
            log,
            start,
            f"pareto {m['label']:<30} {s['spp']:6.2f} spp "
            f"{s['pass_ms']:8.2f} ms {s['psnr_db']:6.2f} dB",
        )
    for i in pareto_front(points):
        points[i]["front"] = True
    for p in points:
        p.setdefault("front", False)

    calibration = _calibration_from(points, cfg, scene, size, len(measured), warm)
    cal = quality.Calibration.from_dict(calibration)
    checks = _quality_checks(cfg, cal, frames, ref, warm, base, log, start)

    default = next(
        (
            p
            for p in points
            if p["method"] == "as_ccv"
            and p["family"] == "sweep"
            and p["value"] == PAPER_DEFAULTS["target_variance"]
        ),
        None,
    )
    equal_psnr = []
    for p in points:
        if p["method"] == "as_ccv" and p["family"] == "sweep":
            t_fixed, extra = fixed_time_at(points, p["psnr_db"])
            equal_psnr.append(
                {
                    "value": p["value"],
                    "psnr_db": p["psnr_db"],
                    "pass_ms": p["pass_ms"],
                    "fixed_ms_at_equal_psnr": t_fixed,
                    "ratio": p["pass_ms"] / t_fixed,
                    "extrapolated": extra,
                }
            )
    return {
        "scene": scene,
        "size": size_key(size),
        "frames": len(measured),
        "warmup": warm,
        "reference": ref_info,
        "points": points,
        "separable": sep_note,
        "front": [p["label"] for p in points if p["front"]],
        "as_ccv_vs_fixed": equal_psnr,
        "as_ccv_default": None if default is None else default["label"],
        "calibration": calibration,
        "quality_checks": checks,
    }


def _calibration_from(points, cfg, scene, size, frames, warm) -> dict:
    curves: dict[str, list[dict]] = {}
    fx = [p for p in points if p["method"] == "fixed"]
    if fx:
        curves["fixed"] = [
            {
                "param": "fixed_spp",
                "values": [p["value"] for p in fx],
                "psnr_db": [p["psnr_db"] for p in fx],
                "spp": [p["spp"] for p in fx],
                "pass_ms": [p["pass_ms"] for p in fx],
                "fixed": {},
            }
        ]
    for method in ADAPTIVE:
        fams: dict[int, list[dict]] = {}
        for p in points:
            if p["method"] == method and p["param"] == "target_variance":
                fams.setdefault(p["beta_min"], []).append(p)
        curves[method] = [
            {
                "param": "target_variance",
                "values": [p["value"] for p in ps],
                "psnr_db": [p["psnr_db"] for p in ps],
                "spp": [p["spp"] for p in ps],
                "pass_ms": [p["pass_ms"] for p in ps],
                "fixed": {"beta_min": bm},
            }
            for bm, ps in sorted(fams.items(), reverse=True)
        ]
    defaults = {
        k: v
        for k, v in SSSParams(seed=cfg.seed).to_dict().items()
        if k not in ("target_variance", "beta_min", "fixed_spp")
    }
    return quality.calibration_dict(
        curves,
        {
            "scene": scene,
            "resolution": size_key(size),
            "frames": frames,
            "warmup_frames": warm,
            "measured": "mean luminance PSNR over SSS pixels against the 1024-spp reference "
            "(display-referred) and mean spp, frames after the warm-up",
            "params": defaults,
        },
    )


def _quality_checks(cfg, cal, frames, ref, warm, base, log, start) -> dict:
    """Ask the fresh calibration for targets, then measure on an independent seed."""
    out = {"method": cfg.check_method, "seed": cfg.check_seed}
    base = base.replace(seed=cfg.check_seed)
    for key, target in (
        ("psnr", quality.QualityTarget("psnr", cfg.check_psnr_db)),
        ("spp", quality.QualityTarget("spp", cfg.check_spp)),
    ):
        choice = quality.choose(target, cfg.check_method, cal)
        params = base.replace(**choice.changes)
        recs, _ = run_sequence(frames, cfg.check_method, params, reference=ref, skip=warm)
        s = _summary(recs)
        got = s["psnr_db"] if key == "psnr" else s["spp"]
        out[key] = {
            "target": target.value,
            "choice": choice.changes,
            "clamped": choice.clamped,
            "predicted_psnr_db": choice.predicted_psnr_db,
            "predicted_spp": choice.predicted_spp,
            "measured_psnr_db": s["psnr_db"],
            "measured_spp": s["spp"],
            "error": got - target.value,
        }
        _progress(
            log,
            start,
            f"quality {target}: {choice.describe()}; measured "
            f"{s['psnr_db']:.2f} dB at {s['spp']:.2f} spp",
        )
    if cfg.transfer_size is not None:
        tf = _frames(cfg.scene, cfg.transfer_size, len(frames))
        tref, _ = reference_composites(tf, base.replace(seed=cfg.seed))
        choice = quality.choose(
            quality.QualityTarget("psnr", cfg.check_psnr_db), cfg.check_method, cal
        )
        recs, _ = run_sequence(
            tf, cfg.check_method, base.replace(**choice.changes), reference=tref, skip=warm
        )
        s = _summary(recs)
        out["transfer"] = {
            "size": size_key(cfg.transfer_size),
            "target": cfg.check_psnr_db,
            "choice": choice.changes,
            "measured_psnr_db": s["psnr_db"],
            "measured_spp": s["spp"],
            "error": s["psnr_db"] - cfg.check_psnr_db,
        }
        _progress(
            log,
            start,
            f"quality {cfg.check_psnr_db:g} dB at {size_key(cfg.transfer_size)}: "
            f"measured {s['psnr_db']:.2f} dB",
        )
    try:
        shipped = quality.load_calibration()
        sc = quality.choose(
            quality.QualityTarget("psnr", cfg.check_psnr_db), cfg.check_method, shipped
        )
        out["shipped_choice"] = {"choice": sc.changes, "predicted_psnr_db": sc.predicted_psnr_db}
    except (FileNotFoundError, ValueError) as exc:
        out["shipped_choice"] = {"error": str(exc)}
    return out


# -- targets, plots, the whole run ---------------------------------------------------
def _target(value: float | None, target: float, op: str, **extra) -> dict:
    ok = value is not None and not (isinstance(value, float) and math.isnan(value))
    met = ok and (value <= target if op == "<=" else value >= target)
    return {"value": value, "target": f"{op} {target:g}", "met": bool(met), **extra}


def evaluate_targets(result: dict) -> dict:
    """The issue's targets as ``{value, target, met}``."""
    t: dict[str, dict] = {}
    cost = result.get("cost")
    if cost:
        ratios = {k: v["as_ccv"]["ratio_to_gather"] for k, v in cost["sizes"].items()}
        t["ns_per_sample_vs_gather"] = _target(
            max(ratios.values()), 4.0, "<=", per_size=ratios, method="as_ccv"
        )
        big = list(cost["sizes"])[-1]
        t["overhead_fraction_as_ocv"] = _target(
            cost["sizes"][big]["as_ocv"]["overhead_fraction"], 0.25, "<=", size=big
        )
    fit = result.get("samples_time_r2")
    if fit:
        t["samples_time_r2"] = _target(fit["value"], 0.95, ">=", size=fit["size"])
    rss = result.get("peak_rss_mb")
    if rss:
        big = max(
            (r for r in rss["rows"] if r.get("peak_rss_mb") is not None),
            key=lambda r: (int(r["size"].split("x")[0]), r["peak_rss_mb"]),
            default=None,
        )
        if big is not None:
            t["peak_rss_mb_largest"] = _target(
                big["peak_rss_mb"],
                4096.0,
                "<=",
                size=big["size"],
                method=big["method"],
                precision=big["precision"],
            )
    par = result.get("pareto")
    if par:
        d = next(
            (e for e in par["as_ccv_vs_fixed"] if e["value"] == PAPER_DEFAULTS["target_variance"]),
            None,
        )
        if d:
            t["as_ccv_time_vs_fixed_at_equal_psnr"] = _target(
                d["ratio"],
                0.5,
                "<=",
                psnr_db=d["psnr_db"],
                extrapolated=d["extrapolated"],
                sigma0_sq=d["value"],
            )
        q = par["quality_checks"].get("psnr")
        if q:
            t["quality_45db_error_db"] = _target(
                abs(q["error"]), 2.0, "<=", measured_psnr_db=q["measured_psnr_db"]
            )
    if "wall_s" in result:
        t["bench_wall_s"] = _target(result["wall_s"], 900.0, "<=", cpus=os.cpu_count())
    return t


def _clean_json(obj: Any) -> Any:
    if isinstance(obj, float):
        return None if not math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {str(k): _clean_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_clean_json(v) for v in obj]
    if isinstance(obj, np.generic):
        return _clean_json(obj.item())
    return obj


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (NaN → null)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    tmp.write_text(
        json.dumps(_clean_json(data), indent=1, ensure_ascii=False) + "\n", encoding="utf-8"
    )
    os.replace(tmp, path)


def _environment() -> dict:
    env = {
        "python": platform.python_version(),
        "numpy": np.__version__,
        "machine": platform.machine(),
        "system": platform.system(),
        "cpus": os.cpu_count(),
        "processor": platform.processor() or None,
        "load_average_1min": os.getloadavg()[0] if hasattr(os, "getloadavg") else None,
    }
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as fh:
            env["cpu_model"] = next(
                (ln.split(":", 1)[1].strip() for ln in fh if ln.startswith("model name")), None
            )
    except OSError:
        pass
    try:
        root = Path(__file__).resolve().parent.parent
        rev = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "--short", "HEAD"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
        dirty = subprocess.run(
            ["git", "-C", str(root), "status", "--porcelain"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
        if rev.returncode == 0:
            env["git"] = rev.stdout.strip() + ("+dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        pass
    return env


def run_bench(
    out: Path,
    config: BenchConfig | None = None,
    *,
    passes: Path | None = None,
    write_calibration: bool = False,
    plots: bool = True,
    log: Log = print,
) -> dict:
    """Run the bench, write ``out/bench.json``, the calibration and the plots.

    Parameters
    ----------
    out : output directory
    config : BenchConfig, default the full ``make bench`` configuration
    passes : pass directory to use for the Pareto sequence instead of the
        synthetic one (timing sections stay synthetic: they need sizes and
        coverages the directory does not have)
    write_calibration : also replace the shipped ``core/data/quality_calibration.json``
    plots : write the PNG figures (needs matplotlib)

    Returns
    -------
    dict, the content of bench.json
    """
    cfg = config or BenchConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    result: dict[str, Any] = {
        "version": 1,
        "command": REGENERATE,
        "config": cfg.to_dict(),
        "environment": _environment(),
        "section_s": {},
        "cpu_share": {},
    }
    sections: list[tuple[str, Callable[[], dict]]] = [
        ("cost", lambda: section_cost(cfg, log, start)),
        ("fit", lambda: section_fit(cfg, log, start)),
        ("coverage", lambda: section_coverage(cfg, log, start)),
        ("resolution", lambda: section_resolution(cfg, log, start)),
        ("rss", lambda: section_rss(cfg, log, start)),
        ("pareto", lambda: section_pareto(cfg, log, start, passes)),
    ]
    keys = {
        "fit": "samples_time_r2",
        "coverage": "coverage_scaling",
        "resolution": "resolution_scaling",
        "rss": "peak_rss_mb",
    }
    for name, fn in sections:
        if name not in cfg.sections:
            continue
        t0 = time.perf_counter()
        CPU_LEDGER.clear()
        result[keys.get(name, name)] = fn()
        result["section_s"][name] = time.perf_counter() - t0
        if CPU_LEDGER:
            wall = sum(w for w, _ in CPU_LEDGER)
            result["cpu_share"][name] = sum(c for _, c in CPU_LEDGER) / wall if wall else None
    if "cost" in result:
        cost = result["cost"]
        result["ns_per_sample"] = {
            "method": "as_ccv",
            **{k: v["as_ccv"]["ns_per_sample"] for k, v in cost["sizes"].items()},
        }
        result["gather_ns_per_sample"] = {
            "method": "as_ccv",
            **{k: v["as_ccv"]["gather_ns_per_sample"] for k, v in cost["sizes"].items()},
        }
        big = list(cost["sizes"])[-1]
        result["overhead_fraction"] = {
            "size": big,
            **{m: v["overhead_fraction"] for m, v in cost["sizes"][big].items()},
        }
    if "pareto" in result:
        cal = result["pareto"]["calibration"]
        write_json(out / "quality_calibration.json", cal)
        if write_calibration:
            write_json(quality.CALIBRATION_PATH, cal)
            quality._load_cached.cache_clear()
    result["wall_s"] = time.perf_counter() - start
    if hasattr(os, "getloadavg"):
        # Other processes on the machine slow some frames; interleaving spreads that over
        # every configuration, but the load is recorded so a noisy run can be recognised.
        result["environment"]["load_average_1min_end"] = os.getloadavg()[0]
    result["targets"] = evaluate_targets(result)
    if plots:
        try:
            result["plots"] = [p.name for p in write_plots(result, out)]
        except ImportError as exc:
            result["plots"] = []
            _progress(log, start, f"no plots: {exc}")
    write_json(out / "bench.json", result)
    if log:
        log(format_summary(result))
        log(f"wrote {out / 'bench.json'} in {result['wall_s']:.0f} s")
    return result


def format_summary(result: dict) -> str:
    """The targets as a small text table."""
    lines = ["target                                  value        target     met"]
    for name, t in result.get("targets", {}).items():
        v = t["value"]
        vs = "n/a" if v is None else f"{v:.4g}"
        lines.append(f"{name:<38} {vs:>10}   {t['target']:>10}   {'yes' if t['met'] else 'NO'}")
    return "\n".join(lines)


# -- plots ----------------------------------------------------------------------------
_COLOURS = {
    "fixed": "tab:gray",
    "as": "tab:green",
    "as_ocv": "tab:blue",
    "as_ccv": "tab:red",
    "separable": "tab:purple",
}


def write_plots(result: dict, out: Path) -> list[Path]:
    """pareto.png, quality.png and scaling.png from a bench result."""
    from ..studies.plotting import pyplot, save

    plt = pyplot()
    written = []
    par = result.get("pareto")
    if par:
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.8))
        pts = par["points"]
        for ax, xkey, xlabel in (
            (axes[0], "pass_ms", "mean sampling-pass time per frame (ms)"),
            (axes[1], "spp", "mean samples per SSS pixel"),
        ):
            for method in dict.fromkeys(p["method"] for p in pts):
                if xkey == "spp" and method == "separable":
                    continue  # taps, not samples
                for fam, marker, fill in (("sweep", "o", True), ("calibration", "s", False)):
                    ps = [p for p in pts if p["method"] == method and p["family"] == fam]
                    if not ps:
                        continue
                    c = _COLOURS.get(method, "k")
                    ax.scatter(
                        [p[xkey] for p in ps],
                        [p["psnr_db"] for p in ps],
                        marker=marker,
                        facecolors=c if fill else "none",
                        edgecolors=c,
                        s=36,
                        label=method if fam == "sweep" else f"{method} (other β_min / σ0²)",
                    )
                    if fam == "sweep" and method != "separable":
                        ps = sorted(ps, key=lambda p: p["value"])
                        ax.plot(
                            [p[xkey] for p in ps],
                            [p["psnr_db"] for p in ps],
                            color=c,
                            lw=0.8,
                            alpha=0.6,
                        )
            if xkey == "pass_ms":
                front = sorted((p for p in pts if p["front"]), key=lambda p: p["pass_ms"])
                ax.step(
                    [p["pass_ms"] for p in front],
                    [p["psnr_db"] for p in front],
                    where="post",
                    color="k",
                    lw=2,
                    alpha=0.5,
                    label="Pareto front",
                )
                for p in front:
                    if p["family"] != "sweep":
                        continue  # calibration-only points: markers without labels
                    ax.annotate(
                        p["label"].replace("σ0²=", ""),
                        (p["pass_ms"], p["psnr_db"]),
                        fontsize=6,
                        xytext=(3, -8),
                        textcoords="offset points",
                    )
            ax.set_xscale("log")
            ax.set_xlabel(xlabel)
            ax.set_ylabel("mean PSNR vs reference (dB)")
            ax.grid(True, which="both", alpha=0.3)
        axes[0].legend(fontsize=7, loc="lower right")
        axes[0].set_title(f"{par['scene']} {par['size']}, {par['frames']} frames")
        axes[1].set_title("same points against mean spp")
        written.append(save(fig, out / "pareto.png"))

        cal = par["calibration"]
        fig, axes = plt.subplots(1, 2, figsize=(12, 4.5))
        for method in ADAPTIVE:
            for fam in cal["methods"].get(method, {}).get("families", []):
                bm = fam["fixed"].get("beta_min")
                style = {8: "-", 4: "--", 2: ":"}.get(bm, "-.")
                kw = {"color": _COLOURS[method], "ls": style, "marker": "o", "ms": 3}
                axes[0].plot(fam["values"], fam["psnr_db"], label=f"{method} β_min={bm}", **kw)
                axes[1].plot(fam["values"], fam["spp"], **kw)
        q = par["quality_checks"]
        for key, ax in (("psnr", axes[0]), ("spp", axes[1])):
            c = q.get(key)
            if c and "target_variance" in c["choice"]:
                y = c["measured_psnr_db"] if key == "psnr" else c["measured_spp"]
                ax.scatter(
                    [c["choice"]["target_variance"]],
                    [y],
                    marker="*",
                    s=160,
                    color="k",
                    zorder=5,
                    label=f"asked {c['target']:g} {'dB' if key == 'psnr' else 'spp'}"
                    f": measured {y:.1f}",
                )
                ax.axhline(c["target"], color="k", lw=0.6, ls="--")
        for ax, ylab in ((axes[0], "mean PSNR (dB)"), (axes[1], "mean spp")):
            ax.set_xscale("log")
            ax.set_xlabel("σ0² (target variance of tracked luminance)")
            ax.set_ylabel(ylab)
            ax.grid(True, which="both", alpha=0.3)
            ax.legend(fontsize=7)
        axes[0].set_title(f"quality knob calibration ({cal['resolution']})")
        written.append(save(fig, out / "quality.png"))

    fig, axes = plt.subplots(2, 3, figsize=(15, 8))
    fit = result.get("samples_time_r2")
    if fit:
        ax = axes[0, 0]
        labels = dict.fromkeys(p[2] for p in fit["points"])
        for lab in labels:
            ps = [p for p in fit["points"] if p[2] == lab]
            ax.scatter([p[0] / 1e6 for p in ps], [p[1] for p in ps], s=14, label=lab)
        xs = np.linspace(0, max(p[0] for p in fit["points"]), 10)
        ax.plot(xs / 1e6, fit["intercept_ms"] + fit["slope_ns_per_sample"] * 1e-6 * xs, "k--", lw=1)
        ax.set(
            xlabel="samples per frame (millions)",
            ylabel="sampling pass (ms)",
            title=f"time vs samples {fit['size']}: R² = {fit['value']:.4f}",
        )
        ax.legend(fontsize=6)
    cost = result.get("cost")
    if cost:
        ax = axes[0, 1]
        sizes = list(cost["sizes"])
        width = 0.8 / (len(sizes) * 2)
        for j, size in enumerate(sizes):
            rows = cost["sizes"][size]
            xs = np.arange(len(rows))
            ax.bar(
                xs + (2 * j) * width,
                [r["ns_per_sample"] for r in rows.values()],
                width,
                label=f"sampling step {size}",
            )
            ax.bar(
                xs + (2 * j + 1) * width,
                [r["gather_ns_per_sample"] for r in rows.values()],
                width,
                label=f"np.take gather {size}",
                hatch="//",
            )
            ax.set_xticks(xs + width * (len(sizes) - 0.5), list(rows))
        ax.set(ylabel="ns per sample", title="cost per sample vs the gather roofline")
        ax.set_yscale("log")
        ax.legend(fontsize=6)
        bd = {
            k: v
            for k, v in cost.get("breakdown", {}).items()
            if isinstance(v, float) and k != "samples"
        }
        if bd:
            ax = axes[0, 2]
            ax.barh(list(bd), list(bd.values()), color="tab:gray")
            ax.set(xlabel="ns per sample", title=f"building blocks ({cost['breakdown']['size']})")
    cov = result.get("coverage_scaling")
    if cov:
        ax = axes[1, 0]
        rows = cov["rows"]
        ax.plot(
            [r["sss_pixels"] / 1e3 for r in rows],
            [r["total_ms"] for r in rows],
            "o-",
            label="frame total",
        )
        ax.plot(
            [r["sss_pixels"] / 1e3 for r in rows],
            [r["pass_ms"] for r in rows],
            "s-",
            label="sampling pass",
        )
        if "eps_u" in cov:
            e = cov["eps_u"]
            ax.plot(
                [e["default"]["distant_pixels"] / 1e3, e["raised"]["distant_pixels"] / 1e3],
                [e["default"]["pass_ms"], e["raised"]["pass_ms"]],
                "k*--",
                ms=10,
                label=f"scene, ε_u {e['default_eps_u']:g} → {e['eps_u']:.2f} "
                "(x = pixels above ε_u)",
            )
        ax.set(
            xlabel="SSS pixels (thousands)",
            ylabel="ms per frame",
            title=f"coverage 10/50/100 % ({cov['size']}, {cov['method']})",
        )
        ax.legend(fontsize=7)
    res = result.get("resolution_scaling")
    if res:
        ax = axes[1, 1]
        rows = res["rows"]
        ax.plot(
            [r["pixels"] / 1e6 for r in rows],
            [r["ns_per_pixel"] for r in rows],
            "o-",
            label="frame total / pixel",
        )
        ax.plot(
            [r["pixels"] / 1e6 for r in rows],
            [r["pass_ns_per_pixel"] for r in rows],
            "s-",
            label="sampling pass / pixel",
        )
        ax.set_xscale("log")
        ax.set(
            xlabel="megapixels",
            ylabel="ns per pixel",
            ylim=(0, None),
            title=f"resolution scaling ({res['method']})",
        )
        ax.legend(fontsize=7)
    rss = result.get("peak_rss_mb")
    if rss:
        ax = axes[1, 2]
        rows = [r for r in rss["rows"] if r.get("peak_rss_mb") is not None]
        labels = [f"{r['method']} {r['precision'][5:]}\n{r['size']}" for r in rows]
        ax.barh(range(len(rows)), [r["peak_rss_mb"] for r in rows], color="tab:blue")
        ax.set_yticks(range(len(rows)), labels, fontsize=6)
        ax.axvline(4096, color="r", ls="--", lw=1, label="4 GB")
        ax.set(xlabel="peak RSS (MB)", title="peak memory per configuration (1 frame)")
        ax.legend(fontsize=7)
    written.append(save(fig, out / "scaling.png"))
    return written


# -- command line -----------------------------------------------------------------
def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    """Arguments of ``cvsss bench`` (also ``python -m cvsss.core.eval.bench``)."""
    parser = parser or argparse.ArgumentParser(
        prog="cvsss bench", description="Speed and the speed/accuracy trade, measured."
    )
    parser.add_argument("--out", type=Path, default=Path("out/bench"), help="output directory")
    parser.add_argument(
        "--passes",
        type=Path,
        default=None,
        help="pass directory for the Pareto sequence (default: synthetic flash)",
    )
    parser.add_argument(
        "--quick",
        action="store_true",
        help="tiny sizes and few frames (seconds; a smoke run, not a measurement)",
    )
    parser.add_argument(
        "--sections",
        default=None,
        help="comma-separated subset of cost,fit,coverage,resolution,rss,pareto",
    )
    parser.add_argument(
        "--write-calibration",
        action="store_true",
        help="also replace the shipped core/data/quality_calibration.json",
    )
    parser.add_argument("--no-plots", action="store_true", help="skip the PNG figures")
    parser.add_argument("--rss-worker", default=None, help=argparse.SUPPRESS)
    return parser


def config_from_args(args: argparse.Namespace) -> BenchConfig:
    cfg = QUICK if args.quick else BenchConfig()
    if args.sections:
        names = tuple(s.strip() for s in args.sections.split(",") if s.strip())
        bad = [s for s in names if s not in BenchConfig().sections]
        if bad or not names:
            raise ValueError(
                f"--sections must be a subset of {','.join(BenchConfig().sections)}, "
                f"got {args.sections!r}"
            )
        cfg = dataclasses.replace(cfg, sections=names)
    return cfg


def main(argv: Iterable[str] | None = None) -> int:
    args = build_parser().parse_args(list(argv) if argv is not None else None)
    if args.rss_worker:
        print(json.dumps(rss_worker(json.loads(args.rss_worker))))
        return 0
    try:
        cfg = config_from_args(args)
    except ValueError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    run_bench(
        args.out,
        cfg,
        passes=args.passes,
        write_calibration=args.write_calibration,
        plots=not args.no_plots,
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Speed and the speed/accuracy trade, measured: the computation behind ``cvsss bench``.

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
    ``np.take``, best of three, timed right after each frame's passes with
    that frame's counts, median over the same frames. Each ratio
    ``ns_per_sample / gather_ns_per_sample`` thus compares two timings taken
    within a second of each other (a roofline taken minutes apart moved the
    ratio with the machine's drift). The size's roofline in ``cost`` is the
    fastest of the configurations' gathers.
``backend_default``, ``by_backend``
    The figures above are measured for every sampling backend that imports
    here (``SSSParams.backend``: NumPy, and the compiled numba kernel), side
    by side in one interleaved run; ``ns_per_sample`` and
    ``gather_ns_per_sample`` are ``{backend: {size: ns}}``. The other sections
    run on ``backend_default``, what ``backend = "auto"`` picks.
``frame_time_ms``
    Whole-frame time (``total_ms``) per backend, size (1280×720, 1920×1080,
    2560×1440) and method (:data:`FRAME_METHODS`: the cost methods, ``as_ccv_t``
    and ``separable``), on the first frame of the sequence (no history
    yet: the adaptive methods take their initial count, an upper bound of a
    steady frame's time; see :func:`section_frames`).
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
    method and history precision. This module lists the configurations
    (:func:`rss_specs`) and tabulates what a ``measure`` callable returns for
    them (:func:`section_rss`); measuring needs one fresh process per
    configuration, which the command line does (``sss_addon.cli.bench``).
``pareto``
    Mean spp, mean pass ms (3rd-order median over frames, P Sec. 7) and mean
    PSNR against the 1024-spp reference on the flashing-light sequence for
    ``fixed`` N ∈ {1…64}, the adaptive methods over σ0² ∈ {1e-2…1e-6} (and
    the extra σ0²/β_min of the quality calibration), and every separable
    kernel (whose "spp" is its reads per pixel, 2·J·taps).

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
the calibration this bench produces (:func:`section_pareto`,
``result["pareto"]["calibration"]``); ``cvsss bench --write-calibration``
replaces it.

Nothing here prints, spawns processes or draws: progress goes to an optional
``log`` callable, and the front-end (``sss_addon.cli.bench``) writes
``bench.json``, the calibration and the plots.
"""

from __future__ import annotations

import dataclasses
import gc
import json
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..frame import Frame
from ..geometry import prepare
from ..io.atomic import write_text
from ..mc import backend as mc_backend
from ..methods import METHODS, MethodOptions, Processor, make_processor
from ..params import KERNELS, PAPER_DEFAULTS, SeparableParams, SSSParams
from ..profiles import burley
from ..profiles.factory import frame_profile
from ..result import FrameResult
from ..sampling.sequence import DIRECTION_BITS, DIRECTIONS, pixel_hashes, r2_fixed
from ..synthetic import scene_frame
from . import quality
from .metrics import median3, psnr

Size = tuple[int, int]
Log = Callable[[str], None] | None
#: Measures the peak memory of each RSS configuration (see :func:`section_rss`).
MeasureRss = Callable[[list[dict]], list[dict]]
#: Measures the tiled post on 1 and 2 Dask workers (the front-end's; core runs no processes).
MeasureWorkers = Callable[["BenchConfig"], dict]

ADAPTIVE = ("as", "as_ocv", "as_ccv")
COST_METHODS = ("fixed", "as", "as_ocv", "as_ccv")
#: Whole-frame rows: the cost methods, the temporal one the README recommends for
#: sequences (its proxy and neighbourhood passes weigh on the frame, not the sampling
#: step) and the separable baseline.
FRAME_METHODS = (*COST_METHODS, "as_ccv_t", "separable")
#: Every section, in the order they run. ``rss`` runs last: its fresh processes take and
#: free gigabytes, and for minutes afterwards the machine (here a VM returning the freed
#: pages) slowed every timing section by spells of tens of milliseconds (the Pareto
#: sweep's pass times by up to 1.6x on a quiet machine).
SECTIONS = ("cost", "frames", "fit", "coverage", "resolution", "pareto", "workers", "rss")
#: Section → its key in the result (default: the section's name).
RESULT_KEYS = {
    "frames": "frame_time_ms",
    "fit": "samples_time_r2",
    "coverage": "coverage_scaling",
    "resolution": "resolution_scaling",
    "rss": "peak_rss_mb",
}


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
    #: Sampling backends compared (those that import here; see core.mc.backend).
    backends: tuple[str, ...] = ("numpy", "numba")
    # whole-frame time per backend and method
    frame_sizes: tuple[Size, ...] = ((1280, 720), (1920, 1080), (2560, 1440))
    frame_methods: tuple[str, ...] = FRAME_METHODS
    frame_frames: int = 1
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
    # the tiled post on Dask workers (issue 16): 2 workers against 1
    workers_size: Size = (1280, 720)
    workers_frames: int = 6
    workers_methods: tuple[str, ...] = ("as_ccv",)
    workers_tile: int = 256
    workers_counts: tuple[int, ...] = (1, 2)
    sections: tuple[str, ...] = SECTIONS

    def __post_init__(self) -> None:
        bad = [s for s in self.sections if s not in SECTIONS]
        if bad or not self.sections:
            raise ValueError(
                f"sections must be a non-empty subset of {', '.join(SECTIONS)}, "
                f"got {self.sections!r}"
            )

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


#: A seconds-long configuration for the smoke test.
QUICK = BenchConfig(
    cost_sizes=((32, 18),),
    cost_frames=2,
    cost_fixed_spp=4,
    frame_sizes=((32, 18), (48, 27)),
    frame_methods=("fixed", "as_ccv", "as_ccv_t", "separable"),
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
    workers_size=(64, 36),
    workers_frames=2,
    workers_tile=24,
)


def size_key(size: Sequence[int]) -> str:
    """``"WxH"`` of a (width, height) size."""
    return f"{size[0]}x{size[1]}"


def _progress(log: Log, start: float | None, text: str) -> None:
    if log:
        log(text if start is None else f"[{time.perf_counter() - start:7.1f} s] {text}")


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
    separable : SeparableParams or None, kernel of the ``separable`` method
    keep_last : bool, keep the last FrameResult
    repeats : int, times each recorded frame is processed from the same state
        (the processor's state is restored between repetitions); timings are the
        minimum, which discards a slow spell of the machine that hit one repetition
    gather : bool, time the gather roofline (:func:`gather_ns_per_sample`, the
        frame's own counts) right after each recorded frame: ``record["gather_ns"]``.
        Pass and roofline then share the machine's state of that moment (a shared
        machine's speed can drift by tens of percent within minutes)
    """

    label: str
    method: str
    params: SSSParams
    frame: Callable[[int], Frame]
    reference: Callable[[int], np.ndarray] | None = None
    first: int = 0
    record_from: int = 0
    separable: SeparableParams | None = None
    keep_last: bool = False
    repeats: int = 1
    gather: bool = False
    records: list = dataclasses.field(default_factory=list)
    last: FrameResult | None = None

    def processor(self) -> Processor:
        """A fresh processor of this job's method."""
        options = None if self.separable is None else MethodOptions(separable=self.separable)
        return make_processor(self.method, self.params, options)


#: (wall s, thread CPU s) of every ``process()`` call since the last reset.
CPU_LEDGER: list[tuple[float, float]] = []


def process_timed(
    proc: Processor, frame: Frame, repeats: int = 1
) -> tuple[FrameResult, list[tuple[float, float, float, float]]]:
    """Process ``frame`` ``repeats`` times from the same state (the last one carries on).

    Returns
    -------
    result : FrameResult of the last repetition
    times : [(pass_ms, update_ms, total_ms, cpu_share)] per repetition; cpu_share
        is the CPU time this thread got during ``process()`` over its wall time
        (also appended to :data:`CPU_LEDGER`)
    """
    state = proc.state() if repeats > 1 else None
    times = []
    for r in range(repeats):
        if r:
            proc.restore(state)
        w0, c0 = time.perf_counter(), time.thread_time()
        res = proc.process(frame)
        wall, cpu = time.perf_counter() - w0, time.thread_time() - c0
        CPU_LEDGER.append((wall, cpu))
        times.append((res.pass_ms, res.update_ms, res.total_ms, cpu / wall if wall > 0 else 1.0))
    return res, times


def _rotation(i: int, n: int) -> list[int]:
    """Job order of frame ``i``: 0…n−1 rotated by i."""
    return [(i + j) % n for j in range(n)]


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
    procs = [job.processor() for job in jobs]
    gc.collect()
    for i in range(count):
        for j in _rotation(i, len(jobs)):
            job, proc = jobs[j], procs[j]
            if i < job.first:
                continue
            frame = job.frame(i)
            record = i >= job.record_from
            res, times = process_timed(proc, frame, job.repeats if record else 1)
            if not record:
                continue
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
                    "cpu_share": min(times, key=lambda t: t[2])[3],
                    "psnr_db": None
                    if job.reference is None
                    else psnr(res.composite, job.reference(i), res.mask, job.params.exposure),
                }
            )
            if job.gather:
                job.records[-1]["gather_ns"] = gather_ns_per_sample(
                    frame.lighting, res.counts, job.params.seed, repeats=3
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
    separable: SeparableParams | None = None,
) -> tuple[list[dict], FrameResult | None]:
    """Process ``frames`` in order with one method: ``(records, last FrameResult)``.

    ``skip`` frames are processed (history warm-up) but not recorded.
    """
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


def summarize(records: Sequence[dict]) -> dict:
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


def gather_indices(counts: np.ndarray, seed: int = 0, radius: int = 16) -> np.ndarray:
    """Flat pixel indices of ``counts.sum()`` random local gathers (the roofline's reads).

    Parameters
    ----------
    counts : (H, W) int, samples per pixel
    seed : int, offset stream
    radius : int, offsets are uniform in ``[−radius, radius]²`` pixels, clipped
        to the image

    Returns
    -------
    (counts.sum(),) int64, pixel ``p`` contributes ``counts[p]`` consecutive reads.
    """
    h, w = counts.shape
    c = counts.reshape(-1)
    pixels = np.flatnonzero(c > 0)
    reps = c[pixels]
    y, x = np.divmod(pixels, w)
    # int32 coordinates, in place: the bench draws these for every timed frame
    # (3.5x faster than int64 arrays per sample, 0.3 s for 20 M samples).
    off = np.random.default_rng(seed).integers(
        -radius, radius + 1, (2, int(reps.sum())), dtype=np.int32
    )
    qy = np.repeat(y.astype(np.int32), reps)
    qy += off[0]
    np.clip(qy, 0, h - 1, out=qy)
    qx = np.repeat(x.astype(np.int32), reps)
    qx += off[1]
    np.clip(qx, 0, w - 1, out=qx)
    q = qy.astype(np.int64)
    q *= w
    q += qx
    return q


def gather_ns_per_sample(
    lighting: np.ndarray, counts: np.ndarray, seed: int = 0, radius: int = 16, repeats: int = 5
) -> float:
    """Cost of ``counts.sum()`` random local gathers from ``lighting`` with ``np.take``.

    Parameters
    ----------
    lighting : (H, W, 3) float32
    counts : (H, W) int, samples per pixel (the sampling step's counts)
    radius : int, offsets are uniform in ``[−radius, radius]²`` pixels

    Returns
    -------
    float, ns per gathered sample (best of ``repeats``); nan when no samples.
    """
    q = gather_indices(counts, seed, radius)
    if q.size == 0:
        return math.nan
    light = np.ascontiguousarray(lighting.reshape(-1, 3), dtype=np.float32)
    return _best_of(lambda: np.take(light, q, axis=0), repeats) * 1e9 / q.size


def cost_breakdown(frame: Frame, params: SSSParams, n: int = 1 << 21) -> dict:
    """Per-sample cost of the sampling step's building blocks, measured in isolation.

    What bounds the NumPy path: each block is timed on ``n`` samples of the
    same frame through the public functions the estimator calls (best of 3),
    next to one float64 elementwise multiply (the cost of one pass over a
    per-sample array: NumPy dispatch + memory traffic), and the formulas the
    tables replace (``exact_inverse_formula``, ``pdf_exp``). A block whose API
    changed is reported as unavailable instead of failing.
    """
    out: dict[str, Any] = {"samples": n}
    rng = np.random.default_rng(1)
    profile = frame_profile(frame, params)
    geom = prepare(frame, profile)
    if geom.size == 0:
        return out
    p = rng.integers(0, geom.size, n)
    k = rng.integers(1, 65, n)
    a, b = rng.random(n), rng.random(n)
    hx, hy = pixel_hashes(geom.x[p], geom.y[p], 1, params.seed)
    t = (rng.random(n) * 0.99 + 0.01).astype(np.float32)
    scale = np.float32(burley.TABLE_SIZE / (params.truncate * 0.01))
    v32 = rng.integers(0, 2**32, n, dtype=np.uint64).astype(np.uint32)
    blocks: dict[str, Callable[[], Any]] = {
        "stream_multiply_f64": lambda: a * b,
        "log_f64": lambda: np.log(a),
        # Hashed once per active pixel (not per sample) by the estimator.
        "hash_offsets_per_pixel": lambda: pixel_hashes(geom.x[p], geom.y[p], 1, params.seed),
        "r2_fixed": lambda: r2_fixed(hx, hy, k),
        "exact_inverse_formula": lambda: burley.radius_from_tail(t, np.float32(0.01)),
        # Tables of the Burley profile (AttributeError, reported, for other profiles).
        "radius_table": lambda: burley.radius_from_table(t, profile._rtab, profile.truncate),
        "pdf_exp": lambda: profile.pdf_channels(a.astype(np.float32), geom.mat[p]),
        "pdf_table_1ch": lambda: burley.pdf_from_table(t, scale, np.float32(100.0), profile._pcols),
        "direction_table": lambda: np.take(
            DIRECTIONS, (v32 >> np.uint32(32 - DIRECTION_BITS)).astype(np.intp), axis=0
        ),
        "gather_take": lambda: np.take(
            np.ascontiguousarray(frame.lighting.reshape(-1, 3)), geom.index[p], axis=0
        ),
        "bincount_3ch": lambda: [np.bincount(p, weights=a, minlength=geom.size) for _ in range(3)],
    }
    for name, fn in blocks.items():
        try:
            out[name] = _best_of(fn) * 1e9 / n
        except Exception as exc:  # a profile's API may change under us: report it
            out[name] = None
            out.setdefault("unavailable", {})[name] = f"{type(exc).__name__}: {exc}"
    return out


# -- sections -------------------------------------------------------------------------
def available_backends(cfg: BenchConfig) -> list[str]:
    """The backends of ``cfg.backends`` that run here (numba only where it imports)."""
    return [b for b in cfg.backends if mc_backend.resolve(b) == b]


def section_cost(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """ns per sample, the gather roofline and the overhead fraction at ``cost_sizes``.

    Every backend of :func:`available_backends` is timed in the same interleaved run;
    ``sizes`` holds the rows of the default backend, ``by_backend`` those of each. A
    row's ``ratio_to_gather`` divides its ns per sample by the gather roofline timed
    right after each of its frames (median over the steady frames of both);
    ``gather_ns_per_sample`` per size is the fastest of those gathers.
    """
    backends = available_backends(cfg)
    default = mc_backend.resolve("auto")
    out: dict[str, Any] = {
        "frames": cfg.cost_frames,
        "fixed_spp": cfg.cost_fixed_spp,
        "backend_default": default,
        "backends": backends,
        "sizes": {},
        "by_backend": {b: {} for b in backends},
    }
    base = SSSParams(seed=cfg.seed, fixed_spp=cfg.cost_fixed_spp)
    for size in cfg.cost_sizes:
        frames = _frames(cfg.scene, size, cfg.cost_frames)
        jobs = run_jobs(
            [
                Job(
                    f"{m}@{b}",
                    m,
                    base.replace(backend=b),
                    frames.__getitem__,
                    repeats=cfg.repeats,
                    gather=True,
                )
                for b in backends
                for m in COST_METHODS
            ],
            len(frames),
        )
        rows = []
        for job in jobs:
            st = _steady(job.records)
            samples, pass_ms = _median(st, "samples"), _median(st, "pass_ms")
            total_ms, update_ms = _median(st, "total_ms"), _median(st, "update_ms")
            ns = pass_ms * 1e6 / samples if samples else math.nan
            # The roofline of the same frames, each timed right after that frame's
            # passes with its counts: the ratio compares the two at one state of the
            # machine. (Dividing by the fastest gather of the whole section, timed
            # minutes apart, showed a slow spell between the two as a worse ratio.)
            gather = _median(st, "gather_ns")
            row = {
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
            out["by_backend"][job.params.backend].setdefault(size_key(size), {})[job.method] = row
            rows.append(row)
            _progress(
                log,
                start,
                f"cost {size_key(size)} {job.params.backend:>5} {job.method:>6}: "
                f"{ns:7.1f} ns/sample (gather {gather:5.2f}: {ns / gather:5.1f}x), update "
                f"{update_ms:6.1f} of {total_ms:7.1f} ms",
            )
        # The size's roofline, a bound: the fastest gather of the section.
        out.setdefault("gather_ns_per_sample", {})[size_key(size)] = min(
            r["gather_ns_per_sample"] for r in rows
        )
        out["sizes"][size_key(size)] = out["by_backend"][default][size_key(size)]
        if size == cfg.cost_sizes[-1]:
            out["breakdown"] = cost_breakdown(frames[-1], base)
            out["breakdown"]["size"] = size_key(size)
        del frames, jobs
    return out


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
        frames = _frames(cfg.scene, size, cfg.frame_frames)
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
            _progress(
                log,
                start,
                f"frame {size_key(size)} {b:>5} {job.method:>6}: {rec['total_ms']:8.1f} ms "
                f"({rec['spp']:.1f} spp, sampling {rec['pass_ms']:.1f} ms)",
            )
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


def section_fit(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
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
    return [_scaling_row(_steady(job.records), run[3]) for job, run in zip(jobs, runs)]


def section_coverage(cfg: BenchConfig, log: Log = None, start: float | None = None) -> dict:
    """Time against SSS coverage, and against the share of pixels above ε_u."""
    method = cfg.scaling_method
    base = SSSParams(seed=cfg.seed)
    size, count = cfg.coverage_size, cfg.scaling_frames
    seqs = {cov: _frames(cfg.scene, size, count, coverage=cov) for cov in cfg.coverages}
    rows = _scaling_rows(
        cfg,
        method,
        [(f"{cov:.0%}", base, seqs[cov].__getitem__, size) for cov in cfg.coverages],
        count,
    )
    for cov, row in zip(cfg.coverages, rows):
        row["coverage"] = cov
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
            "pass_ratio": b["pass_ms"] / a["pass_ms"],
            "time_ratio": b["total_ms"] / a["total_ms"],
        }
        _progress(
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
        row["pass_ns_per_pixel"] = row["pass_ms"] * 1e6 / row["pixels"]
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
def rss_specs(cfg: BenchConfig) -> tuple[list[dict], dict | None]:
    """The memory section's configurations, and a two-frame check of one of them.

    Returns
    -------
    specs : [{"size": [w, h], "method", "precision", "frames": 1, "scene", "seed"}],
        per size, method (plus ``separable`` with its default kernel when
        ``cfg.rss_separable``) and history precision (both for adaptive methods)
    check : the first adaptive spec with ``frames = 2``, or None. One frame
        suffices: the first frame allocates every buffer (the history, its
        reprojected copy, sample batches bounded by chunk_samples); the check
        measures a second frame to show it.
    """
    methods = list(cfg.rss_methods)
    if cfg.rss_separable and "separable" not in methods:
        methods.append("separable")
    specs = [
        {
            "size": list(size),
            "method": method,
            "precision": prec,
            "frames": 1,
            "scene": cfg.scene,
            "seed": cfg.seed,
        }
        for size in cfg.rss_sizes
        for method in methods
        for prec in (("float32", "float16") if METHODS[method].adaptive else ("float32",))
    ]
    adaptive = next((s for s in specs if METHODS[s["method"]].adaptive), None)
    return specs, None if adaptive is None else dict(adaptive, frames=2)


def section_rss(
    cfg: BenchConfig, measure: MeasureRss, log: Log = None, start: float | None = None
) -> dict:
    """Peak RSS per size, method and history precision.

    Parameters
    ----------
    cfg : BenchConfig
    measure : callable [spec] -> [result], the memory of one fresh process per
        spec of :func:`rss_specs` (and the check), in order; a result holds
        ``peak_rss_mb`` (and whatever else the measurement reports) or ``error``
    """
    specs, check = rss_specs(cfg)
    results = measure([*specs, check] if check else specs)
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
def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (
        a is not None and b is not None and np.array_equal(a, b, equal_nan=True)
    )


def _affine_coefficients(frames: Sequence[Frame], tol: float = 1e-5):
    """``(a, b, s)`` with ``B_t = B_a + s_t (B_b − B_a)`` for every frame, or None.

    Also requires the same geometry, albedo, materials and Subsurface Weight in
    every frame and the same relation for Combined.
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
            or not _same(f.sss_weight, f0.sss_weight)
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
    frames: Sequence[Frame], params: SSSParams, log: Log = None, start: float | None = None
) -> tuple[Callable[[int], np.ndarray], dict]:
    """The reference composite of each frame (see module docstring) and how it was made.

    Returns
    -------
    ref : callable i -> (H, W, 3) float32 composite of ``frames[i]``
    info : dict (``mode``: ``"affine"`` or ``"per_frame"``, ``spp``, ``seconds``)
    """
    t0 = time.perf_counter()
    proc = make_processor("reference", params)
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
        f"reference ({info['mode']}, {params.reference_spp} spp) in {info['seconds']:.1f} s",
    )
    return ref, info


def separable_kernels() -> tuple[list[tuple[str, SeparableParams]], str]:
    """``[(kernel name, SeparableParams)]`` of every separable kernel, and a note."""
    runs = [(name, SeparableParams(kernel=name)) for name in KERNELS]
    taps = runs[0][1].taps if runs else 0
    return runs, f"{len(runs)} separable kernels ({taps} taps, no jitter)"


# -- the Pareto front and the quality calibration ---------------------------------
def pareto_front(points: Sequence[dict]) -> list[int]:
    """Indices of points no other point beats in both pass time and PSNR, fastest first.

    >>> pareto_front([{"pass_ms": 1, "psnr_db": 30}, {"pass_ms": 2, "psnr_db": 20},
    ...               {"pass_ms": 3, "psnr_db": 40}])
    [0, 2]
    """
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
    if len(fx) < 2:
        return math.nan, True
    ps = np.array([p["psnr_db"] for p in fx])
    lt = np.log([p["pass_ms"] for p in fx])
    lt = np.minimum.accumulate(lt[::-1])[::-1]
    if ps[0] <= psnr_db <= ps[-1]:
        return float(np.exp(np.interp(psnr_db, ps, lt))), False
    i = (0, 1) if psnr_db < ps[0] else (-2, -1)
    slope = (lt[i[1]] - lt[i[0]]) / (ps[i[1]] - ps[i[0]])
    return float(np.exp(lt[i[0]] + slope * (psnr_db - ps[i[0]]))), True


def section_pareto(
    cfg: BenchConfig, log: Log = None, start: float | None = None, passes: Path | None = None
) -> dict:
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
        separable: SeparableParams | None = None,
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
        # (σ0², β_min or None for the default, family)
        sweeps = [(s0, None, "sweep") for s0 in cfg.sigmas]
        sweeps += [(s0, None, "calibration") for s0 in cfg.calib_extra_sigmas]
        sweeps += [(s0, bm, "calibration") for bm, sig in cfg.calib_families for s0 in sig]
        for s0, beta_min, family in sweeps:
            params = base.replace(target_variance=s0)
            label = f"{method} σ0²={s0:g}"
            if beta_min is not None:
                params = params.replace(beta_min=beta_min)
                label += f" β_min={beta_min}"
            add(method, params, label, family, "target_variance", s0)
    # The same sweep on the other backends: same samples (same spp and PSNR), other times.
    default_backend = mc_backend.resolve("auto")
    others = [b for b in available_backends(cfg) if b != default_backend]
    n_default = len(jobs)
    for b in others:
        for job, m in list(zip(jobs[:n_default], meta[:n_default])):
            if m["family"] == "sweep":
                jobs.append(
                    dataclasses.replace(job, label=f"{job.label} [{b}]", records=[], last=None)
                )
                jobs[-1].params = job.params.replace(backend=b)
                meta.append({**m, "label": jobs[-1].label, "backend": b})
    extra = (jobs[n_default:], meta[n_default:])
    del jobs[n_default:], meta[n_default:]
    sep_runs, sep_note = separable_kernels()
    for name, sparams in sep_runs:
        try:  # a kernel failing on this scene is reported, not fatal
            make_processor("separable", base, MethodOptions(separable=sparams)).process(frames[0])
        except Exception as exc:
            sep_note += f"; separable {name} failed: {type(exc).__name__}: {exc}"
            continue
        add("separable", base, f"separable {name}", "sweep", "kernel", name, separable=sparams)
    _progress(
        log,
        start,
        f"{sep_note}; running {len(jobs) + len(extra[0])} configurations interleaved over "
        f"{len(frames)} frames",
    )
    run_jobs(jobs + extra[0], len(frames))
    by_backend: dict[str, list[dict]] = {b: [] for b in others}
    for job, m in zip(*extra):
        s = summarize(job.records)
        by_backend[m["backend"]].append({**m, **s})
    points: list[dict] = []
    for job, m in zip(jobs, meta):
        s = summarize(job.records)
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
    front = set(pareto_front(points))
    for i, p in enumerate(points):
        p["front"] = i in front
        p["backend"] = default_backend
    # Per backend, the Monte Carlo sweep (separable does not sample) and its own front.
    by_backend = {
        default_backend: [p for p in points if p["family"] == "sweep"],
        **by_backend,
    }
    for pts in by_backend.values():
        mc = [p for p in pts if p["method"] != "separable"]
        fr = set(pareto_front(mc))
        for i, p in enumerate(mc):
            p["front_backend"] = i in fr

    calibration = calibration_from(points, cfg, scene, size, len(measured), warm)
    cal = quality.Calibration.from_dict(calibration)
    checks = quality_checks(cfg, cal, frames, ref, warm, base, log, start)

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
        "backend_default": default_backend,
        "by_backend": {
            b: [
                {k: p[k] for k in ("label", "method", "value", "spp", "pass_ms", "psnr_db")}
                | {"front": p.get("front_backend", False)}
                for p in pts
            ]
            for b, pts in by_backend.items()
        },
        "separable": sep_note,
        "front": [p["label"] for p in points if p["front"]],
        "as_ccv_vs_fixed": equal_psnr,
        "as_ccv_default": None if default is None else default["label"],
        "calibration": calibration,
        "quality_checks": checks,
    }


def calibration_from(
    points: Sequence[dict], cfg: BenchConfig, scene: str, size: Size, frames: int, warm: int
) -> dict:
    """The quality calibration (``quality_calibration.json`` body) from Pareto points.

    ``fixed`` is one family over N; each adaptive method has one σ0² family
    per β_min, largest β_min first.
    """
    curves: dict[str, list[dict]] = {}

    def family(ps: list[dict], param: str, fixed: dict) -> dict:
        return {
            "param": param,
            "values": [p["value"] for p in ps],
            "psnr_db": [p["psnr_db"] for p in ps],
            "spp": [p["spp"] for p in ps],
            "pass_ms": [p["pass_ms"] for p in ps],
            "fixed": fixed,
        }

    fx = [p for p in points if p["method"] == "fixed"]
    if fx:
        curves["fixed"] = [family(fx, "fixed_spp", {})]
    for method in ADAPTIVE:
        fams: dict[int, list[dict]] = {}
        for p in points:
            if p["method"] == method and p["param"] == "target_variance":
                fams.setdefault(p["beta_min"], []).append(p)
        curves[method] = [
            family(ps, "target_variance", {"beta_min": bm})
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


def quality_checks(
    cfg: BenchConfig,
    cal: quality.Calibration,
    frames: Sequence[Frame],
    ref: Callable[[int], np.ndarray],
    warm: int,
    base: SSSParams,
    log: Log = None,
    start: float | None = None,
) -> dict:
    """Ask the fresh calibration for targets, then measure on an independent seed."""
    out: dict[str, Any] = {"method": cfg.check_method, "seed": cfg.check_seed}
    base = base.replace(seed=cfg.check_seed)

    def measure(
        target: quality.QualityTarget, seq, reference
    ) -> tuple[quality.QualityChoice, dict]:
        choice = quality.choose(target, cfg.check_method, cal)
        recs, _ = run_sequence(
            seq, cfg.check_method, base.replace(**choice.changes), reference=reference, skip=warm
        )
        return choice, summarize(recs)

    for key, value in (("psnr", cfg.check_psnr_db), ("spp", cfg.check_spp)):
        target = quality.QualityTarget(key, value)
        choice, s = measure(target, frames, ref)
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
        choice, s = measure(quality.QualityTarget("psnr", cfg.check_psnr_db), tf, tref)
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


# -- the sections together ------------------------------------------------------------
def run_sections(
    cfg: BenchConfig,
    *,
    passes: Path | None = None,
    measure_rss: MeasureRss | None = None,
    log: Log = None,
    start: float | None = None,
    measure_workers: MeasureWorkers | None = None,
) -> dict:
    """Run the sections of ``cfg.sections`` and derive the headline figures.

    Parameters
    ----------
    cfg : BenchConfig
    passes : pass directory for the Pareto sequence instead of the synthetic one
        (the timing sections stay synthetic: they need sizes and coverages the
        directory does not have)
    measure_rss : callable, see :func:`section_rss`; needed for the ``rss`` section
    measure_workers : callable BenchConfig -> dict, the ``workers`` section (the tiled post
        on Dask, run by the front-end: core starts no processes); None: the section
        records that it was skipped
    log : callable str -> None receiving progress lines, or None
    start : time.perf_counter() of the run's start (progress time stamps)

    Returns
    -------
    dict with ``section_s`` (seconds per section), ``cpu_share`` (this thread's
    CPU time over wall time while processing, per section), one entry per
    section (keys of :data:`RESULT_KEYS`), ``backend_default``, and
    ``ns_per_sample``, ``gather_ns_per_sample`` (``{backend: {size: ns}}`` of
    as_ccv, ``cost_method``) and ``overhead_fraction`` when ``cost`` ran.
    """
    if "rss" in cfg.sections and measure_rss is None:
        raise ValueError("the rss section needs measure_rss (one fresh process per configuration)")
    runners: dict[str, Callable[[], dict]] = {
        "cost": lambda: section_cost(cfg, log, start),
        "frames": lambda: section_frames(cfg, log, start),
        "fit": lambda: section_fit(cfg, log, start),
        "coverage": lambda: section_coverage(cfg, log, start),
        "resolution": lambda: section_resolution(cfg, log, start),
        "rss": lambda: section_rss(cfg, measure_rss, log, start),
        "pareto": lambda: section_pareto(cfg, log, start, passes),
        "workers": lambda: (
            measure_workers(cfg)
            if measure_workers is not None
            else {"skipped": "needs a Dask cluster: run by the front-end (cvsss bench)"}
        ),
    }
    result: dict[str, Any] = {"section_s": {}, "cpu_share": {}}
    for name in SECTIONS:
        if name not in cfg.sections:
            continue
        t0 = time.perf_counter()
        CPU_LEDGER.clear()
        result[RESULT_KEYS.get(name, name)] = runners[name]()
        result["section_s"][name] = time.perf_counter() - t0
        if CPU_LEDGER:
            wall = sum(w for w, _ in CPU_LEDGER)
            result["cpu_share"][name] = sum(c for _, c in CPU_LEDGER) / wall if wall else None
    result["backend_default"] = mc_backend.resolve("auto")
    if "cost" in result:
        cost = result["cost"]
        result["cost_method"] = "as_ccv"
        for key in ("ns_per_sample", "gather_ns_per_sample"):
            result[key] = {
                b: {k: v["as_ccv"][key] for k, v in sizes.items()}
                for b, sizes in cost["by_backend"].items()
            }
        big = list(cost["sizes"])[-1]
        result["overhead_fraction"] = {
            "size": big,
            **{m: v["overhead_fraction"] for m, v in cost["sizes"][big].items()},
        }
    return result


# -- targets and JSON -------------------------------------------------------------------
def _target(value: float | None, target: float, op: str, **extra) -> dict:
    ok = value is not None and not (isinstance(value, float) and math.isnan(value))
    met = ok and (value <= target if op == "<=" else value >= target)
    return {"value": value, "target": f"{op} {target:g}", "met": bool(met), **extra}


def evaluate_targets(result: dict) -> dict:
    """The issue's targets as ``{value, target, met}``."""
    t: dict[str, dict] = {}
    cost = result.get("cost")
    if cost:
        # Issue 15: the compiled kernel within 4x of the gather roofline, NumPy within 15x.
        limits = {"numba": 4.0, "numpy": 15.0}
        for b, sizes in cost.get("by_backend", {"": cost["sizes"]}).items():
            ratios = {k: v["as_ccv"]["ratio_to_gather"] for k, v in sizes.items()}
            name = f"ns_per_sample_vs_gather_{b}" if b else "ns_per_sample_vs_gather"
            t[name] = _target(
                max(ratios.values()), limits.get(b, 4.0), "<=", per_size=ratios, method="as_ccv"
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
        cpus = result.get("environment", {}).get("cpus")
        t["bench_wall_s"] = _target(result["wall_s"], 900.0, "<=", cpus=cpus)
    return t


def clean_json(obj: Any) -> Any:
    """``obj`` with NumPy scalars as Python numbers, tuples as lists and non-finite floats as None.

    >>> clean_json({"a": float("nan"), 1: (np.float32(0.5), np.int64(2))})
    {'a': None, '1': [0.5, 2]}
    """
    if isinstance(obj, float):
        return None if not math.isfinite(obj) else obj
    if isinstance(obj, dict):
        return {str(k): clean_json(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [clean_json(v) for v in obj]
    if isinstance(obj, np.generic):
        return clean_json(obj.item())
    return obj


def to_json(data: Any) -> str:
    """The bench's JSON text of ``data`` (:func:`clean_json`, indent 1, UTF-8, final newline)."""
    return json.dumps(clean_json(data), indent=1, ensure_ascii=False) + "\n"


def write_json(path: str | Path, data: Any) -> None:
    """Write :func:`to_json` of ``data`` to ``path`` atomically (folders created)."""
    write_text(path, to_json(data))

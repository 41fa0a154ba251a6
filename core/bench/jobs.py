"""Running the synthetic sequences the sections time, interleaved."""

from __future__ import annotations

import dataclasses
import gc
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from ..eval.metrics import median3, psnr
from ..frame import Frame
from ..method import MethodOptions, Processor
from ..methods import make_processor
from ..params import SeparableParams, SSSParams
from ..result import FrameResult
from ..synthetic import scene_frame
from .config import Size
from .gather import gather_ns_per_sample


# -- running sequences --------------------------------------------------------------
def synthetic_frames(kind: str, size: Size, count: int, start: int = 1, **kw) -> list[Frame]:
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
    times : [(sampling_ms, update_ms, total_ms, cpu_share)] per repetition; cpu_share
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
        times.append(
            (res.sampling_ms, res.update_ms, res.total_ms, cpu / wall if wall > 0 else 1.0)
        )
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
    sampling_ms, update_ms, total_ms, sss_pixels, distant_share`` and
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
            sampling_ms, update_ms, total_ms = (min(t[k] for t in times) for k in range(3))
            job.records.append(
                {
                    "frame": frame.number,
                    "spp": res.spp,
                    "samples": int(res.samples),
                    "sampling_ms": sampling_ms,
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


def median_of(records: Sequence[dict], key: str) -> float:
    return float(np.median([r[key] for r in records])) if records else math.nan


def steady(records: list[dict]) -> list[dict]:
    """Frames after the first (history present, caches warm) when there are any."""
    return records[1:] if len(records) > 1 else records


def summarize(records: Sequence[dict]) -> dict:
    """Mean spp, sampling ms (median-3 filtered, P Sec. 7), total ms and PSNR of records."""
    out = {
        "frames": len(records),
        "spp": float(np.mean([r["spp"] for r in records])),
        "samples": float(np.mean([r["samples"] for r in records])),
        "sampling_ms": float(np.mean(median3(np.array([r["sampling_ms"] for r in records])))),
        "update_ms": float(np.mean([r["update_ms"] for r in records])),
        "total_ms": float(np.mean(median3(np.array([r["total_ms"] for r in records])))),
    }
    ps = [r["psnr_db"] for r in records if r.get("psnr_db") is not None]
    out["psnr_db"] = float(np.mean(ps)) if ps else math.nan
    out["cpu_share"] = float(np.mean([r.get("cpu_share", math.nan) for r in records]))
    return out

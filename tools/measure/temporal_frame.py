"""Where a steady frame of the temporal method goes, step by step, against ``as_ccv``.

Runs the bench's flash sequence (``core.synthetic``: a still scene whose light
flashes) at WxH through each method on one backend, ``--warmup`` frames first, then
``--runs`` more frames interleaved (one frame of every method per round, so a slow
spell of a shared machine hits them alike) and prints, per method, the median and the
min–max of the whole ``process()`` call (wall seconds and process CPU seconds: all
threads', which a busy machine inflates less than wall time), and the median
milliseconds of each step inside it, wall and CPU. The steps are the functions the
processor calls, wrapped with timers for the run; a step's time includes the steps
indented under it, ``rest`` is the call's time outside the named steps. Run from the
repo root:

    .venv/bin/python tools/measure/temporal_frame.py [WxH] [--runs 5] [--warmup 3]
        [--methods as_ccv as_ccv_t] [--backend numba] [--no-keep]

Freed memory is kept for the next frame, as the ``cvsss`` command (and so ``make
bench``) does (:func:`sss_addon.cli.heap.keep_freed_memory`), unless ``--no-keep``.

Frames are 60 fps frames of the sequence: frame ``warmup + r + 1`` is round r's.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import time
from collections import defaultdict
from collections.abc import Iterator

import numpy as np

import cvsss
from cvsss.core import result as result_module
from cvsss.core.backends.compile import compile_all
from cvsss.core.geometry import GeometryCache
from cvsss.core.mc import processor as mc_processor
from cvsss.core.mc import temporal
from cvsss.core.mc.history import History
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.separable import apply as separable_apply
from cvsss.core.synthetic import scene_frame
from cvsss.sss_addon.cli.heap import keep_freed_memory

#: (owner, attribute, label) of every timed step.
STEPS = (
    (mc_processor.MonteCarloProcessor, "process", "frame"),
    (GeometryCache, "get", "geometry"),
    (mc_processor.MonteCarloProcessor, "_aligned_history", "reproject"),
    (mc_processor.MonteCarloProcessor, "_counts", "counts"),
    (mc_processor, "estimate_distant", "sampling"),
    (mc_processor.MonteCarloProcessor, "_proxy", "proxy"),
    (separable_apply, "_two_passes", "passes"),
    (mc_processor, "update", "history step"),
    (mc_processor, "light_scale", "light scale"),
    (temporal, "reuse", "reuse"),
    (History, "read_columns", "read"),
    (History, "write_columns", "write"),
    (temporal, "_step", "step"),
    (temporal, "neighbourhood", "neighbourhood"),
    (mc_processor, "assemble", "assemble"),
    (result_module, "composite", "composite"),
)
STEPS = tuple(s for s in STEPS if hasattr(s[0], s[1]))


class Timers:
    """Inclusive (wall, process CPU) seconds per path of nested step labels, for the
    current frame."""

    def __init__(self) -> None:
        self.stack: list[str] = []
        self.seconds: dict[tuple[str, ...], np.ndarray] = {}

    def wrap(self, fn, label: str):
        @functools.wraps(fn)
        def timed(*args, **kwargs):
            self.stack.append(label)
            path = tuple(self.stack)
            # Listed in the order the steps begin.
            self.seconds.setdefault(path, np.zeros(2))
            t0, c0 = time.perf_counter(), time.process_time()
            try:
                return fn(*args, **kwargs)
            finally:
                self.seconds[path] += (time.perf_counter() - t0, time.process_time() - c0)
                self.stack.pop()

        return timed


@contextlib.contextmanager
def instrumented(timers: Timers) -> Iterator[None]:
    """The steps of :data:`STEPS` wrapped with ``timers`` for the ``with`` block."""
    saved = [(owner, name, owner.__dict__[name]) for owner, name, _ in STEPS]
    try:
        for owner, name, label in STEPS:
            setattr(owner, name, timers.wrap(getattr(owner, name), label))
        yield
    finally:
        for owner, name, original in saved:
            setattr(owner, name, original)


def spread(values) -> str:
    return f"{np.median(values):7.3f} ({min(values):.3f}–{max(values):.3f})"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("size", nargs="?", default="1920x1080")
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--warmup", type=int, default=3)
    ap.add_argument("--methods", nargs="+", default=["as_ccv", "as_ccv_t"])
    ap.add_argument("--backend", default="numba")
    ap.add_argument(
        "--no-keep", action="store_true", help="do not keep freed memory (the cvsss command does)"
    )
    a = ap.parse_args()
    if not a.no_keep:
        keep_freed_memory()
    w, h = (int(v) for v in a.size.split("x"))
    if a.backend != "numpy":
        compile_all()
    params = SSSParams(backend=a.backend)
    procs = {m: make_processor(m, params) for m in a.methods}
    for n in range(1, a.warmup + 1):
        frame = scene_frame("flash", n, w, h)
        for proc in procs.values():
            proc.process(frame)
    wall: dict[str, list] = defaultdict(list)
    cpu: dict[str, list] = defaultdict(list)
    steps: dict[str, dict] = {m: defaultdict(list) for m in a.methods}
    for r in range(a.runs):
        frame = scene_frame("flash", a.warmup + r + 1, w, h)
        for m, proc in procs.items():
            timers = Timers()
            with instrumented(timers):
                t0, c0 = time.perf_counter(), time.process_time()
                proc.process(frame)
                wall[m].append(time.perf_counter() - t0)
                cpu[m].append(time.process_time() - c0)
            for path in [*timers.seconds, *(p for p in steps[m] if p not in timers.seconds)]:
                steps[m][path].append(timers.seconds.get(path, np.zeros(2)))
    print(f"{cvsss.__file__}: {w}x{h}, {a.backend}, {a.runs} interleaved runs after "
          f"{a.warmup} frames")  # fmt: skip
    for m in a.methods:
        print(f"\n{m}: wall s {spread(wall[m])}   cpu s {spread(cpu[m])}   (median (min–max))")
        rows = {path: np.asarray(v) * 1e3 for path, v in steps[m].items()}
        top = [p for p in rows if len(p) == 2]
        print(f"  {'step (median ms)':<22} {'wall':>8} {'cpu':>8}")
        for path in rows:
            if len(path) < 2:
                continue
            wall_ms, cpu_ms = np.median(rows[path], axis=0)
            print(f"  {'  ' * (len(path) - 2) + path[-1]:<22} {wall_ms:8.1f} {cpu_ms:8.1f}")
        rest = rows[("frame",)] - sum(rows[p] for p in top)
        wall_ms, cpu_ms = np.median(rest, axis=0)
        print(f"  {'rest':<22} {wall_ms:8.1f} {cpu_ms:8.1f}")


if __name__ == "__main__":
    main()

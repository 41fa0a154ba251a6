"""The compiled kernel's tasks dealt out over the threads, against one run of consecutive
tasks per thread.

``core.mc.estimator_numba.pixel_sums`` takes its pixels in tasks of
PIXELS_PER_TASK, in tile order, and numba splits its parallel loop into one run
of consecutive iterations per thread. Iteration t runs task
``(t % per)·threads + t // per``, so each thread takes every threads-th task of
the image; passed ``threads = 1`` the kernel runs the tasks in order, each
thread one part of the image (as before the deal). This script times the
sampling step (``estimate_distant``, parallel build) both ways on steady
``as_ccv`` frames of the flash scene (``core.synthetic``): frame 3 at 640×360
and 1280×720 (``shared.steady``) and frame 22 at 320×180 (the bench's Pareto
size and σ0² = 1e-4, after 21 frames of history, where most pixels sit at
β_min and the lit region at β_max). Calls interleaved, minimum of ``--calls``
each; also checks that both give the same bits. Run from the repo root:

    .venv/bin/python docs/checks/task_deal.py [--calls 15]
"""

import argparse
import time

import numba
import numpy as np
from shared import steady

from cvsss.core.backends.numba import sampling as estimator_numba
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.synthetic import scene_frame


def frames():
    """(label, frame, profile, counts image) of each steady frame timed."""
    for size in ((640, 360), (1280, 720)):
        frame, profile, result = steady(size, SSSParams())
        yield f"{size[0]}x{size[1]} frame 3", frame, profile, result.counts
    proc = make_processor("as_ccv", SSSParams(target_variance=1e-4))
    for n in range(1, 23):
        frame = scene_frame("flash", n, 320, 180)
        result = proc.process(frame)
    yield "320x180 frame 22", frame, proc.profiles.get(frame), result.counts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=15)
    a = ap.parse_args()
    params = SSSParams()
    original = estimator_numba.build_for
    ways = {
        "dealt": lambda *args: estimator_numba.pixel_sums(*args),
        "in order": lambda *args: estimator_numba.pixel_sums(*args[:-1], 1),
    }
    print(f"{numba.get_num_threads()} threads; ms per call (min of {a.calls}), ns per sample")
    for label, frame, profile, image in frames():
        geom = geometry_of(frame, profile, surface_distance=True, backend="numba")
        counts = image.reshape(-1)[geom.index].astype(np.int32)
        best = dict.fromkeys(ways, np.inf)
        out = {}
        try:
            for call in range(a.calls):
                order = list(ways) if call % 2 else list(ways)[::-1]
                for way in order:
                    estimator_numba.build_for = lambda n, p=0, fn=ways[way]: fn
                    t0 = time.perf_counter()
                    est = estimate_distant(
                        geom, frame.lighting, frame.depth, profile, counts,
                        frame=frame.number, seed=0, depth_slope=params.depth_slope,
                        backend="numba", disk=True,
                    )  # fmt: skip
                    best[way] = min(best[way], time.perf_counter() - t0)
                    out[way] = (est.distant, est.fallback)
        finally:
            estimator_numba.build_for = original
        same = np.array_equal(out["dealt"][0], out["in order"][0])
        same = same and out["dealt"][1] == out["in order"][1]
        n = int(counts.sum())
        cells = "  ".join(f"{w}: {best[w] * 1e3:6.2f} ms {best[w] * 1e9 / n:5.2f} ns" for w in ways)
        ratio = best["dealt"] / best["in order"]
        print(f"  {label:>17}, {n / geom.size:4.1f} spp: {cells}  dealt/in order {ratio:.3f}"
              f"  same bits: {same}")  # fmt: skip


if __name__ == "__main__":
    main()

"""What the compiled kernel costs per pixel and per sample, from a fit over fixed counts.

Times the kernel call alone (``core.mc.estimator_numba.build_for``, inside
``core.mc.estimator._distant_sums_compiled``) on the bench's flash frame (``core.synthetic``, default sample
kernel ``cycles``) with every SSS pixel at N ∈ {1, 2, 4, 8, 16, 32} samples,
calls interleaved, minimum of ``--calls`` per N, on one thread and on all of
them, and fits ``time = a·pixels + b·samples``. ``a`` is what a pixel costs
besides its samples: the per-task pre-pass (hash, channel maps, disk axes,
tangent plane), the loads of its values and the start of each stage loop for
its samples. It is work, not waiting on reads: batches that take their samples
from consecutive pixels (a pixel's lone sample beside 31 others) cost as much
per pixel (see docs/performance.md, *Backends*). ``b`` is printed next to the
bench's gather roofline (``core.bench.gather_ns_per_sample``, timed in
the same run with the 32-spp counts). Run from the repo root:

    .venv/bin/python docs/checks/kernel_per_pixel.py [WxH] [--calls N]
"""

import argparse

import numba
import numpy as np
from shared import timed_kernel

from cvsss.core.backends.numba import sampling as estimator_numba
from cvsss.core.bench.gather import gather_ns_per_sample
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import _distant_sums_compiled, mirror_slots
from cvsss.core.params import SSSParams
from cvsss.core.profiles.factory import ProfileCache
from cvsss.core.synthetic import scene_frame

COUNTS = (1, 2, 4, 8, 16, 32)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("size", nargs="?", default="640x360")
    ap.add_argument("--calls", type=int, default=9)
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    params = SSSParams()
    frame = scene_frame("flash", 2, w, h)
    profile = ProfileCache(params, None).get(frame)
    geom = geometry_of(frame, profile, surface_distance=True, backend="numba")
    active = np.flatnonzero(geom.gamma_sum > 0)
    threads = numba.get_num_threads()
    try:
        # The parallel build at every count.
        with timed_kernel(estimator_numba.pixel_sums) as timed:
            for n_threads in sorted({1, threads}):
                numba.set_num_threads(n_threads)
                best = {n: np.inf for n in COUNTS}
                for _ in range(a.calls + 1):  # the first round compiles or loads
                    for n in COUNTS:
                        counts = np.full(geom.size, n, np.int64)
                        _distant_sums_compiled(
                            geom, profile, counts, active, frame.lighting, frame.depth,
                            frame=2, seed=0, depth_slope=params.depth_slope, variance=False,
                            disk=True, hidden_light=1.0, contact=params.contact,
                            hidden_mirror=mirror_slots(profile, params.hidden_mirror),
                            chunk_samples=1 << 16, distant=np.zeros((geom.size, 3)),
                            start=False, samples=int(counts[active].sum()),
                        )  # fmt: skip
                        best[n] = min(best[n], timed["s"])
                x = np.array(COUNTS, float) * active.size
                y = np.array([best[n] for n in COUNTS])
                slope, intercept = np.polyfit(x, y, 1)
                rows = "  ".join(f"{n}: {best[n] * 1e3:.1f}" for n in COUNTS)
                print(f"{w}x{h}, {active.size} pixels, {n_threads} thread(s), ms per call: {rows}")
                image = np.zeros(h * w, np.int64)
                image[geom.index[active]] = COUNTS[-1]
                gather = gather_ns_per_sample(frame.lighting, image.reshape(h, w))
                print(
                    f"  fit: {intercept * 1e9 / active.size:.0f} ns per pixel + "
                    f"{slope * 1e9:.1f} ns per sample (wall); gather roofline {gather:.2f} ns: "
                    f"{slope * 1e9 / gather:.1f}x per sample"
                )
    finally:
        numba.set_num_threads(threads)


if __name__ == "__main__":
    main()

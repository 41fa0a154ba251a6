"""The NumPy sampling step against the bench's gather roofline, per distance mode.

``make bench`` holds the NumPy step to ≤ 15× a bare gather (issue 15) in the
default distance mode, ``cycles`` (the surface distance plus Cycles' disk
kernel). This script says how far each mode is from that: on a steady
``as_ccv`` frame of the bench's flash sequence (``core.synthetic``; frame 3,
history from frames 1–2, its sample counts), it times the NumPy
``estimate_distant`` in the ``cycles``, ``surface`` and ``planar`` modes and the
bench's roofline (``core.bench.gather_ns_per_sample``: the same number of
random local gathers with ``np.take``), calls interleaved, so a slow spell of a
shared machine hits all of them. Prints ns per sample (minimum and median of
the calls) and the ratio of each mode's minimum to the gather's. Run from the
repo root:

    .venv/bin/python docs/checks/numpy_modes.py [WxH ...] [--calls N]
"""

import argparse
import time

import numpy as np
from shared import steady

from cvsss.core.bench.gather import gather_ns_per_sample
from cvsss.core.geometry import geometry_of
from cvsss.core.mc import estimator
from cvsss.core.params import SSSParams


def measure(size: tuple[int, int], calls: int) -> None:
    w, h = size
    params = SSSParams(backend="numpy")
    frame, profile, result = steady(size, params)
    surface = geometry_of(frame, profile, surface_distance=True, core_only=True)
    planar = geometry_of(frame, profile, surface_distance=False, core_only=True)
    counts = result.counts.reshape(-1)[surface.index].astype(np.int64)
    total = int(counts.sum())
    modes = {"cycles": (surface, True), "surface": (surface, False), "planar": (planar, False)}

    def run(mode: str) -> None:
        geom, disk = modes[mode]
        estimator.estimate_distant(
            geom,
            frame.lighting,
            frame.depth,
            profile,
            counts,
            frame=frame.number,
            seed=params.seed,
            depth_slope=params.depth_slope,
            backend="numpy",
            contact=params.contact,
            disk=disk,
            hidden_light=params.hidden_light,
            hidden_mirror=params.hidden_mirror,
        )

    times: dict[str, list[float]] = {name: [] for name in (*modes, "gather")}
    for _ in range(calls):
        for mode in modes:
            t0 = time.perf_counter()
            run(mode)
            times[mode].append((time.perf_counter() - t0) * 1e9 / total)
        times["gather"].append(gather_ns_per_sample(frame.lighting, result.counts, repeats=3))
    gather = min(times["gather"])
    print(f"{w}x{h}: {total} samples ({total / surface.size:.1f} per SSS pixel)")
    for name, ns in times.items():
        ratio = f"{min(ns) / gather:5.1f}x the gather" if name != "gather" else ""
        print(f"  {name:>8}: min {min(ns):6.1f}  median {np.median(ns):6.1f} ns/sample  {ratio}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sizes", nargs="*", default=["640x360", "1280x720"])
    ap.add_argument("--calls", type=int, default=7)
    a = ap.parse_args()
    for size in a.sizes:
        measure(tuple(int(v) for v in size.split("x")), a.calls)


if __name__ == "__main__":
    main()

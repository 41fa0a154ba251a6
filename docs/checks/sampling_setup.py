"""The compiled sampling step outside its kernel: a still scene's reused inputs against none.

Processes frames 1–6 of the bench's flash sequence (``core.synthetic``: a still
scene whose light flashes) with ``as_ccv`` and the compiled backend, then calls
``estimate_distant`` on frame 7 with its steady counts, CALLS times in each of
two ways, interleaved: with the reused Geometry's memos cleared before the call
(the kernel builds its texels, keys and pixel order anew, as for a Geometry
seen once) and with them kept (it relights the last call's texels). Prints the
time outside the kernel call, in it, and of the whole step (ms, minimum and
median). Both ways give the same bits (tests/core/test_backend.py). Run from
the repo root:

    .venv/bin/python docs/checks/sampling_setup.py [WxH ...] [--calls N]
"""

import argparse
import time

import numpy as np
from shared import timed_kernel

from cvsss.core.mc import estimator
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.synthetic import scene_frame


def measure(w: int, h: int, calls: int) -> None:
    frames = [scene_frame("flash", n, w, h) for n in range(1, 8)]
    proc = make_processor("as_ccv", SSSParams(backend="numba"))
    for frame in frames[:6]:
        proc.process(frame)
    frame, p = frames[6], proc.params
    profile = proc.profiles.get(frame)
    options = dict(surface_distance=True, core_only=True, margin=0, backend="numba")
    geom = proc._geometry.get(frame, profile, **options)
    counts, _ = proc._counts(geom, proc._aligned_history(frame))
    assert geom.reused, "frame 7 of a still scene reuses the Geometry"
    with timed_kernel() as in_kernel:

        def step() -> tuple[float, float]:
            t0 = time.perf_counter()
            estimator.estimate_distant(
                geom, frame.lighting, frame.depth, profile, counts,
                frame=frame.number, seed=p.seed, depth_slope=p.depth_slope,
                backend="numba", disk=p.distance == "cycles",
                hidden_light=p.hidden_light, contact=p.contact,
                hidden_mirror=p.hidden_mirror,
            )  # fmt: skip
            return time.perf_counter() - t0, in_kernel["s"]

        step()
        times = {"anew": [], "reused": []}
        for _ in range(calls):
            for way in times:
                if way == "anew":
                    geom.memos.clear()
                times[way].append(step())
    print(f"{w}x{h}: {geom.size} SSS pixels, {counts.sum() / geom.size:.1f} spp (ms)")
    for way, t in times.items():
        t = np.array(t) * 1e3
        outside, kernel, whole = t[:, 0] - t[:, 1], t[:, 1], t[:, 0]
        print(
            f"  {way:>6}: outside the kernel min {outside.min():6.2f} median "
            f"{np.median(outside):6.2f} | kernel min {kernel.min():7.2f} | "
            f"step min {whole.min():7.2f} median {np.median(whole):7.2f}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sizes", nargs="*", default=["1280x720", "1920x1080"])
    ap.add_argument("--calls", type=int, default=12)
    a = ap.parse_args()
    for size in a.sizes:
        measure(*(int(v) for v in size.split("x")), a.calls)


if __name__ == "__main__":
    main()

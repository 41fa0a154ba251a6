"""What reusing a still scene's Geometry saves: geometry_of() against a cache hit, and whole frames.

A lighting animation over a still scene renders the same Depth, Material Index
and Object Index passes every frame; :class:`core.geometry.GeometryCache`
then reuses the last frame's Geometry and takes only the direct light and the
Subsurface Weight from the new frame. On the bench's flash frame
(``core.synthetic``), for each size, this prints:

- ``geometry_of()`` with the compiled backend (the processors' options: surface
  distances, core pixels), a cache hit (the next frame of the sequence, whose
  passes equal the cached ones: the comparison plus the lighting part) and a
  miss (one depth value changed: the comparison, ``geometry_of()`` and the copy of
  the passes), minimum and median of ``--calls`` interleaved calls, each after
  the same set-up (a cache holding the previous frame);
- a steady ``as_ccv`` frame (frame 7, history from frames 1–6) through the
  whole ``process()`` call, with the cache and with every frame prepared anew
  (the same processor state restored before each call), interleaved, minimum
  and median, and whether both give the same composite and counts.

With ``--passes DIR ...`` it instead processes the first ``--frames`` pass
EXRs of each folder (``make demo`` renders them with Cycles into
``out/demo/SCENE/passes``) with ``as_ccv`` and prints how many frames reused
the previous frame's Geometry. Run from the repo root:

    .venv/bin/python docs/checks/geometry_reuse.py [WxH ...] [--calls N]
    .venv/bin/python docs/checks/geometry_reuse.py --passes out/demo/*/passes [--frames 8]
"""

import argparse
import dataclasses
import time

import numpy as np

from cvsss.core import geometry
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.synthetic import scene_frame

OPTIONS = {"surface_distance": True, "core_only": True, "margin": 0, "backend": "numba"}


class Fresh(geometry.GeometryCache):
    """Prepares every frame anew (the processors before the cache)."""

    def geometry_of(self, frame, profile, **options):
        return geometry.geometry_of(frame, profile, **options)


def stats(times: list[float]) -> str:
    v = np.array(times) * 1e3
    return f"min {v.min():7.1f}  median {np.median(v):7.1f} ms"


def prepare_calls(w: int, h: int, calls: int) -> None:
    frames = [scene_frame("flash", n, w, h) for n in (3, 4)]
    proc = make_processor("as_ccv", SSSParams(backend="numba"))
    profile = proc.profiles.get(frames[0])
    depth = frames[1].depth.copy()
    depth[h // 2, w // 2] *= 1.01
    moved = dataclasses.replace(frames[1], depth=depth)
    times = {"prepare": [], "hit": [], "miss": []}
    for _ in range(calls):
        # The same set-up before each timed call: a cache holding the previous frame.
        for name, frame in (("prepare", moved), ("hit", frames[1]), ("miss", moved)):
            cache = geometry.GeometryCache()
            cache.get(frames[0], profile, **OPTIONS)
            t = time.perf_counter()
            if name == "prepare":
                geometry.geometry_of(frame, profile, **OPTIONS)
            else:
                cache.get(frame, profile, **OPTIONS)
            times[name].append(time.perf_counter() - t)
            assert cache.hits == (name == "hit")
    for name, v in times.items():
        print(f"  {name:>8}: {stats(v)}")


def frame_calls(w: int, h: int, calls: int) -> None:
    frames = [scene_frame("flash", n, w, h) for n in range(1, 8)]
    procs = {}
    for name in ("cache", "fresh"):
        proc = make_processor("as_ccv", SSSParams(backend="numba"))
        if name == "fresh":
            proc._geometry = Fresh()
        for f in frames[:6]:
            proc.process(f)
        procs[name] = (proc, proc.state())
    times = {name: [] for name in procs}
    out = {}
    for _ in range(calls):
        for name, (proc, state) in procs.items():
            proc.restore(state)
            t = time.perf_counter()
            out[name] = proc.process(frames[6])
            times[name].append(time.perf_counter() - t)
    same = np.array_equal(out["cache"].composite, out["fresh"].composite) and np.array_equal(
        out["cache"].counts, out["fresh"].counts
    )
    for name, v in times.items():
        print(f"  as_ccv frame, {name:>5}: {stats(v)}  ({out[name].spp:.1f} spp)")
    print(f"  same composite and counts: {same}")


def pass_folders(folders: list[str], count: int) -> None:
    from pathlib import Path

    from cvsss.core.io.exr import read_frame

    for folder in folders:
        files = sorted(Path(folder).glob("*.exr"))[:count]
        proc = make_processor("as_ccv", SSSParams(backend="numba"))
        for path in files:
            proc.process(read_frame(path))
        print(f"{folder}: {proc._geometry.hits} of {len(files)} frames reused the geometry")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sizes", nargs="*", default=["1280x720", "1920x1080"])
    ap.add_argument("--calls", type=int, default=8)
    ap.add_argument("--passes", nargs="+", help="pass folders to count reused frames in")
    ap.add_argument("--frames", type=int, default=8)
    a = ap.parse_args()
    if a.passes:
        pass_folders(a.passes, a.frames)
        return
    for size in a.sizes:
        w, h = (int(v) for v in size.split("x"))
        print(f"{w}x{h}:")
        prepare_calls(w, h, a.calls)
        frame_calls(w, h, a.calls)


if __name__ == "__main__":
    main()

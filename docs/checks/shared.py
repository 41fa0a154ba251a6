"""Shared by the check scripts beside it: a steady ``as_ccv`` frame of the bench's flash
scene (and its Geometry and counts as the compiled kernel takes them), and the compiled
kernel's calls timed.

Not a check itself; the scripts import it by name (Python puts a script's own
folder first on ``sys.path``).
"""

import contextlib
import time
from collections.abc import Iterator

import numpy as np

from cvsss.core.backends.numba import sampling as estimator_numba
from cvsss.core.frame import Frame
from cvsss.core.geometry import Geometry, GeometryCache
from cvsss.core.method import MethodOptions
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.result import FrameResult
from cvsss.core.synthetic import scene_frame


def steady(
    size: tuple[int, int],
    params: SSSParams,
    options: MethodOptions | None = None,
    number: int = 3,
) -> tuple[Frame, object, FrameResult]:
    """Frame ``number`` (3) of the flash sequence (``core.synthetic``) at ``size`` (W, H
    pixels) after the frames before it through ``as_ccv``: the frame, its profile and its
    result (whose sample counts are a steady frame's: about 34 spp at frame 3, where the
    bench times its cost rows; from frame 4 on most pixels take β_min = 8)."""
    w, h = size
    frames = [scene_frame("flash", n, w, h) for n in range(1, number + 1)]
    proc = make_processor("as_ccv", params, options or MethodOptions())
    for frame in frames:
        result = proc.process(frame)
    return frames[-1], proc.profiles.get(frames[-1]), result


def steady_processor(size: tuple[int, int], method: str, number: int = 7) -> tuple:
    """A processor of ``method`` on the compiled backend after frames 1…``number`` − 1 of
    the flash sequence (``core.synthetic``) at ``size`` (W, H pixels): ``(processor, its
    state, frame number)``, to time that frame from the same state again and again."""
    w, h = size
    frames = [scene_frame("flash", n, w, h) for n in range(1, number + 1)]
    proc = make_processor(method, SSSParams(backend="numba"))
    for f in frames[:-1]:
        proc.process(f)
    return proc, proc.state(), frames[-1]


def steady_geometry(
    size: tuple[int, int], params: SSSParams, number: int = 3
) -> tuple[Frame, object, Geometry, np.ndarray]:
    """:func:`steady`'s frame, its profile, its Geometry (surface distance, core pixels,
    numba backend) as a still scene's next frame gets it from a ``GeometryCache`` (the
    second call hands it on), and the result's counts per Geometry pixel ((G,) int64)."""
    frame, profile, result = steady(size, params, number=number)
    cache = GeometryCache()
    for _ in range(2):
        geom = cache.get(frame, profile, surface_distance=True, core_only=True, backend="numba")
    counts = result.counts.reshape(-1)[geom.index].astype(np.int64)
    return frame, profile, geom, counts


@contextlib.contextmanager
def timed_kernel(build=None) -> Iterator[dict]:
    """``estimator_numba.build_for`` wrapped for the ``with`` block: each call of the kernel
    it returns puts its seconds in the yielded dict (``"s"``). ``build``: that build
    at every count (e.g. ``pixel_sums``, the parallel one); None: the one it picks."""
    timed: dict = {}
    original = estimator_numba.build_for

    def kernel(samples, pixels=0):
        fn = build or original(samples, pixels)

        def run(*args):
            t0 = time.perf_counter()
            out = fn(*args)
            timed["s"] = time.perf_counter() - t0
            return out

        return run

    estimator_numba.build_for = kernel
    try:
        yield timed
    finally:
        estimator_numba.build_for = original

"""sss_addon.precompile: the numba kernels prepared before the first frame is
processed, on a thread the caller waits for, and said out loud when that takes long.

The compile is stood in for by a timed sleep where the test is about timing and
messages (a cold compile takes most of a minute); the real one (loaded from the
disk cache) runs in :func:`test_real_kernels_are_prepared`.
"""

import re
import time

import numpy as np

from cvsss.core.mc import backend as mc_backend
from cvsss.core.mc import estimator_numba
from cvsss.sss_addon import precompile

ANNOUNCE = "compiling the numba kernels (first use on this machine, about a minute)…"
MC = ("none", "as_ccv")  # a job with one method that samples
REPORT = re.compile(r"compiled the numba kernels in ([\d.]+) s; later runs load them from (.+)$")


def test_numpy_prepares_nothing(no_compile, slow_compile):
    calls = slow_compile(0.0)
    lines = []
    assert precompile.prepared("numpy", MC)
    precompile.prepare("numpy", MC, 100, lines.append)
    assert calls == [] and lines == [] and not no_compile


def test_methods_that_do_not_sample_prepare_nothing(no_compile, slow_compile):
    calls = slow_compile(0.0)
    assert precompile.prepared("numba", ("none", "separable"))
    precompile.prepare("numba", ("none", "separable"), 100, None)
    assert calls == [] and not no_compile


def test_once_per_process_for_the_frame_size(no_compile, slow_compile):
    calls = slow_compile(0.0)
    assert not precompile.prepared("numba", MC)
    precompile.prepare("numba", MC, 1920 * 1080, None)
    assert precompile.prepared("numba", MC) and precompile.prepared("auto", MC)
    precompile.prepare("numba", MC, 64, None)
    assert calls == [(1920 * 1080, "cvsss-compile")]


def test_a_long_compile_is_announced_then_reported(no_compile, slow_compile, monkeypatch):
    monkeypatch.setattr(precompile, "NOTICE", 0.1)
    slow_compile(0.6)
    lines = []
    began = time.perf_counter()
    precompile.prepare("numba", MC, None, lines.append)
    returned = time.perf_counter()
    assert no_compile["ended"] <= returned  # the caller waited for the whole compile
    assert len(lines) == 2 and lines[0] == ANNOUNCE, lines
    match = REPORT.match(lines[1])
    assert match, lines[1]
    assert 0.55 <= float(match[1]) <= returned - began + 0.05
    assert match[2] == str(mc_backend.cache_location())


def test_a_short_one_is_not_announced(no_compile, slow_compile):
    slow_compile(0.05)
    lines = []
    precompile.prepare("numba", MC, None, lines.append)
    assert lines == []


def test_a_failed_compile_is_logged(no_compile, slow_compile):
    slow_compile(0.0, RuntimeError("no LLVM here"))
    lines = []
    precompile.prepare("numba", MC, None, lines.append)
    assert lines == ["compiling the numba kernels failed: RuntimeError: no LLVM here"]
    assert precompile.prepared("numba", MC)  # not again: the frame's own call raises it


def test_real_kernels_are_prepared(no_compile, monkeypatch):
    """The real warm-up (from the disk cache, or compiled when it is cold) on the thread,
    reported (NOTICE 0), then a frame on the compiled kernel in this thread."""
    from cvsss.core.methods import make_processor
    from cvsss.core.params import SSSParams
    from cvsss.core.synthetic import scene_frame

    monkeypatch.setattr(precompile, "NOTICE", 0.0)
    lines = []
    precompile.prepare("numba", MC, 48 * 32, lines.append)
    assert REPORT.match(lines[-1]), lines
    assert estimator_numba.pixel_sums_serial.signatures  # the build 48×32 frames take
    result = make_processor("as_ccv", SSSParams(backend="numba")).process(
        scene_frame("flash", 1, 48, 32)
    )
    assert result.spp > 0 and np.isfinite(result.composite).all()

"""sss_addon.precompile: the numba passes compiled before the first frame is
processed, on a thread the caller waits for, and said out loud when that takes long.

The compile is stood in for by a timed sleep where the test is about timing and
messages (a cold compile takes most of a minute); the real one (loaded from the
disk cache) runs in :func:`test_real_kernels_are_compiled`.
"""

import logging
import re
import time
from pathlib import Path

import numpy as np
import pytest

from cvsss.core.backends import cache as numba_cache
from cvsss.sss_addon import precompile

ANNOUNCE = "compiling the numba passes (first use on this machine, about a minute)…"
MC = ("none", "as_ccv")  # a job with one method that samples
STARTED = "compiling the numba passes in a background process (first use on this machine)"
REPORT = re.compile(r"compiled the numba passes in ([\d.]+) s; later runs load them from (.+)$")


def test_numpy_compiles_nothing(no_compile, slow_compile):
    calls = slow_compile(0.0)
    lines = []
    assert precompile.compiled_ready("numpy", MC)
    precompile.ensure_compiled("numpy", MC, 100, lines.append)
    assert calls == [] and lines == [] and not no_compile


def test_methods_that_do_not_sample_compile_nothing(no_compile, slow_compile):
    calls = slow_compile(0.0)
    assert precompile.compiled_ready("numba", ("none", "separable"))
    precompile.ensure_compiled("numba", ("none", "separable"), 100, None)
    assert calls == [] and not no_compile


def test_once_per_process_for_the_frame_size(no_compile, slow_compile):
    calls = slow_compile(0.0)
    assert not precompile.compiled_ready("numba", MC)
    precompile.ensure_compiled("numba", MC, 1920 * 1080, None)
    assert precompile.compiled_ready("numba", MC) and precompile.compiled_ready("auto", MC)
    precompile.ensure_compiled("numba", MC, 64, None)
    assert calls == [(1920 * 1080, "cvsss-compile")]


def test_a_long_compile_is_announced_then_reported(no_compile, slow_compile, monkeypatch):
    monkeypatch.setattr(precompile, "NOTICE", 0.1)
    slow_compile(0.6)
    lines = []
    began = time.perf_counter()
    precompile.ensure_compiled("numba", MC, None, lines.append)
    returned = time.perf_counter()
    assert no_compile["ended"] <= returned  # the caller waited for the whole compile
    assert len(lines) == 2 and lines[0] == ANNOUNCE, lines
    match = REPORT.match(lines[1])
    assert match, lines[1]
    assert 0.55 <= float(match[1]) <= returned - began + 0.05
    assert match[2] == str(numba_cache.location())


def test_a_short_one_is_not_announced(no_compile, slow_compile):
    slow_compile(0.05)
    lines = []
    precompile.ensure_compiled("numba", MC, None, lines.append)
    assert lines == []


def test_a_failed_compile_is_logged(no_compile, slow_compile):
    slow_compile(0.0, RuntimeError("no LLVM here"))
    lines = []
    precompile.ensure_compiled("numba", MC, None, lines.append)
    assert lines == ["compiling the numba passes failed: RuntimeError: no LLVM here"]
    assert precompile.compiled_ready("numba", MC)  # not again: the frame's own call raises it


def test_real_kernels_are_compiled(no_compile, monkeypatch):
    """The real warm-up (from the disk cache, or compiled when it is cold) on the thread,
    reported (NOTICE 0), then a frame on the compiled kernel in this thread."""
    from cvsss.core.methods import make_processor
    from cvsss.core.params import SSSParams
    from cvsss.core.synthetic import scene_frame

    monkeypatch.setattr(precompile, "NOTICE", 0.0)
    lines = []
    precompile.ensure_compiled("numba", MC, 48 * 32, lines.append)
    assert REPORT.match(lines[-1]), lines
    from cvsss.core.backends.numba import sampling

    assert sampling.pixel_sums_serial.signatures  # the build 48×32 frames take
    result = make_processor("as_ccv", SSSParams(backend="numba")).process(
        scene_frame("flash", 1, 48, 32)
    )
    assert result.spp > 0 and np.isfinite(result.composite).all()


# -- the background compile (a process of its own) ------------------------------------
# The real compile_passes.py runs in tests/blender/test_apply_on_render.py (it compiles
# into an empty cache while Blender renders); here stand-in scripts play the child, so that each
# way it can end is seen in a second.
def _child(tmp_path, monkeypatch, body: str):
    script = tmp_path / "child.py"
    script.write_text("import json, sys, time\n" + body + "\n")
    monkeypatch.setattr(precompile, "CHILD", script)
    monkeypatch.setenv("CVSSS_BACKGROUND_COMPILE", "1")
    monkeypatch.setattr(numba_cache, "is_complete", lambda: False)


def test_background_compile_starts_only_where_there_is_work(no_compile, tmp_path, monkeypatch):
    _child(tmp_path, monkeypatch, 'print(json.dumps({"seconds": 0.0}))')
    assert not precompile.start_background("numpy", MC)
    assert not precompile.start_background("numba", ("none", "separable"))
    monkeypatch.setattr(numba_cache, "is_complete", lambda: True)
    assert not precompile.start_background("numba", MC)
    monkeypatch.setattr(numba_cache, "is_complete", lambda: False)
    monkeypatch.setenv("CVSSS_BACKGROUND_COMPILE", "0")
    assert not precompile.start_background("numba", MC)
    assert not precompile._background
    monkeypatch.setenv("CVSSS_BACKGROUND_COMPILE", "1")
    lines = []
    assert precompile.start_background("auto", MC, lines.append)
    assert lines == [STARTED]
    assert not precompile.start_background("auto", MC)  # once per process
    assert precompile._background["process"].wait(30) == 0


def test_no_background_compile_where_numba_is_not_installed(
    no_compile, tmp_path, monkeypatch, caplog
):
    """The windows-arm64 zip has no numba wheel: nothing to compile, and nothing logged."""
    _child(tmp_path, monkeypatch, 'print(json.dumps({"seconds": 0.0}))')

    def absent(name, package=None):
        return None

    monkeypatch.setattr(precompile.importlib.util, "find_spec", absent)
    assert not precompile.start_background("auto", MC) and not precompile._background

    def refused(name, package=None):  # an import hook, or a broken install
        raise ModuleNotFoundError(f"No module named {name!r}")

    monkeypatch.setattr(precompile.importlib.util, "find_spec", refused)
    with caplog.at_level(logging.INFO, logger="cvsss"):  # start_background's note is INFO
        assert not precompile.start_background("auto", MC) and not precompile._background
    assert caplog.records == []


def test_no_background_compile_once_the_kernels_are_compiled(
    no_compile, slow_compile, tmp_path, monkeypatch
):
    _child(tmp_path, monkeypatch, 'print(json.dumps({"seconds": 0.0}))')
    slow_compile(0.0)
    precompile.ensure_compiled("numba", MC, 64, None)
    assert not precompile.start_background("numba", MC) and not precompile._background


def test_ensure_compiled_waits_for_the_background_compile_then_loads(
    no_compile, tmp_path, monkeypatch
):
    """The first frame's ensure_compiled waits for the child, says so, and only then
    compiles in this process (which loads what the child compiled)."""
    done = tmp_path / "child-done"
    _child(
        tmp_path,
        monkeypatch,
        f'time.sleep(0.6); open({str(done)!r}, "w").close(); print(json.dumps({{"seconds": 41.5}}))',
    )
    monkeypatch.setattr(precompile, "NOTICE", 0.1)
    seen = []
    monkeypatch.setattr(
        precompile, "compile_all", lambda pixels=None: seen.append(done.exists()) or 0.0
    )
    lines = []
    assert precompile.start_background("numba", MC, lines.append)
    precompile.ensure_compiled("numba", MC, 64, lines.append)
    assert seen == [True]  # after the child ended
    assert lines == [
        STARTED,
        "waiting for the numba passes' compile in the background (first use)…",
        "the numba passes were compiled in the background in 41.5 s",
    ]


@pytest.mark.parametrize(
    "body, why",
    [
        (
            'print(json.dumps({"error": "ImportError: no numba here"}))',
            "ImportError: no numba here",
        ),
        ("sys.exit(3)", "it exited with code 3 and no report"),
    ],
)
def test_a_failed_background_compile_is_reported_and_compiled_here(
    no_compile, slow_compile, tmp_path, monkeypatch, body, why
):
    _child(tmp_path, monkeypatch, body)
    calls = slow_compile(0.0)
    lines = []
    assert precompile.start_background("numba", MC)
    precompile.ensure_compiled("numba", MC, 64, lines.append)
    assert lines == [
        f"the background compile of the numba passes failed ({why}); compiling them here"
    ]
    assert calls == [(64, "cvsss-compile")]


def test_stop_background_ends_a_running_compile(no_compile, tmp_path, monkeypatch):
    _child(tmp_path, monkeypatch, "time.sleep(120)")
    assert precompile.start_background("numba", MC)
    process = precompile._background["process"]
    began = time.perf_counter()
    precompile.stop_background()
    assert process.poll() is not None and time.perf_counter() - began < 10
    assert not precompile._background  # a later start may begin again


def test_ensure_compiled_waits_only_for_the_kernels_of_its_frame_size(
    no_compile, tmp_path, monkeypatch
):
    """With the job's frame size the child reports ``ready`` once that size's kernels are
    compiled; the job goes on while it compiles the rest."""
    _child(
        tmp_path,
        monkeypatch,
        'print(json.dumps({"ready": 30.5}), flush=True); time.sleep(60); '
        'print(json.dumps({"seconds": 44.0}))',
    )
    monkeypatch.setattr(precompile, "compile_all", lambda pixels=None: 0.0)
    lines = []
    assert precompile.start_background("numba", MC, None, pixels=640 * 360)
    assert precompile._background["process"].args[-1] == str(640 * 360)
    began = time.perf_counter()
    precompile.ensure_compiled("numba", MC, 640 * 360, lines.append)
    assert time.perf_counter() - began < 30
    assert precompile._background["process"].poll() is None  # still compiling the rest
    assert lines == ["the numba passes were compiled in the background in 30.5 s"]


def test_a_background_compile_that_cannot_start_leaves_the_job_to_compile(
    no_compile, slow_compile, tmp_path, monkeypatch
):
    """No Python to run (say): nothing started, nothing raised, the frame compiles here."""
    _child(tmp_path, monkeypatch, "")
    monkeypatch.setattr(precompile.sys, "executable", str(tmp_path / "no-such-python"))
    calls = slow_compile(0.0)
    assert not precompile.start_background("numba", MC)
    assert not precompile._background
    precompile.ensure_compiled("numba", MC, 64, None)
    assert calls == [(64, "cvsss-compile")]


def test_the_add_on_starts_every_kernel_when_it_loads_in_the_ui_only(
    no_compile, tmp_path, monkeypatch
):
    """``register()``'s step: in Blender's UI the compile of every kernel starts (no frame
    size); headless (``blender -b``, the bpy module) the render job starts its own."""
    from cvsss.sss_addon import registration

    _child(tmp_path, monkeypatch, 'print(json.dumps({"seconds": 0.0}))')
    assert not registration._compile_on_load(background=True)
    assert not precompile._background
    assert registration._compile_on_load(background=False)
    process = precompile._background["process"]
    assert process.args[2:] == [str(Path(registration.__file__).resolve().parents[1]), "cvsss"]
    assert process.wait(30) == 0

"""The first use of the numba backend on a machine: compiling its kernels, said out loud.

The first job that samples on the numba backend compiles the kernels
(``core.backends.compile.compile_all``; ``make bench`` reports ``jit.compile_s``, 47–52 s
on the 2-core bench machine); later processes load them from numba's disk
cache in under a second. Compiled inside the first frame's post-process, that
minute passed without a word: Blender's UI froze, a headless render printed
nothing. Now every job calls :func:`ensure_compiled` before it processes its first
frame (``cvsss render``, the operators and Apply on Render directly; ``cvsss
post`` and ``cvsss demo`` through ``run_folder``'s ``prepare``,
:func:`before_first_frame`): it compiles (or loads) the kernels the frame size
needs and, when that takes longer than :data:`NOTICE` seconds, says what is
happening and then how long it took. In the UI, finishing an Apply on Render
(``sss.finish_render``) shows :data:`COMPILING_STATUS` in the status bar on the tick
before, and the Render Sequence operators say it in their starting status
(:func:`compiled_ready` tells whether a compile is due).

The compile runs on a thread only so that the caller can time it out and
speak; the caller waits for it, doing nothing else. Nothing may run beside it:
compiling while Blender rendered (to hide the minute behind the first frame's
render) crashed the ``bpy`` module with a segmentation fault inside LLVM's
module creation in 3 of 10 runs of ``tests/blender/apply_on_render_check.py`` (Apply on
Render with a warm-up frame, into an empty cache), and numba's ``workqueue``
threading layer aborts the process when two threads launch parallel regions
at once.

A process of its own can compile beside Blender: :func:`start_background`
runs ``compile_passes.py`` on Blender's Python when the cache is not complete
(``core.backends.cache.is_complete``; an extension that ships its compiled passes,
``core.backends.shipped``, has them). The add-on starts it when it registers
in Blender's UI (installed, updated, or Blender opened), at low priority, so
that the minute passes while the user works, and every render job starts it
before Blender renders the first frame, at normal priority (the job waits for
it), with its frame size, whose build the process compiles first.
:func:`ensure_compiled` then waits until the process has what the job needs (or
has failed), and loads it from the cache.
``CVSSS_BACKGROUND_COMPILE=0`` turns it off.
"""

from __future__ import annotations

import importlib.util
import json
import logging
import math
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from ..core.backends import cache as numba_cache
from ..core.backends import select, shipped
from ..core.backends.compile import compile_all
from ..core.methods import METHODS

#: A compile still running after this many seconds is announced; one that took longer is
#: reported with its time.
NOTICE = 2.0
#: The status bar's text for the tick before :func:`ensure_compiled` (UI).
COMPILING_STATUS = "compiling the numba passes (about a minute the first time on this machine)"

_state: dict = {}
#: The script the background compile runs (:func:`start_background`).
CHILD = Path(__file__).with_name("compile_passes.py")

#: The background compile's process (:func:`start_background`), while this process has one.
_background: dict = {}


def compiled_ready(requested: str, methods: Sequence[str]) -> bool:
    """Whether frames of ``methods`` on backend ``requested`` can be processed without
    :func:`ensure_compiled` compiling first: NumPy, no method that samples (``none``,
    ``separable``), the kernels already compiled (or loaded) in this process, or
    shipped with the extension (``core.backends.shipped``: each loads in tens of
    milliseconds when first called, only the ones the job's methods call)."""
    return (
        _nothing_to_compile(requested, methods)
        or shipped.shipped()
        or not select.compiled(requested)
    )


def _nothing_to_compile(requested: str, methods: Sequence[str]) -> bool:
    """NumPy, no method that samples, or the kernels compiled in this process already
    (decided without importing numba)."""
    if requested == "numpy" or "ended" in _state:
        return True
    return not any(METHODS[name].monte_carlo for name in methods)


def ensure_compiled(
    requested: str,
    methods: Sequence[str],
    pixels: int | None,
    log: Callable[[str], None] | None,
) -> None:
    """Compile (or load from the disk cache) the kernels of backend ``requested``.

    ``methods``: the job's method names (nothing to do when none samples);
    ``pixels``: the frames' pixel count (H·W), so that only the sampling kernel's
    build for that size compiles (``core.backends.compile.compile_all``); None: both builds.
    Once per process; NumPy returns at once, without importing numba. With
    ``log``, a compile still running after :data:`NOTICE` seconds is announced and
    then reported with its time; a failure is logged, and the frame then compiles
    on its own and raises the error where it belongs.
    """
    if compiled_ready(requested, methods):
        return
    _wait_for_background(log)
    # numba's threading layer (Blender's TBB inside Blender) starts on this thread, as
    # it did when the first frame compiled the kernels; the thread's kernels join it.
    select.threads()
    began = time.perf_counter()
    thread = threading.Thread(target=_compile, args=(pixels,), name="cvsss-compile")
    _state.update(began=began, error=None)
    thread.start()
    thread.join(NOTICE)
    if thread.is_alive() and log is not None:
        log("compiling the numba passes (first use on this machine, about a minute)…")
    thread.join()
    error, seconds = _state["error"], _state["ended"] - began
    if log is None:
        return
    if error is not None:
        log(f"compiling the numba passes failed: {type(error).__name__}: {error}")
    elif seconds > NOTICE:
        log(
            f"compiled the numba passes in {seconds:.1f} s; later runs load them from "
            f"{numba_cache.location()}"
        )


def start_background(
    requested: str,
    methods: Sequence[str],
    log: Callable[[str], None] | None = None,
    pixels: int | None = None,
) -> bool:
    """Start compiling the kernels into the disk cache in a process of their own
    (``compile_passes.py``; at low priority without ``pixels``); whether one started.

    ``pixels``: the job's frame size (H·W), whose kernels the process compiles
    first (:func:`ensure_compiled` waits for those only); None: all, in their order.
    Nothing starts for NumPy or methods that do not sample, when the kernels are
    compiled in this process, when numba is not installed or the cache is complete
    already (``core.backends.cache.is_complete``; numba is not imported here), when
    this process started one before, or with ``CVSSS_BACKGROUND_COMPILE=0``. ``log``
    is told that it started. Safe beside Blender's render: no LLVM in this process.
    Never raises: where it cannot start, the first frame compiles as before.
    """
    try:
        return _start(requested, methods, log, pixels)
    except Exception as exc:  # an optimisation: it must never stop a render
        logging.getLogger("cvsss").info("cvsss: no background compile: %s", exc)
        return False


def _start(requested, methods, log, pixels) -> bool:
    if os.environ.get("CVSSS_BACKGROUND_COMPILE", "1") == "0" or _background:
        return False
    if _nothing_to_compile(requested, methods):
        return False
    # Without importing numba (Blender's start-up): installed, and not cached yet.
    # numba_cache.is_complete() has pointed NUMBA_CACHE_DIR, which the child inherits, at a
    # writable folder where numba's default one is read-only.
    if not _installed("numba") or numba_cache.is_complete():
        return False
    package = __name__.rsplit(".", 2)[0]  # e.g. bl_ext.user_default.cvsss
    root = Path(__file__).resolve().parents[1]
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in sys.path if p and os.path.isdir(p))
    flags = 0
    if sys.platform == "win32":  # no console window; below the UI's priority when idle
        flags = subprocess.CREATE_NO_WINDOW
        if pixels is None:
            flags |= subprocess.BELOW_NORMAL_PRIORITY_CLASS
    size = [] if pixels is None else [str(int(pixels))]
    process = subprocess.Popen(
        [sys.executable, str(CHILD), str(root), package, *size],
        env=env,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        creationflags=flags,
    )
    ready, report = threading.Event(), {}
    _background.update(process=process, ready=ready, report=report)
    threading.Thread(
        target=_read_reports,
        args=(process, ready, report),
        name="cvsss-compile-reports",
        daemon=True,
    ).start()
    if log is not None:
        log("compiling the numba passes in a background process (first use on this machine)")
    return True


def _installed(name: str) -> bool:
    """Whether module ``name`` can be found, without importing it (False where its
    platform has no wheel, as Windows on ARM has none of numba's)."""
    try:
        return importlib.util.find_spec(name) is not None
    except (ImportError, ValueError):  # a broken install, or an import hook refusing it
        return False


def _read_reports(process: subprocess.Popen, ready: threading.Event, report: dict) -> None:
    """The child's first report (``ready``, ``seconds`` or ``error``) into ``report``, then
    the rest of its output read and dropped, so that it never blocks on the pipe."""
    for raw in process.stdout:
        try:
            line = json.loads(raw)
        except ValueError:
            continue
        if not ready.is_set() and isinstance(line, dict):
            report.update(line)
            ready.set()
    code = process.wait()
    if not ready.is_set():
        report["error"] = f"it exited with code {code} and no report"
        ready.set()


def stop_background() -> None:
    """End a background compile that is still running (the add-on is being disabled)."""
    process = _background.get("process")
    if process is not None and process.poll() is None:
        process.terminate()
        process.wait()
        # The next start may begin again (numba replaces cache files whole).
        _background.clear()


def _wait_for_background(log: Callable[[str], None] | None) -> None:
    """Wait until the background compile, if one runs, has what the job needs (or ended),
    and report how that went. Once per process: :func:`ensure_compiled` calls it only while
    the kernels are not compiled, and compiles (or loads) them right after."""
    ready = _background.get("ready")
    if ready is None:
        return
    if not ready.wait(NOTICE) and log is not None:
        log("waiting for the numba passes' compile in the background (first use)…")
    ready.wait()
    report = _background["report"]
    if log is None:
        return
    if "error" in report:
        log(
            f"the background compile of the numba passes failed ({report['error']}); "
            "compiling them here"
        )
    else:
        seconds = report.get("ready", report.get("seconds", 0.0))
        if seconds > NOTICE:
            log(f"the numba passes were compiled in the background in {seconds:.1f} s")


def _compile(pixels: int | None) -> None:
    try:
        compile_all(pixels)
    except Exception as exc:  # the frame's own call raises it where it belongs
        _state["error"] = exc
    _state["ended"] = time.perf_counter()


def before_first_frame(
    requested: str, methods: Sequence[str], log: Callable[[str], None] | None
) -> Callable:
    """``core.run.run_folder``'s ``prepare`` (``cvsss post``, ``cvsss demo``):
    :func:`ensure_compiled` for the first frame's size, called with the first frame to be
    processed."""

    def kernels(frame) -> None:
        ensure_compiled(requested, methods, math.prod(frame.shape), log)

    return kernels

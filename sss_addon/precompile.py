"""The first use of the numba backend on a machine: compiling its kernels, said out loud.

The first job that samples on the numba backend compiles the kernels
(``core.mc.backend.warm_up``; ``make bench`` reports ``jit.compile_s``, 47–52 s
on the 2-core bench machine); later processes load them from numba's disk
cache in under a second. Compiled inside the first frame's post-process, that
minute passed without a word: Blender's UI froze, a headless render printed
nothing. Now every job calls :func:`prepare` before it processes its first
frame (``cvsss render``, the operators and Apply on Render directly; ``cvsss
post`` and ``cvsss demo`` through ``run_folder``'s ``prepare``,
:func:`before_first_frame`): it compiles (or loads) the kernels the frame size
needs and, when that takes longer than :data:`NOTICE` seconds, says what is
happening and then how long it took. In the UI, finishing an Apply on Render
(``sss.finish_render``) shows :data:`PREPARING` in the status bar on the tick
before, and the Render Sequence operators say it in their starting status
(:func:`prepared` tells whether a compile is due).

The compile runs on a thread only so that the caller can time it out and
speak; the caller waits for it, doing nothing else. Nothing may run beside it:
compiling while Blender rendered (to hide the minute behind the first frame's
render) crashed the ``bpy`` module with a segmentation fault inside LLVM's
module creation in 3 of 10 runs of ``tests/blender/native_check.py`` (Apply on
Render with a warm-up frame, into an empty cache), and numba's ``workqueue``
threading layer aborts the process when two threads launch parallel regions
at once.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable, Sequence

from ..core.mc import backend as mc_backend
from ..core.methods import METHODS

#: A compile still running after this many seconds is announced; one that took longer is
#: reported with its time.
NOTICE = 2.0
#: The status bar's text for the tick before :func:`prepare` (UI).
PREPARING = "preparing the numba kernels (about a minute the first time on this machine)"

_state: dict = {}


def prepared(requested: str, methods: Sequence[str]) -> bool:
    """Whether frames of ``methods`` on backend ``requested`` can be processed without
    :func:`prepare` compiling first: NumPy, no method that samples (``none``,
    ``separable``), or the kernels already prepared in this process."""
    if requested == "numpy" or "ended" in _state:
        return True
    if not any(METHODS[name].monte_carlo for name in methods):
        return True
    return not mc_backend.compiled(requested)


def prepare(
    requested: str,
    methods: Sequence[str],
    pixels: int | None,
    log: Callable[[str], None] | None,
) -> None:
    """Compile (or load from the disk cache) the kernels of backend ``requested``.

    ``methods``: the job's method names (nothing to do when none samples);
    ``pixels``: the frames' pixel count (H·W), so that only the sampling kernel's
    build for that size compiles (``core.mc.backend.warm_up``); None: both builds.
    Once per process; NumPy returns at once, without importing numba. With
    ``log``, a compile still running after :data:`NOTICE` seconds is announced and
    then reported with its time; a failure is logged, and the frame then compiles
    on its own and raises the error where it belongs.
    """
    if prepared(requested, methods):
        return
    # numba's threading layer (Blender's TBB inside Blender) starts on this thread, as
    # it did when the first frame compiled the kernels; the thread's kernels join it.
    mc_backend.threads()
    began = time.perf_counter()
    thread = threading.Thread(target=_compile, args=(pixels,), name="cvsss-compile")
    _state.update(began=began, error=None)
    thread.start()
    thread.join(NOTICE)
    if thread.is_alive() and log is not None:
        log("compiling the numba kernels (first use on this machine, about a minute)…")
    thread.join()
    error, seconds = _state["error"], _state["ended"] - began
    if log is None:
        return
    if error is not None:
        log(f"compiling the numba kernels failed: {type(error).__name__}: {error}")
    elif seconds > NOTICE:
        log(
            f"compiled the numba kernels in {seconds:.1f} s; later runs load them from "
            f"{mc_backend.cache_location()}"
        )


def _compile(pixels: int | None) -> None:
    try:
        mc_backend.warm_up(pixels)
    except Exception as exc:  # the frame's own call raises it where it belongs
        _state["error"] = exc
    _state["ended"] = time.perf_counter()


def before_first_frame(
    requested: str, methods: Sequence[str], log: Callable[[str], None] | None
) -> Callable:
    """``core.run.run_folder``'s ``prepare`` (``cvsss post``, ``cvsss demo``): :func:`prepare`
    for the first frame's size, called with the first frame to be processed."""

    def kernels(frame) -> None:
        prepare(requested, methods, math.prod(frame.shape), log)

    return kernels

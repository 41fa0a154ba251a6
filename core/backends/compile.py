"""Compiling the numba passes ahead of the first frame that needs them."""

from __future__ import annotations

import importlib
import logging
import time

from . import cache
from .select import numba_status

log = logging.getLogger("cvsss")


def compile_all(pixels: int | None = None) -> float:
    """Compile (or load from the disk cache) the numba passes; seconds it took.

    ``pixels``: of the sampling step, compile only the build that frames of that many
    pixels take (:func:`core.backends.numba.sampling.build_for`); None: both builds, and
    the cache is then stamped complete (:func:`core.backends.cache.is_complete`).

    Raises ImportError when numba is unavailable.
    """
    ok, what = numba_status()
    if not ok:
        raise ImportError(what)
    passes = importlib.import_module(f"{__package__}.numba.compile")
    t0 = time.perf_counter()
    passes.compile_all(pixels)
    seconds = time.perf_counter() - t0
    if pixels is None:  # every pass: the cache is complete (see cache.is_complete)
        try:
            cache.write_stamp()
        except OSError as exc:  # a read-only cache still serves; a later run compiles
            log.info("cvsss: could not stamp the numba cache: %s", exc)
    return seconds

"""Freed memory kept for the next frame: the command line's setting of glibc's malloc.

A temporal frame (``as_ccv_t`` and the other ``*_t`` methods) allocates and
frees a few hundred MB of arrays: the proxy's images, the reuse's (P, 3)
float64 terms. glibc hands the top of its heap back to the system once more
than ``M_TRIM_THRESHOLD`` of it is free, and serves large blocks from fresh
``mmap``\\ s, so each frame touches that memory anew: at 1920×1080 about 17 000
page faults and 115-175 ms of system CPU time per steady ``as_ccv_t`` frame on
the bench's flash scene. :func:`keep_freed_memory` raises both thresholds, so
the freed blocks serve the next frame: 435-609 page faults and 32-47 ms of
system time per frame, and 1-16 % less wall time per frame (median 12 %) in six
alternating pairs of runs (``docs/checks/heap_frame.py``); frames that fault no
pages (``as_ccv``) read the same within this host's noise (median of 14 runs
each way: 261 ms without, 264 ms with). The process's peak resident memory stays the same, but
between frames it no longer falls back.

Linux with glibc only (elsewhere the allocator is another one and this does
nothing); ``CVSSS_KEEP_HEAP=0`` in the environment turns it off.
"""

from __future__ import annotations

import ctypes
import os
import sys
from collections.abc import Mapping

#: mallopt's parameter numbers (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
#: Blocks up to this many bytes come from the heap, not from their own mmap (glibc's
#: largest allowed value on 64-bit systems: a (H·W, 3) float32 image of 2560×1440 is 44
#: MB and still gets its own).
MMAP_THRESHOLD = 32 << 20
#: Free bytes at the heap's top kept before they go back to the system.
TRIM_THRESHOLD = 1 << 30


def keep_freed_memory(environ: Mapping[str, str] = os.environ) -> bool:
    """Raise glibc's mmap and trim thresholds for this process (see the module doc).

    Returns
    -------
    bool, whether both were set (False: not glibc, or turned off by
    ``CVSSS_KEEP_HEAP=0``)
    """
    if environ.get("CVSSS_KEEP_HEAP", "1") == "0" or not sys.platform.startswith("linux"):
        return False
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError):  # no C library symbols, or no mallopt
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # musl's mallopt is a stub that returns 0.
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(
        mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD)
    )

"""The one place that chooses which implementation runs: NumPy or the compiled passes.

``numpy``
    Vectorised NumPy: the readable specification of every step; always available
    (the only backend where numba has no wheel, e.g. Windows on ARM).
``numba``
    The compiled passes of :mod:`core.backends.numba`, parallel over pixels.
    Used when numba imports; the steps it does not cover (the dipole and artist
    profiles, float16 histories, …) run on NumPy, and the twin table says which
    (:mod:`core.backends.twins`).

``SSSParams.backend = "auto"`` takes numba when it imports, NumPy otherwise;
asking for ``"numba"`` where it does not import falls back to NumPy with a
warning rather than failing a render. numba is imported lazily, the first time
a backend is resolved, so importing the core never pays for it.
"""

from __future__ import annotations

import importlib
import logging

from ..params import BACKENDS
from . import cache

log = logging.getLogger("cvsss")

_state: dict = {}


def numba_status() -> tuple[bool, str]:
    """(importable, description) of numba, importing it on the first call.

    The description is ``"numba 0.60.0"`` or why it is unavailable.
    """
    if "numba" not in _state:
        try:
            cache.use_writable_cache()
            numba = importlib.import_module("numba")
            importlib.import_module(f"{__package__}.numba")
            _state["numba"] = (True, f"numba {numba.__version__}")
        except Exception as exc:  # ImportError, or a broken llvmlite: fall back
            _state["numba"] = (False, f"numba unavailable ({type(exc).__name__}: {exc})")
    return _state["numba"]


def resolve(requested: str) -> str:
    """The backend that runs for ``requested`` (one of :data:`BACKENDS`): "numpy" or "numba".

    Logs the choice once per process and requested value.
    """
    if requested not in BACKENDS:
        raise ValueError(f"backend must be one of {', '.join(BACKENDS)}, got {requested!r}")
    if requested == "numpy":
        chosen, why = "numpy", "requested"
    else:
        ok, what = numba_status()
        chosen = "numba" if ok else "numpy"
        why = what if ok else f"{what}; NumPy fallback"
    key = ("logged", requested)
    if key not in _state:
        _state[key] = True
        level = logging.WARNING if requested == "numba" and chosen == "numpy" else logging.INFO
        log.log(level, "cvsss: Monte Carlo backend %s (asked %s: %s)", chosen, requested, why)
    return chosen


def compiled(requested: str) -> bool:
    """True where ``requested`` resolves to the compiled (numba) backend.

    "numpy" returns at once, without importing numba.
    """
    return requested != "numpy" and resolve(requested) == "numba"


def describe(requested: str = "auto") -> str:
    """One line for the panel and reports: which backend runs and why."""
    chosen = resolve(requested)
    if chosen == "numba":
        return f"numba ({numba_status()[1].split()[-1]}, {threads()} threads)"
    return "NumPy" if requested == "numpy" else f"NumPy ({numba_status()[1]})"


def threads() -> int:
    """Threads the compiled passes run on (1 when numba is unavailable)."""
    if not numba_status()[0]:
        return 1
    return int(importlib.import_module("numba").get_num_threads())

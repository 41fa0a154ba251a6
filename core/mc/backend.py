"""Which implementation of the sampling step runs: NumPy or the compiled numba kernel.

The sampling step (:func:`core.mc.estimator.estimate_distant`) has two
implementations that take the same samples and return the same estimate
within float32 rounding:

``numpy``
    Vectorised over the samples of bounded batches; always available.
``numba``
    One fused loop per pixel (sample → offset → gather → weight → accumulate),
    compiled by numba and parallel over pixels (:mod:`core.mc.estimator_numba`).
    Used when numba can be imported; it supports the Burley profile (the
    dipole and artist profiles run on NumPy, and the log says so).

``SSSParams.backend = "auto"`` takes numba when it imports, NumPy otherwise;
asking for ``"numba"`` where it does not import falls back to NumPy with a
warning rather than failing a render. numba is imported lazily, the first
time a backend is resolved, so importing core never pays for it.

Compiled code is cached on disk (numba ``cache=True``). numba writes its
cache next to the module; when that directory is read-only (an installed
extension, a system site-packages) ``NUMBA_CACHE_DIR`` is pointed at a
per-user cache directory first (:func:`cache_dir`), unless the user set it.
A warm-up of every kernel leaves a stamp there (:func:`kernels_cached`), so
that a later process can tell, without importing numba, that the cache is
complete for this source, Python and numba.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from importlib import metadata
from pathlib import Path

from ..io.atomic import write_text
from ..params import BACKENDS

log = logging.getLogger("cvsss")

_state: dict = {}


def cache_dir() -> Path:
    """Per-user directory for numba's compiled-code cache (``…/cvsss/numba``)."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "cvsss" / "numba"


def cache_location() -> Path:
    """Where numba keeps the compiled kernels: ``NUMBA_CACHE_DIR`` when set, else beside
    the module (``core/mc/__pycache__``)."""
    _prepare_cache()
    folder = os.environ.get("NUMBA_CACHE_DIR")
    return Path(folder) if folder else Path(__file__).resolve().parent / "__pycache__"


#: The stamp a complete warm-up writes into :func:`cache_location`.
STAMP = "cvsss-kernels.json"


def _stamp() -> dict:
    """What the cache's entries depend on besides the machine: the kernels' source file
    (numba's own staleness test: its modification time and size), Python and numba."""
    source = Path(__file__).with_name("estimator_numba.py").stat()
    return {
        "source": [source.st_mtime_ns, source.st_size],
        "python": sys.version,
        "numba": metadata.version("numba"),
    }


def kernels_cached() -> bool:
    """Whether every kernel was compiled into (or loaded from) :func:`cache_location` for
    this source, Python and numba: a warm-up of all of them left its stamp there.

    Does not import numba. False when numba is not installed. A cache that numba
    nevertheless finds stale (another CPU, say) is compiled again by the next warm-up.
    """
    try:
        return json.loads((cache_location() / STAMP).read_text()) == _stamp()
    except (OSError, ValueError, metadata.PackageNotFoundError):
        return False


def _prepare_cache() -> None:
    """Point numba's cache at a writable directory when the module's own is not."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    here = Path(__file__).resolve().parent
    target = here / "__pycache__"
    writable = os.access(target if target.exists() else here, os.W_OK)
    if not writable:
        path = cache_dir()
        path.mkdir(parents=True, exist_ok=True)
        os.environ["NUMBA_CACHE_DIR"] = str(path)
        if "numba" in sys.modules:  # imported by someone else: re-read its config
            from numba.core import config

            config.reload_config()


def numba_status() -> tuple[bool, str]:
    """(importable, description) of numba, importing it on the first call.

    The description is ``"numba 0.60.0"`` or why it is unavailable.
    """
    if "numba" not in _state:
        try:
            _prepare_cache()
            import numba

            from . import estimator_numba  # noqa: F401

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

    The sampling step and the per-frame steps with a compiled twin (the surface,
    the region, the SPVG step, the composite and maps, the history reprojection,
    the separable passes, the temporal neighbourhood) dispatch on it; "numpy"
    returns at once, without importing numba.
    """
    return requested != "numpy" and resolve(requested) == "numba"


def describe(requested: str = "auto") -> str:
    """One line for the panel and reports: which backend runs and why."""
    chosen = resolve(requested)
    if chosen == "numba":
        return f"numba ({numba_status()[1].split()[-1]}, {threads()} threads)"
    return "NumPy" if requested == "numpy" else f"NumPy ({numba_status()[1]})"


def threads() -> int:
    """Threads the numba kernel runs on (1 when numba is unavailable)."""
    if not numba_status()[0]:
        return 1
    import numba

    return int(numba.get_num_threads())


def warm_up(pixels: int | None = None) -> float:
    """Compile (or load from the disk cache) the numba kernels; seconds it took.

    ``pixels``: compile only the sampling kernel's build for frames of that many
    pixels (``estimator_numba.warm_up``); None: both builds, and the cache is then
    stamped complete (:func:`kernels_cached`).

    Raises ImportError when numba is unavailable.
    """
    ok, what = numba_status()
    if not ok:
        raise ImportError(what)
    from . import estimator_numba

    t0 = time.perf_counter()
    estimator_numba.warm_up(pixels)
    seconds = time.perf_counter() - t0
    if pixels is None:  # every kernel: the cache is complete (see kernels_cached)
        try:
            write_text(cache_location() / STAMP, json.dumps(_stamp()))
        except OSError as exc:  # a read-only cache still serves; a later run compiles
            log.info("cvsss: could not stamp the numba cache: %s", exc)
    return seconds

"""Where numba keeps the compiled passes on disk, and whether that cache is complete.

numba caches compiled code (``cache=True``) next to each module's source; when
that directory is read-only (an installed extension, a system site-packages)
``NUMBA_CACHE_DIR`` is pointed at a per-user cache directory first
(:func:`use_writable_cache`), unless the user set it. A compile of every pass
leaves a stamp there (:func:`is_complete`), so that a later process can tell,
without importing numba, that the cache is complete for this source, Python and
numba. An extension built by ``make extension`` ships the passes compiled
(:mod:`.shipped`): they load from there first, and count as complete.
"""

from __future__ import annotations

import json
import os
import sys
from importlib import metadata
from pathlib import Path

from ..io.atomic import write_text
from . import shipped

#: The folder of the compiled passes' sources (``core/backends/numba``).
SOURCES = Path(__file__).resolve().parent / "numba"

#: The stamp a complete compile writes into :func:`location`.
STAMP = "cvsss-kernels.json"


def user_dir() -> Path:
    """Per-user directory for numba's compiled-code cache (``…/cvsss/numba``)."""
    if sys.platform == "win32":
        base = Path(os.environ.get("LOCALAPPDATA") or Path.home() / "AppData" / "Local")
    elif sys.platform == "darwin":
        base = Path.home() / "Library" / "Caches"
    else:
        base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "cvsss" / "numba"


def location() -> Path:
    """Where numba keeps the compiled passes: ``NUMBA_CACHE_DIR`` when set, else beside
    their sources (``core/backends/numba/__pycache__``)."""
    use_writable_cache()
    folder = os.environ.get("NUMBA_CACHE_DIR")
    return Path(folder) if folder else SOURCES / "__pycache__"


def stamp() -> dict:
    """What the cache's entries depend on besides the machine: the sources (numba's own
    staleness test: each file's modification time and size), Python and numba."""
    sources = {}
    for path in sorted(SOURCES.glob("*.py")):
        st = path.stat()
        sources[path.name] = [st.st_mtime_ns, st.st_size]
    return {"source": sources, "python": sys.version, "numba": metadata.version("numba")}


def is_complete() -> bool:
    """Whether every compiled pass was compiled into (or loaded from) :func:`location`
    for these sources, Python and numba: a compile of all of them left its stamp there.

    Does not import numba. False when numba is not installed. A cache that numba
    nevertheless finds stale (another CPU, say) is compiled again by the next compile.
    True also where the extension ships the passes compiled for these sources, Python,
    numba and platform (:func:`core.backends.shipped.shipped`).
    """
    if shipped.shipped():
        return True
    try:
        return json.loads((location() / STAMP).read_text()) == stamp()
    except (OSError, ValueError, metadata.PackageNotFoundError):
        return False


def write_stamp() -> None:
    """Mark the cache complete (after every pass was compiled or loaded)."""
    write_text(location() / STAMP, json.dumps(stamp()))


def use_writable_cache() -> None:
    """Point numba's cache at a writable directory when the sources' own is not."""
    if os.environ.get("NUMBA_CACHE_DIR"):
        return
    target = SOURCES / "__pycache__"
    writable = os.access(target if target.exists() else SOURCES, os.W_OK)
    if not writable:
        path = user_dir()
        path.mkdir(parents=True, exist_ok=True)
        os.environ["NUMBA_CACHE_DIR"] = str(path)
        if "numba" in sys.modules:  # imported by someone else: re-read its config
            from numba.core import config

            config.reload_config()

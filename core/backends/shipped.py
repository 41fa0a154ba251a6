"""The numba passes compiled ahead, shipped inside the extension, loaded without compiling.

numba's own disk cache (``cache=True``) cannot travel. It takes an index for
stale when a pass's source file has another modification time or size
(``numba/core/caching.py``: ``_SourceFileBackedLocatorMixin.get_source_stamp``,
``IndexDataCacheFile._load_index``), and unzipping an extension gives every
file the time of the unzipping. It keys each entry by the CPU name and
features of the machine that compiled it (``Cache._index_key``,
``CPUCodegen.magic_tuple`` in ``numba/core/codegen.py``). And an entry names
the module it was compiled in, which loading it imports again
(``numba/core/environment.py``: ``_rebuild_env``), while an installed
extension's modules are named after the user's repository
(``bl_ext.user_default.cvsss``…).

So the build (``tools/ship_passes.py``, run by ``make extension``) compiles every pass
(:func:`core.backends.compile.compile_all`) for a CPU model every machine of a
target runs (``NUMBA_CPU_NAME``: ``x86-64-v3``, the AVX2 machines, and
``generic``; see :data:`TARGETS`), with the package imported as
:data:`BUILD_PACKAGE`, and writes numba's cache files into :data:`FOLDER`
(one folder per CPU model), each index stamped with the SHA-256 of the
passes' sources instead of their times, and a manifest: sources' hash,
Python, numba, platform, the entries' key and the CPU features they need.

At run time :func:`attach` (called by :mod:`core.backends.numba` when it is
imported) takes the first shipped build whose manifest matches these
sources, Python, numba and platform and whose CPU features this machine has,
and gives every pass a cache that looks there first, read-only, then in
numba's usual cache (:mod:`core.backends.cache`), where whatever it compiles
goes. A CPU model's code runs on any machine with its features; numba's own
cache holds a machine's own CPU name and would refuse it.
``CVSSS_SHIPPED_PASSES=0`` turns the shipped passes off.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import pickle
import platform
import shutil
import sys
from importlib import metadata
from pathlib import Path

log = logging.getLogger("cvsss")

#: Where the shipped builds live inside the extension, one folder per CPU model.
FOLDER = Path(__file__).resolve().with_name("shipped_passes")
#: Each build's manifest, written last.
MANIFEST = "manifest.json"
#: The package name the build imports the add-on under; its entries name it.
BUILD_PACKAGE = "_cvsss_build"
#: The package of the compiled passes, below the add-on's.
PASSES = "core.backends.numba"
#: Its folder (one module per domain).
SOURCES = Path(__file__).resolve().with_name("numba")

_V2 = ("cx16", "sahf", "popcnt", "sse3", "ssse3", "sse4.1", "sse4.2")
#: CPU models the build compiles for, best first, per machine architecture, with the
#: host features (LLVM's names) each needs: x86-64-v3 is AVX2 + FMA (Haswell, 2013, and
#: Zen on); the generic model, SSE2 on x86-64, runs on every machine of the platform.
TARGETS = {
    "x86_64": {
        "x86-64-v3": (*_V2, "avx", "avx2", "bmi", "bmi2", "f16c", "fma", "lzcnt", "movbe"),
        "generic": (),
    },
    "aarch64": {"generic": ()},
    "arm64": {"generic": ()},
}


def _machine() -> str:
    machine = platform.machine().lower()
    return "x86_64" if machine == "amd64" else machine


def targets() -> dict[str, tuple[str, ...]]:
    """The CPU models the build compiles for on this machine's architecture."""
    return TARGETS.get(_machine()) or {"generic": ()}


def source_hash(folder: Path = SOURCES) -> str:
    """SHA-256 of the passes' sources, every module of ``folder`` by name (what every
    shipped index is stamped with)."""
    digest = hashlib.sha256()
    for path in sorted(folder.glob("*.py")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _expected() -> dict:
    """What a shipped build must have been built for, to serve this process."""
    return {
        "source": source_hash(),
        "python": list(sys.version_info[:2]),
        "numba": metadata.version("numba"),
        "platform": [sys.platform, _machine()],
    }


def manifests() -> list[dict]:
    """The manifests of the shipped builds that match this source, Python, numba and
    platform, best CPU model first (read without importing numba)."""
    if os.environ.get("CVSSS_SHIPPED_PASSES", "1") == "0":
        return []
    try:
        expected = _expected()
    except (OSError, metadata.PackageNotFoundError):
        return []
    found = []
    for cpu in targets():
        try:
            manifest = json.loads((FOLDER / cpu / MANIFEST).read_text())
        except (OSError, ValueError):
            continue
        if all(manifest.get(key) == value for key, value in expected.items()):
            found.append(manifest)
    return found


def shipped() -> bool:
    """Whether a shipped build may serve this process (:func:`manifests`; whether this
    CPU has its features is known once numba is imported)."""
    return bool(manifests())


def _same_target(built: str, here: str) -> bool:
    """Whether code built for LLVM triple ``built`` runs under ``here``: the same
    architecture and system (macOS puts its version in the triple: darwin23.1.0)."""

    def stem(triple: str) -> list[str]:
        parts = triple.split("-")
        return parts[:2] + [part.rstrip("0123456789.") for part in parts[2:]]

    return stem(built) == stem(here)


def choose() -> dict | None:
    """The manifest of the shipped build this process loads: the first of
    :func:`manifests` for this LLVM target whose CPU features this machine has."""
    found = manifests()
    if not found:
        return None
    from llvmlite import binding as llvm

    triple = llvm.get_process_triple()
    features = {name for name, on in llvm.get_host_cpu_features().items() if on}
    for manifest in found:
        if _same_target(manifest["key"][0], triple) and set(manifest["requires"]) <= features:
            return manifest
    return None


#: The CPU model of the shipped build the passes load from (:func:`attach`), or None.
attached: str | None = None


def attach(package: str) -> str | None:
    """Give every pass of ``package`` (the name of :mod:`core.backends.numba`; its
    modules are imported here) the chosen shipped build (:func:`choose`) as its first
    place to look; that build's CPU model, or None."""
    global attached
    manifest = choose()
    if manifest is None:
        return None
    import importlib
    import pkgutil

    from numba.core.caching import FunctionCache, IndexDataCacheFile
    from numba.core.registry import CPUDispatcher

    folder = str(FOLDER / manifest["cpu"])
    key = tuple(manifest["key"])
    stamp = ("sha256", manifest["source"])

    class ShippedFirst(FunctionCache):
        """numba's cache of one pass, the shipped build looked up first."""

        def __init__(self, py_func):
            super().__init__(py_func)
            self._shipped = IndexDataCacheFile(folder, self._impl.filename_base, stamp)

        def _load_overload(self, sig, target_context):
            if self._enabled:
                sig_key, _, code = self._index_key(sig, target_context.codegen())
                try:
                    data = self._shipped.load((sig_key, key, code))
                    if data is not None:
                        return self._impl.rebuild(target_context, data)
                except Exception as exc:  # a damaged file: numba's own cache then serves
                    log.info("cvsss: shipped pass %s not loaded: %s", self._name, exc)
            return super()._load_overload(sig, target_context)

    built = manifest["module"]
    for info in pkgutil.iter_modules([str(SOURCES)]):
        module = importlib.import_module(f"{package}.{info.name}")
        # The entries' environments import the module they were compiled in
        # (_rebuild_env): this one, also after an update of the extension in a session.
        sys.modules[f"{built}.{info.name}"] = module
        for value in vars(module).values():
            if isinstance(value, CPUDispatcher) and type(value._cache) is FunctionCache:
                value._cache = ShippedFirst(value.py_func)
    attached = manifest["cpu"]
    return attached


# -- the build (tools/ship_passes.py compiles; this writes what it compiled) ------
def write_build(folder: Path, out: Path, root: Path, cpu: str, requires) -> dict:
    """Copy numba's cache files from ``folder`` to ``out``, each index stamped with the
    source's hash; then the manifest."""
    import numba
    from numba.core.serialize import dumps

    source = source_hash(root / PASSES.replace(".", "/"))
    if out.exists():
        shutil.rmtree(out)
    out.mkdir(parents=True)
    keys = set()
    for index in sorted(folder.glob("*.nbi")):
        with open(index, "rb") as f:
            version = pickle.load(f)
            _stamp, overloads = pickle.loads(f.read())
        if version != numba.__version__:
            raise RuntimeError(f"{index.name}: numba {version}, not {numba.__version__}")
        keys.update(key[1] for key in overloads)
        with open(out / index.name, "wb") as f:  # as numba's IndexDataCacheFile._save_index
            pickle.dump(version, f, protocol=-1)
            f.write(dumps((("sha256", source), overloads)))
        for name in overloads.values():
            shutil.copyfile(folder / name, out / name)
    if len(keys) != 1 or next(iter(keys))[1:] != (cpu, ""):
        raise RuntimeError(f"the cache holds entries for {sorted(keys)}, not CPU {cpu!r} only")
    manifest = {
        "source": source,
        "python": list(sys.version_info[:2]),
        "numba": numba.__version__,
        "platform": [sys.platform, _machine()],
        "cpu": cpu,
        "requires": list(requires),
        "key": list(next(iter(keys))),
        "module": f"{BUILD_PACKAGE}.{PASSES}",
    }
    (out / MANIFEST).write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


def blender_platform(manifest: dict) -> str:
    """Blender's name of the platform a shipped build is for (``linux-x64``…)."""
    system, machine = manifest["platform"]
    system = {"linux": "linux", "darwin": "macos", "win32": "windows"}[system]
    machine = {"x86_64": "x64", "aarch64": "arm64", "arm64": "arm64"}[machine]
    return f"{system}-{machine}"

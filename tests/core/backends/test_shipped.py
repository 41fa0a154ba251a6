"""The shipped numba passes (core.backends.shipped): built once, loaded elsewhere without
compiling."""

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytest.importorskip("numba")

from cvsss.core.backends import shipped  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]

#: Two small passes of the sampling step, called as the step and compile_all call them;
#: prints numba's cache hits and misses and the results.
CALL = """
import json, numpy as np
k = importlib.import_module(package + ".core.backends.numba.sampling")
order = k.tile_order(np.array([40, 0, 1], np.int64), np.zeros(3, np.int64), 64)  # tiles 1, 0, 0
texel = np.zeros(8, np.float32)
k.relight(np.array([[1.0, 2.0, 3.0]], np.float32), texel)
stats = [k._tile_order.stats, k.relight.stats]
print(json.dumps({
    "hits": sum(sum(s.cache_hits.values()) for s in stats),
    "misses": sum(sum(s.cache_misses.values()) for s in stats),
    "order": order.tolist(), "texel": texel[:3].tolist(),
    "shipped": type(k.relight._cache).__name__,
}))
"""

#: Imports the add-on at ``root`` as ``package`` (as Blender names an installed one).
IMPORT = """
import importlib, importlib.util, sys, types
root, package = sys.argv[1], sys.argv[2]
parts = package.split(".")
for i in range(1, len(parts)):
    parent = types.ModuleType(".".join(parts[:i])); parent.__path__ = []
    sys.modules.setdefault(parent.__name__, parent)
spec = importlib.util.spec_from_file_location(
    package, root + "/__init__.py", submodule_search_locations=[root])
module = importlib.util.module_from_spec(spec); sys.modules[package] = module
spec.loader.exec_module(module)
"""


def _run(root: Path, package: str, env: dict) -> dict:
    code = textwrap.dedent(IMPORT) + textwrap.dedent(CALL)
    proc = subprocess.run(
        [sys.executable, "-c", code, str(root), package],
        capture_output=True,
        text=True,
        timeout=600,
        env={**os.environ, **env},
        cwd=root.parent,
    )
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _addon_copy(path: Path) -> Path:
    """The add-on's Python files copied to ``path`` (new paths and modification times,
    as Blender's installer leaves them)."""
    shutil.copytree(
        ROOT / "core", path / "core", ignore=shutil.ignore_patterns("__pycache__", "shipped_*")
    )
    shutil.copy(ROOT / "__init__.py", path / "__init__.py")
    return path


@pytest.fixture(scope="module")
def build(tmp_path_factory):
    """A shipped build of the two passes for the generic CPU, compiled from this source
    under the build's package name into an empty cache: (its folder, manifest)."""
    tmp = tmp_path_factory.mktemp("build")
    cache = tmp / "numba"
    env = {
        "NUMBA_CACHE_DIR": str(cache),
        "NUMBA_CPU_NAME": "generic",
        "NUMBA_CPU_FEATURES": "",
        "CVSSS_SHIPPED_PASSES": "0",
    }
    built = _run(ROOT, shipped.BUILD_PACKAGE, env)
    assert built["misses"] == 2 and built["hits"] == 0
    (folder,) = (p for p in cache.iterdir() if p.is_dir())
    out = tmp / "shipped" / "generic"
    manifest = shipped.write_build(folder, out, ROOT, "generic", ())
    return out, manifest


def test_the_manifest_names_what_the_entries_were_built_for(build):
    out, manifest = build
    assert manifest["source"] == shipped.source_hash()
    assert manifest["cpu"] == "generic" and manifest["requires"] == []
    assert manifest["key"][1:] == ["generic", ""]
    assert manifest["module"] == "_cvsss_build.core.backends.numba"
    assert json.loads((out / shipped.MANIFEST).read_text()) == manifest
    assert sorted(p.suffix for p in out.iterdir()).count(".nbi") == 2


def test_an_installed_copy_loads_the_shipped_passes_without_compiling(build, tmp_path):
    """Another path, new file times, another package name and an empty cache: the two
    passes load from the shipped build (numba's cache: 2 hits, no miss), give the
    right results, and nothing is written into the shipped folder."""
    out, _ = build
    addon = _addon_copy(tmp_path / "cvsss")
    target = addon / "core" / "backends" / shipped.FOLDER.name / "generic"
    shutil.copytree(out, target)
    before = {p.name: p.read_bytes() for p in target.iterdir()}
    got = _run(addon, "bl_ext.user_default.cvsss", {"NUMBA_CACHE_DIR": str(tmp_path / "c")})
    assert got["shipped"] == "ShippedFirst"
    assert (got["hits"], got["misses"]) == (2, 0)
    assert got["order"] == [1, 2, 0] and got["texel"] == [1.0, 2.0, 3.0]
    assert {p.name: p.read_bytes() for p in target.iterdir()} == before


def test_another_source_compiles_into_numbas_own_cache(build, tmp_path):
    """A shipped build of other sources (one byte of one module changed) is refused: the
    passes compile as without one."""
    out, _ = build
    addon = _addon_copy(tmp_path / "cvsss")
    shutil.copytree(out, addon / "core" / "backends" / shipped.FOLDER.name / "generic")
    source = addon / "core" / "backends" / "numba" / "sampling.py"
    source.write_text(source.read_text() + "\n")
    got = _run(addon, "bl_ext.user_default.cvsss", {"NUMBA_CACHE_DIR": str(tmp_path / "c")})
    assert got["shipped"] == "FunctionCache"
    assert (got["hits"], got["misses"]) == (0, 2)
    assert got["order"] == [1, 2, 0]


def test_manifests_match_source_python_numba_and_platform(tmp_path, monkeypatch):
    monkeypatch.setattr(shipped, "FOLDER", tmp_path)
    good = {
        "source": shipped.source_hash(),
        "python": list(sys.version_info[:2]),
        "numba": __import__("numba").__version__,
        "platform": [sys.platform, shipped._machine()],
        "cpu": "generic",
    }
    (tmp_path / "generic").mkdir()
    for manifest, usable in [
        (good, True),
        ({**good, "source": "0" * 64}, False),
        ({**good, "python": [3, 10]}, False),
        ({**good, "numba": "0.59.1"}, False),
        ({**good, "platform": ["win32", "x86_64"]}, False),
    ]:
        (tmp_path / "generic" / shipped.MANIFEST).write_text(json.dumps(manifest))
        assert shipped.shipped() is usable, manifest
    monkeypatch.setenv("CVSSS_SHIPPED_PASSES", "0")
    (tmp_path / "generic" / shipped.MANIFEST).write_text(json.dumps(good))
    assert not shipped.shipped()


@pytest.mark.parametrize(
    "built, here, same",
    [
        ("x86_64-unknown-linux-gnu", "x86_64-unknown-linux-gnu", True),
        ("arm64-apple-darwin22.1.0", "arm64-apple-darwin23.4.0", True),
        ("x86_64-apple-darwin22.1.0", "arm64-apple-darwin22.1.0", False),
        ("x86_64-pc-windows-msvc", "x86_64-unknown-linux-gnu", False),
    ],
)
def test_same_target_ignores_the_system_version(built, here, same):
    assert shipped._same_target(built, here) is same


def test_blender_platform_names():
    names = {
        ("linux", "x86_64"): "linux-x64",
        ("linux", "aarch64"): "linux-arm64",
        ("darwin", "arm64"): "macos-arm64",
        ("darwin", "x86_64"): "macos-x64",
        ("win32", "x86_64"): "windows-x64",
    }
    for platform, name in names.items():
        assert shipped.blender_platform({"platform": list(platform)}) == name

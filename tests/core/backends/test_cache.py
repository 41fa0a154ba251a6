"""Where numba keeps the compiled passes (core.backends.cache) and compiling them all
(core.backends.compile)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import pytest

from cvsss.core.backends import cache
from cvsss.core.backends.compile import compile_all

numba = pytest.importorskip("numba")


def test_cache_dir_is_per_user():
    path = cache.user_dir()
    assert path.parts[-2:] == ("cvsss", "numba")
    if sys.platform.startswith("linux"):
        base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
        assert str(path).startswith(base)


def test_compiled_passes_are_cached_on_disk():
    """After the first compile, a fresh process loads the sampling passes from numba's
    disk cache."""
    code = textwrap.dedent(
        """
        import json
        from cvsss.core.backends.compile import compile_all
        from cvsss.core.backends.numba import sampling
        seconds = compile_all()
        passes = (sampling.pixel_sums, sampling.pixel_sums_serial)
        print(json.dumps({"s": seconds,
                          "hits": sum(sum(k.stats.cache_hits.values()) for k in passes),
                          "misses": sum(sum(k.stats.cache_misses.values()) for k in passes)}))
        """
    )
    compile_all()  # compiles (and writes the cache) if nothing did yet
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["hits"] >= 2 and out["misses"] == 0


def test_a_full_compile_stamps_the_cache_for_these_sources(tmp_path, monkeypatch):
    """``is_complete()``: the stamp a compile of every pass leaves in the cache folder,
    held against every source file of the passes (as numba's own staleness test: size
    and modification time), Python and numba; anything else, or no stamp, is not."""
    compile_all()
    assert cache.is_complete()
    stamp = json.loads((cache.location() / cache.STAMP).read_text())
    sources = sorted(p.name for p in cache.SOURCES.glob("*.py"))
    assert sorted(stamp["source"]) == sources and "sampling.py" in sources
    sampling = (cache.SOURCES / "sampling.py").stat()
    assert stamp["source"]["sampling.py"] == [sampling.st_mtime_ns, sampling.st_size]
    assert (stamp["python"], stamp["numba"]) == (sys.version, numba.__version__)
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CVSSS_SHIPPED_PASSES", "0")  # an extension's shipped passes count too
    assert not cache.is_complete()  # nothing there
    touched = {**stamp["source"], "sampling.py": [sampling.st_mtime_ns + 1, sampling.st_size]}
    for other, complete in [
        (stamp, True),
        ({**stamp, "source": touched}, False),
        ({**stamp, "numba": "0.0.1"}, False),
        ({**stamp, "python": "2.7"}, False),
    ]:
        (tmp_path / cache.STAMP).write_text(json.dumps(other))
        assert cache.is_complete() is complete
    (tmp_path / cache.STAMP).write_text("{")
    assert not cache.is_complete()


def test_is_complete_does_not_import_numba():
    code = (
        "import sys; from cvsss.core.backends import cache; cache.is_complete(); "
        "print('numba' in sys.modules)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False"]


@pytest.mark.parametrize(
    "pixels, build", [(1920 * 1080, "pixel_sums"), (48 * 32, "pixel_sums_serial")]
)
def test_compile_for_a_frame_size_loads_the_build_it_takes(pixels, build):
    """``compile_all(pixels)`` (what a job does before its first frame) loads or compiles
    the sampling step's build that frames of that size take, not the other."""
    code = textwrap.dedent(
        f"""
        import json
        from cvsss.core.backends.compile import compile_all
        from cvsss.core.backends.numba import sampling
        compile_all({pixels})
        print(json.dumps({{name: len(getattr(sampling, name).overloads)
                          for name in ("pixel_sums", "pixel_sums_serial")}}))
        """
    )
    compile_all()  # both builds in the disk cache, so the fresh process only loads
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert loaded == {name: int(name == build) for name in loaded}
    from cvsss.core.backends.numba import sampling

    assert sampling.build_for(0, pixels) is getattr(sampling, build)


def test_a_full_compile_prepares_every_specialisation_the_methods_call():
    """After ``compile_all()`` no method compiles anything: every pass, in the argument
    types the methods pass it, is among the compile's (what the background compile and
    the shipped passes hold), for still scenes and moving ones."""
    code = textwrap.dedent(
        """
        import json, pkgutil, importlib, numba
        from cvsss.core import synthetic
        from cvsss.core.backends import cache
        from cvsss.core.backends.compile import compile_all
        from cvsss.core.methods import METHODS, make_processor
        from cvsss.core.params import SSSParams
        compile_all()
        passes = {id(v): v for info in pkgutil.iter_modules([str(cache.SOURCES)])
                  for v in vars(importlib.import_module(
                      "cvsss.core.backends.numba." + info.name)).values()
                  if isinstance(v, numba.core.registry.CPUDispatcher)}.values()
        before = {id(k): set(k.overloads) for k in passes}
        for name in METHODS:
            for frames in (synthetic.sequence("flash", 2, 96, 54),
                           (synthetic.moving_frame(n, 96, 54) for n in (1, 2))):
                proc = make_processor(name, SSSParams(backend="numba"))
                for frame in frames:
                    proc.process(frame)
        print(json.dumps(sorted(f"{k.py_func.__name__}{list(sig)}" for k in passes
                                for sig in set(k.overloads) - before[id(k)])))
        """
    )
    compile_all()  # compiles (and writes the cache) if nothing did yet
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == []

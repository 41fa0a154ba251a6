"""Whole frames with this checkout's setup, SPVG step, composite and history
reprojection against a revision's.

Loads ``core/geometry.py``, ``core/mc/adaptive.py``, ``core/result.py`` and
``core/mc/history.py`` as they were at REV (``git show``; the rest of the core
is this checkout's) and runs ``MonteCarloProcessor.process`` on a steady
``as_ccv`` frame of the bench's flash sequence (``core.synthetic``; frame 3,
history from frames 1–2, the compiled backend) once with each revision's
``prepare``, SPVG counts and history update, ``assemble`` (the composite) and
``History.reproject``, calls interleaved, so a slow spell of a shared machine
hits both. ``prepare`` runs through the revision's ``GeometryCache`` where it
has one: the frame repeats, so that revision reuses the Geometry from the
second call on, as the frames of a still scene do (a revision without it
prepares every call).
Each call starts from the same history. Prints ms per whole frame (minimum,
25th percentile and median of the calls) and whether both give the same
composite, sample counts and history. Run from the repo root:

    .venv/bin/python docs/checks/frame_versus.py REV [WxH ...] [--calls N]
"""

import argparse
import importlib.util
import inspect
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cvsss.core import geometry, result
from cvsss.core.mc import adaptive, history, processor
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.synthetic import scene_frame


def load_module(rev: str, path: str, package: str, folder: Path):
    """The module at ``path`` as it was at ``rev``, as a module of ``package``."""
    text = subprocess.run(
        ["git", "show", f"{rev}:{path}"], check=True, capture_output=True, text=True
    ).stdout
    stem = f"{Path(path).stem}_{rev.replace('/', '_').replace('-', '_')}"
    file = folder / f"{stem}.py"
    file.write_text(text)
    name = f"{package}.{stem}"
    spec = importlib.util.spec_from_file_location(name, file)
    module = importlib.util.module_from_spec(spec)
    module.__package__ = package
    sys.modules[name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


def load_revision(rev: str, folder: Path) -> tuple:
    """(geometry, adaptive, result, history) modules as they were at ``rev``."""
    return (
        load_module(rev, "core/geometry.py", "cvsss.core", folder),
        load_module(rev, "core/mc/adaptive.py", "cvsss.core.mc", folder),
        load_module(rev, "core/result.py", "cvsss.core", folder),
        load_module(rev, "core/mc/history.py", "cvsss.core.mc", folder),
    )


def accepting(fn):
    """``fn`` called with only the keyword arguments it takes (an older revision's
    ``assemble`` or ``History.reproject`` has no ``backend``). An ``assemble`` that
    still takes ``total_ms`` instead of ``started`` gets 0: this script times the
    whole ``process()`` call itself."""
    names = inspect.signature(fn).parameters

    def call(*args, **kwargs):
        if "started" in kwargs and "total_ms" in names:
            kwargs["total_ms"] = 0.0
        return fn(*args, **{k: v for k, v in kwargs.items() if k in names})

    return call


class PrepareEachFrame:
    """The geometry step of a revision before core.geometry.GeometryCache."""

    def __init__(self, prepare) -> None:
        self._prepare = prepare

    def geometry_of(self, frame, profile, **options):
        return self._prepare(frame, profile, **options)


def compare(modules: dict, size: tuple[int, int], calls: int) -> None:
    w, h = size
    reproject = history.History.reproject
    # Each revision's reproject, taken before run() patches this checkout's class.
    reprojects = {id(mods): accepting(mods[3].History.reproject) for mods in modules.values()}
    frames = [scene_frame("flash", n, w, h) for n in (1, 2, 3)]
    proc = make_processor("as_ccv", SSSParams(backend="numba"))
    for frame in frames[:2]:
        proc.process(frame)
    state = proc.state()

    # Each revision's geometry step: its GeometryCache where it has one (the same frame
    # repeats, so it reuses the Geometry as a still scene's frames do), else geometry_of().
    caches = {
        id(mods): mods[0].GeometryCache()
        if hasattr(mods[0], "GeometryCache")
        else PrepareEachFrame(mods[0].prepare)
        for mods in modules.values()
    }

    def run(mods):
        processor.prepare = mods[0].prepare
        proc._geometry = caches[id(mods)]
        processor.adaptive = mods[1]
        processor.assemble = accepting(mods[2].assemble)
        history.History.reproject = reprojects[id(mods)]
        proc.restore(state)
        t0 = time.perf_counter()
        res = proc.process(frames[2])
        return time.perf_counter() - t0, res

    try:
        outputs = {name: run(mods)[1] for name, mods in modules.items()}  # warms up
        times = {name: [] for name in modules}
        for _ in range(calls):
            for name, mods in modules.items():
                times[name].append(run(mods)[0])
        states = {}
        for name, mods in modules.items():
            run(mods)
            states[name] = proc.state()
    finally:
        processor.prepare = geometry.prepare
        processor.adaptive = adaptive
        processor.assemble = result.assemble
        history.History.reproject = reproject
    first = next(iter(modules))
    print(f"{w}x{h}: {outputs[first].spp:.1f} spp, {outputs[first].samples} samples")
    for name, t in times.items():
        ms = np.array(t) * 1e3
        a, b = outputs[first], outputs[name]
        same = (
            np.array_equal(a.composite, b.composite)
            and np.array_equal(a.counts, b.counts)
            and states[first].keys() == states[name].keys()
            and all(np.array_equal(states[first][k], states[name][k]) for k in states[first])
        )
        print(
            f"  {name:>10}: min {ms.min():8.1f}  p25 {np.percentile(ms, 25):8.1f}  "
            f"median {np.median(ms):8.1f} ms per frame  same result as first: {same}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev")
    ap.add_argument("sizes", nargs="*", default=["1280x720", "1920x1080"])
    ap.add_argument("--calls", type=int, default=8)
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        this = (geometry, adaptive, result, history)
        modules = {a.rev: load_revision(a.rev, Path(tmp)), "this": this}
        for size in a.sizes:
            compare(modules, tuple(int(v) for v in size.split("x")), a.calls)


if __name__ == "__main__":
    main()

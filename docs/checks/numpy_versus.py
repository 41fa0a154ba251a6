"""The NumPy sampling step of this checkout against the one of a git revision, side by side.

Loads ``core/mc/estimator.py`` as it was at REV (``git show``; the rest of the
core is this checkout's) next to the current one and times both with the NumPy
backend on the bench's flash frame (``core.synthetic``), the default sample
kernel (``cycles``) and the sample counts of a steady ``as_ccv`` frame (frame 3,
history from frames 1–2), calls interleaved, so a slow spell of a shared
machine hits both. Each module runs with its own default batch size. Prints ns
per sample of the whole ``estimate_distant`` call (minimum, 25th percentile and
median of the calls), and whether both give the same bits in each distance mode
(``cycles``, ``surface``, ``planar``; with the variance and a hidden light of
0.3 in the first). ``--timed`` picks the mode the calls time (default
``cycles``; ``hidden`` is the one with the variance and hidden light).
``--profile dipole`` or ``artist`` puts that profile on every material (the
dipole with the measured skin1 and marble of the scene's two slots; the
compiled kernel runs Burley only, so these always run on NumPy). Run from the
repo root:

    .venv/bin/python docs/checks/numpy_versus.py REV [WxH ...] [--calls N] [--profile P] [--timed MODE]
"""

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from shared import steady

from cvsss.core.geometry import geometry_of
from cvsss.core.mc import estimator
from cvsss.core.method import MethodOptions
from cvsss.core.params import SSSParams
from cvsss.core.profiles import PROFILE_NAMES, ProfileChoice


def load_revision(rev: str, folder: Path):
    """The estimator module as it was at ``rev``, importing this checkout's core."""
    text = subprocess.run(
        ["git", "show", f"{rev}:core/mc/estimator.py"], check=True, capture_output=True, text=True
    ).stdout
    text = text.replace("from . import backend", "from cvsss.core.mc import backend")
    text = text.replace("from ..", "from cvsss.core.")
    path = folder / f"estimator_{rev.replace('/', '_')}.py"
    path.write_text(text)
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


#: --timed: the mode the calls time.
TIMED = {
    "cycles": "cycles",
    "hidden": "cycles, variance, hidden 0.3",
    "surface": "surface",
    "planar": "planar",
}


def compare(modules: dict, size: tuple[int, int], calls: int, kind: str, timed: str) -> None:
    w, h = size
    params = SSSParams()
    # The dipole needs measured materials: the synthetic scene's skin and marble slots.
    presets = ((1, "skin1"), (2, "marble")) if kind == "dipole" else ()
    choice = ProfileChoice(profile=kind, slot_materials=presets)
    frame, profile, result = steady(size, params, MethodOptions(profile=choice))
    surface = geometry_of(frame, profile, surface_distance=True, core_only=True)
    planar = geometry_of(frame, profile, surface_distance=False, core_only=True)
    counts = result.counts.reshape(-1)[surface.index].astype(np.int64)
    total = int(counts.sum())
    common = dict(frame=frame.number, seed=params.seed, depth_slope=params.depth_slope)
    common.update(backend="numpy", contact=params.contact)
    modes = {
        "cycles": (surface, dict(disk=True, hidden_light=params.hidden_light)),
        "cycles, variance, hidden 0.3": (surface, dict(disk=True, hidden_light=0.3, variance=True)),
        "surface": (surface, dict(disk=False, hidden_light=params.hidden_light)),
        "planar": (planar, dict(disk=False, hidden_light=params.hidden_light)),
    }

    def run(module, mode="cycles"):
        geom, kw = modes[mode]
        return module.estimate_distant(
            geom, frame.lighting, frame.depth, profile, counts, **common, **kw
        )

    print(f"{w}x{h}, {kind}: {int((counts > 0).sum())} pixels, {total} samples")
    first = next(iter(modules.values()))
    for mode in modes:
        a = run(first, mode)
        for module in list(modules.values())[1:]:
            b = run(module, mode)
            same = (
                np.array_equal(a.distant, b.distant)
                and a.fallback == b.fallback
                and (a.variance is None) == (b.variance is None)
                and (a.variance is None or np.array_equal(a.variance, b.variance))
            )
            print(f"  {mode}: same bits as {next(iter(modules))}: {same}")
    times = {name: [] for name in modules}
    for _ in range(calls):
        for name, module in modules.items():
            t0 = time.perf_counter()
            run(module, TIMED[timed])
            times[name].append(time.perf_counter() - t0)
    for name, t in times.items():
        ns = np.array(t) * 1e9 / total
        print(
            f"  {name:>10}: min {ns.min():6.1f}  p25 {np.percentile(ns, 25):6.1f}  "
            f"median {np.median(ns):6.1f} ns/sample ({TIMED[timed]})"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev")
    ap.add_argument("sizes", nargs="*", default=["640x360", "1280x720"])
    ap.add_argument("--calls", type=int, default=9)
    ap.add_argument("--profile", choices=PROFILE_NAMES, default="burley")
    ap.add_argument("--timed", choices=list(TIMED), default="cycles")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        modules = {a.rev: load_revision(a.rev, Path(tmp)), "this": estimator}
        for size in a.sizes:
            compare(modules, tuple(int(v) for v in size.split("x")), a.calls, a.profile, a.timed)


if __name__ == "__main__":
    main()

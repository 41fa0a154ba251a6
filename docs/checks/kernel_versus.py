"""The compiled kernel of this checkout against the one of a git revision, side by side.

Loads ``core/mc/estimator_numba.py`` as it was at REV (``git show``) next to
the current one and times both on the bench's flash frame (``core.synthetic``)
with the default sample kernel (``cycles``) and the sample counts of a steady
``as_ccv`` frame (frame 3, history from frames 1–2), calls interleaved, so a
slow spell of a shared machine hits both. Prints ns per sample of the whole
``run_kernel`` call with the start of the estimate, γ·B (minimum, 25th
percentile and median of the calls), and whether both give the same bits:
each pixel's γ·B plus its mean (a revision whose kernel returned sums has
them divided by the counts after the call, as ``estimate_distant`` then did,
inside the timing; a kernel that takes ``start`` sets the rows itself), the
luminance sums and the fall-back count. All calls share one Geometry that a
``GeometryCache`` handed on, as the frames of a still scene do: a kernel that
keeps its texels in a reused Geometry's memos relights them from its second
call on. REV must have ``run_kernel``'s positional arguments of 6ff9b0c
or later. ``--counts LO-HI`` instead gives every SSS pixel of that frame a count
drawn uniformly from LO…HI (a fixed seed): where the adaptive methods spend their
samples at low counts, a pixel's own cost weighs. ``--frame N`` takes frame N of the
sequence and its ``as_ccv`` counts instead of frame 3's (from frame 4 on, once the
history settles, 82–87 % of the pixels take β_min = 8 samples). Run from the repo
root:

    .venv/bin/python docs/checks/kernel_versus.py REV [WxH ...] [--calls N] [--counts LO-HI]
        [--frame N]
"""

import argparse
import importlib.util
import inspect
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np
from shared import steady_geometry

from cvsss.core.backends.numba import sampling as estimator_numba
from cvsss.core.params import SSSParams


def load_revision(rev: str, folder: Path):
    """The kernel module as it was at ``rev``, compiled from a temporary copy."""
    text = subprocess.run(
        ["git", "show", f"{rev}:core/mc/estimator_numba.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    text = text.replace("from ..", "from cvsss.core.")
    path = folder / f"kernel_{rev.replace('/', '_')}.py"
    path.write_text(text.replace("cache=True", "cache=False"))
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def compare(
    modules: dict,
    size: tuple[int, int],
    calls: int,
    spread: tuple[int, int] | None = None,
    number: int = 3,
) -> None:
    w, h = size
    params = SSSParams(backend="numba")
    frame, profile, geom, counts = steady_geometry(size, params, number)
    if spread is not None:
        counts = np.random.default_rng(0).integers(spread[0], spread[1] + 1, geom.size)
    active = np.flatnonzero((counts > 0) & (geom.gamma_sum > 0))
    total = int(counts[active].sum())
    args = (frame.lighting, frame.depth, frame.number, params.seed, params.depth_slope)
    tail = (False, True, params.hidden_light, params.contact)

    every = active.size == geom.size

    def run(module):
        keywords = inspect.signature(module.run_kernel).parameters
        if "start" in keywords and every:  # the kernel starts the rows at γ·B itself
            distant = np.empty((geom.size, 3))
            var, fallback = module.run_kernel(
                geom, profile, counts, active, *args, *tail, distant=distant, start=True
            )
            return distant, var, fallback
        # γ·B first, as estimate_distant does for such a kernel.
        distant = geom.gamma * geom.at(frame.lighting).astype(np.float64)
        if "distant" in keywords:
            var, fallback = module.run_kernel(
                geom, profile, counts, active, *args, *tail, distant=distant
            )
        else:  # before 2026-11-26 the kernel returned sums, divided afterwards
            sums, var, fallback = module.run_kernel(geom, profile, counts, active, *args, *tail)
            distant[active] += sums / counts[active][:, None]
        return distant, var, fallback

    outputs = {name: run(module) for name, module in modules.items()}  # compiles
    times = {name: [] for name in modules}
    for _ in range(calls):
        for name, module in modules.items():
            t0 = time.perf_counter()
            run(module)
            times[name].append(time.perf_counter() - t0)
    first = next(iter(outputs.values()))
    print(f"{w}x{h}: {active.size} pixels, {total} samples ({total / active.size:.1f} spp)")
    for name, t in times.items():
        ns = np.array(t) * 1e9 / total
        same = all(
            np.array_equal(a, b) if a is not None else b is None
            for a, b in zip(first, outputs[name])
        )
        print(
            f"  {name:>10}: min {ns.min():6.2f}  p25 {np.percentile(ns, 25):6.2f}  "
            f"median {np.median(ns):6.2f} ns/sample  same bits as first: {same}"
        )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev")
    ap.add_argument("sizes", nargs="*", default=["640x360", "1280x720", "1920x1080"])
    ap.add_argument("--calls", type=int, default=15)
    ap.add_argument("--counts", default=None, help="LO-HI: uniform random counts per pixel")
    ap.add_argument("--frame", type=int, default=3, help="the frame whose counts to take")
    a = ap.parse_args()
    spread = tuple(int(v) for v in a.counts.split("-")) if a.counts else None
    with tempfile.TemporaryDirectory() as tmp:
        modules = {a.rev: load_revision(a.rev, Path(tmp)), "this": estimator_numba}
        for size in a.sizes:
            compare(modules, tuple(int(v) for v in size.split("x")), a.calls, spread, a.frame)


if __name__ == "__main__":
    main()

"""The history step of a steady ``as_ccv`` frame: one compiled pass against NumPy's, and J.

The adaptive methods (``as``, ``as_ccv``, ``as_ocv`` and their temporal
variants) update their float32 history in one compiled pass
(:func:`core.mc.estimator_numba.history_step`: the tracked luminance, the
online control variate's step, Eq. 5–7 and the stores in place); those without
an online control variate hold no J (its five buffers), which the history then
neither reprojects nor stores. On the
bench's flash frame (``core.synthetic``; frame 7, history from frames 1–6,
the compiled backend), for each size, this prints the whole ``process()``
call, minimum and median of ``--calls`` interleaved calls from the same
processor state, for

- ``this``: the compiled step, no J;
- ``numpy step``: the same processor with the NumPy history step;
- ``numpy step + J``: the NumPy step on a history that also carries J (the
  release before);

and ``update_ms`` (the history step alone) of each, and whether all three give
the same composite, counts and H buffers. Run from the repo root:

    .venv/bin/python docs/checks/history_step.py [WxH ...] [--calls N]
"""

import argparse
import time

import numpy as np

from cvsss.core.mc.history import H_FIELDS, History
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.synthetic import scene_frame


def variant(name: str, frames):
    proc = make_processor("as_ccv", SSSParams(backend="numba"))
    if name != "this":
        proc._compiled_step = lambda hist, index: False
    if name == "numpy step + J":
        p = proc.params
        proc.history = History.empty(
            frames[0].shape, p.history_precision, p.eta_cv, p.target_variance
        )
    for f in frames[:6]:
        proc.process(f)
    return proc, proc.state()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("sizes", nargs="*", default=["1280x720", "1920x1080"])
    ap.add_argument("--calls", type=int, default=8)
    a = ap.parse_args()
    for size in a.sizes:
        w, h = (int(v) for v in size.split("x"))
        frames = [scene_frame("flash", n, w, h) for n in range(1, 8)]
        procs = {n: variant(n, frames) for n in ("this", "numpy step", "numpy step + J")}
        times = {n: [] for n in procs}
        updates = {n: [] for n in procs}
        out = {}
        for _ in range(a.calls):
            for name, (proc, state) in procs.items():
                proc.restore(state)
                t = time.perf_counter()
                out[name] = proc.process(frames[6])
                times[name].append(time.perf_counter() - t)
                updates[name].append(out[name].update_ms)
        first = out["this"]
        print(f"{w}x{h}: {first.spp:.1f} spp")
        for name in procs:
            ms = np.array(times[name]) * 1e3
            r, hist = out[name], procs[name][0].history
            same = (
                np.array_equal(r.composite, first.composite)
                and np.array_equal(r.counts, first.counts)
                and all(
                    np.array_equal(hist.buffers[k], procs["this"][0].history.buffers[k])
                    for k in H_FIELDS
                )
            )
            print(
                f"  {name:>15}: frame min {ms.min():7.1f}  median {np.median(ms):7.1f} ms;  "
                f"update_ms min {min(updates[name]):6.1f};  buffers {len(hist.buffers)};  "
                f"same as this: {same}"
            )


if __name__ == "__main__":
    main()

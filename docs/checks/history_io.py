"""The temporal reuse's history reads and writes at 1920×1080: NumPy against compiled.

Times, per frame of a temporal method in multiplicative mode (``as_ccv_t``), what
:func:`core.mc.temporal.reuse` reads and stores of its float32 history: the frame
count and the three RGB buffers (accumulated estimate, control, proxy), 10 reads
and 10 writes at 915 076 SSS pixels (the bench frame's count) of a 1920×1080
image. "numpy" is :meth:`History.read` / :meth:`History.write` per buffer,
stacked into (P, 3) as the reuse reads them; "compiled" is
:meth:`History.read_columns` / :meth:`History.write_columns` on the numba
backend (the same values, tests/core/test_backend.py). Calls interleaved; prints
the minimum and median ms of each. ``--keep`` first keeps freed memory for the
next frame, as the ``cvsss`` command does. Run from the repo root:

    .venv/bin/python docs/checks/history_io.py [--calls N] [--keep]
"""

import argparse
import time

import numpy as np

from cvsss.core.mc.history import History
from cvsss.sss_addon.cli.heap import keep_freed_memory

SHAPE = (1080, 1920)
PIXELS = 915_076
GROUPS = (
    ("acc_n",),
    ("acc_r", "acc_g", "acc_b"),
    ("ctl_r", "ctl_g", "ctl_b"),
    ("prox_r", "prox_g", "prox_b"),
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--calls", type=int, default=15)
    ap.add_argument("--keep", action="store_true", help="keep freed memory (as cvsss does)")
    a = ap.parse_args()
    if a.keep:
        keep_freed_memory()
    rng = np.random.default_rng(0)
    hist = History.empty(SHAPE, "float32", 1e-3, 1e-4, temporal=True)
    index = np.sort(rng.choice(SHAPE[0] * SHAPE[1], PIXELS, replace=False)).astype(np.int64)
    values = {g: rng.normal(0, 1, (PIXELS, len(g))) for g in GROUPS}

    def numpy_io() -> None:
        for g in GROUPS:
            np.stack([hist.read(n, index) for n in g], axis=-1)
        for g in GROUPS:
            for c, n in enumerate(g):
                hist.write(n, index, values[g][:, c])

    def compiled_io() -> None:
        for g in GROUPS:
            hist.read_columns(g, index, "numba")
        for g in GROUPS:
            hist.write_columns(g, index, values[g], "numba")

    runs = {"numpy": numpy_io, "compiled": compiled_io}
    times: dict[str, list[float]] = {name: [] for name in runs}
    for fn in runs.values():  # compiles or loads the kernels
        fn()
    for _ in range(a.calls):
        for name, fn in runs.items():
            t0 = time.perf_counter()
            fn()
            times[name].append((time.perf_counter() - t0) * 1e3)
    print(f"10 reads + 10 writes of {PIXELS} pixels, freed memory kept: {a.keep}")
    for name, t in times.items():
        print(f"  {name:>8}: min {min(t):6.1f}  median {np.median(t):6.1f} ms")


if __name__ == "__main__":
    main()

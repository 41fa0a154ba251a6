"""A steady frame's time, and how much of it is outside the sampling step.

Processes frames 1–6 of the bench's flash sequence (``core.synthetic``: a still
scene whose light flashes) with one method and the compiled backend, then times
``process()`` on frame 7 ``CALLS`` times from the same processor state and
prints, minimum and median over the calls: the whole call, the sampling step
(``sampling_ms``), the history step (``update_ms``) and the rest of the frame (the
whole call minus ``sampling_ms``, per call: geometry, counts, history reprojection
and update, composite and maps). Run from the repo root:

    .venv/bin/python docs/checks/steady_frame.py [WxH] [CALLS] [--method as_ccv] [--keep]

``--keep`` first keeps freed memory for the next frame, as the ``cvsss`` command
does (:func:`sss_addon.cli.heap.keep_freed_memory`).

To compare with another revision, check it out in a worktree and run this
script (from this checkout) with that worktree first on the import path; run
the two alternately, since the host's speed drifts::

    git worktree add /tmp/rev REV && mkdir -p /tmp/revpkg && ln -s /tmp/rev /tmp/revpkg/cvsss
    PYTHONPATH=/tmp/revpkg .venv/bin/python docs/checks/steady_frame.py 1920x1080 10
    .venv/bin/python docs/checks/steady_frame.py 1920x1080 10
"""

import argparse
import time

import numpy as np
from shared import steady_processor

import cvsss


def stats(values) -> str:
    return f"min {min(values):7.1f}  median {np.median(values):7.1f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("size", nargs="?", default="1920x1080")
    ap.add_argument("calls", nargs="?", type=int, default=10)
    ap.add_argument("--method", default="as_ccv")
    ap.add_argument("--keep", action="store_true", help="keep freed memory, as cvsss does")
    a = ap.parse_args()
    if a.keep:  # imported here: revisions before it have no such module
        from cvsss.sss_addon.cli.heap import keep_freed_memory

        keep_freed_memory()
    w, h = (int(v) for v in a.size.split("x"))
    proc, state, frame = steady_processor((w, h), a.method)
    total, sampling, update, rest = [], [], [], []
    for _ in range(a.calls):
        proc.restore(state)
        t = time.perf_counter()
        res = proc.process(frame)
        total.append((time.perf_counter() - t) * 1e3)
        sampling.append(res.sampling_ms)
        update.append(res.update_ms)
        rest.append(total[-1] - res.sampling_ms)
    print(f"{cvsss.__file__}: {a.method} {w}x{h}, {res.spp:.1f} spp (ms)")
    print(f"  frame {stats(total)} | sampling {stats(sampling)}")
    print(f"  history step {stats(update)} | outside the sampling step {stats(rest)}")


if __name__ == "__main__":
    main()

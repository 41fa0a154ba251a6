"""Page faults and system time of a steady frame, with and without the freed memory kept.

Processes frames 1–6 of the bench's flash sequence (``core.synthetic``) with one
method on the compiled backend, then frame 7 ``CALLS`` times from the same state,
and prints per frame: wall time, this process's user and system CPU time and its
minor page faults, and the process's peak resident memory (``resource.getrusage``;
Linux reports it in KiB). With ``--keep`` it first calls
:func:`sss_addon.cli.heap.keep_freed_memory`, as the ``cvsss`` command does. Run
the two alternately from the repo root (the host's speed drifts)::

    .venv/bin/python docs/checks/heap_frame.py 1920x1080 7 --method as_ccv_t --keep
    CVSSS_KEEP_HEAP=0 .venv/bin/python docs/checks/heap_frame.py 1920x1080 7 --method as_ccv_t
"""

import argparse
import resource
import time

from shared import steady_processor

from cvsss.sss_addon.cli.heap import keep_freed_memory


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("size", nargs="?", default="1920x1080")
    ap.add_argument("calls", nargs="?", type=int, default=7)
    ap.add_argument("--method", default="as_ccv_t")
    ap.add_argument("--keep", action="store_true", help="keep freed memory (as cvsss does)")
    a = ap.parse_args()
    kept = keep_freed_memory() if a.keep else False
    w, h = (int(v) for v in a.size.split("x"))
    proc, state, frame = steady_processor((w, h), a.method)
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    for _ in range(a.calls):
        proc.restore(state)
        proc.process(frame)
    r1, t1 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    n = a.calls
    print(
        f"{a.method} {w}x{h}, freed memory kept: {kept}; per frame: wall "
        f"{(t1 - t0) / n * 1e3:.0f} ms, user {(r1.ru_utime - r0.ru_utime) / n * 1e3:.0f} ms, "
        f"system {(r1.ru_stime - r0.ru_stime) / n * 1e3:.0f} ms, minor page faults "
        f"{(r1.ru_minflt - r0.ru_minflt) / n:.0f}; peak RSS {r1.ru_maxrss / 1024:.0f} MiB"
    )


if __name__ == "__main__":
    main()

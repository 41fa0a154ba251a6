"""The compiled separable passes alone: their time per frame, per configuration.

Runs one frame of the bench's flash scene (``core.synthetic``) at WxH through the
``separable`` method with each configuration below (and through ``as_ccv_t``, whose
noise-free proxy is the linear pre-integrated kernel), records the arguments of
every compiled pass it calls (``core.backends.numba.separable.separable_pass``), then
times those calls again, ``CALLS`` rounds, and prints the minimum and median of a
frame's passes (ms, both directions, all terms). Run from the repo root:

    .venv/bin/python docs/checks/separable_pass.py [WxH] [CALLS]

To compare with another revision, run it with that revision's worktree first on
the import path (as ``steady_frame.py`` explains), alternately with this one
(revisions before the backends floor kept the passes in ``core.mc.estimator_numba``).
"""

import argparse
import time

import numpy as np

import cvsss
from cvsss.core.backends.numba import separable as estimator_numba
from cvsss.core.method import MethodOptions
from cvsss.core.methods import make_processor
from cvsss.core.params import SeparableParams, SSSParams
from cvsss.core.synthetic import scene_frame

CONFIGS = {
    "as_ccv_t proxy (linear)": ("as_ccv_t", {}),
    "separable (nearest, default)": ("separable", {}),
    "separable svd2 linear": ("separable", {"kernel": "svd2", "filter": "linear"}),
    "separable exponential jitter": ("separable", {"follow": "exponential", "jitter": True}),
}


def record(method: str, options: dict, frame) -> list:
    """The (build, arguments) of every compiled pass one frame of ``method`` calls."""
    calls = []
    original = estimator_numba.separable_pass

    def recording(*a):
        # This revision picks a build per follow rule; an older one was the build.
        build = original(*a) if len(a) == 1 else original

        def run(*args):
            calls.append((build, args))
            return build(*args)

        return run if len(a) == 1 else run(*a)

    estimator_numba.separable_pass = recording
    try:
        opts = MethodOptions(separable=SeparableParams(**options))
        make_processor(method, SSSParams(backend="numba"), opts).process(frame)
    finally:
        estimator_numba.separable_pass = original
    return calls


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("size", nargs="?", default="1920x1080")
    ap.add_argument("calls", nargs="?", type=int, default=7)
    a = ap.parse_args()
    w, h = (int(v) for v in a.size.split("x"))
    frame = scene_frame("flash", 2, w, h)
    print(f"{cvsss.__file__}: {w}x{h}, ms per frame's passes")
    for label, (method, options) in CONFIGS.items():
        calls = record(method, options, frame)
        times = []
        for _ in range(a.calls):
            t = 0.0
            for build, args in calls:
                args = (*args[:-1], np.zeros_like(args[-1]))
                t0 = time.perf_counter()
                build(*args)
                t += time.perf_counter() - t0
            times.append(t * 1e3)
        print(f"  {label:<30} {len(calls)} passes  min {min(times):7.1f}  median "
              f"{np.median(times):7.1f}")  # fmt: skip


if __name__ == "__main__":
    main()

"""Where the compiled kernel's time goes: the kernel timed with its later stages cut off.

``core/mc/estimator_numba.py`` takes each batch of samples through four
stages (draw the sample, follow-surface test, weights, gather and sums). This
script compiles copies of the kernel's source that stop after stage 0 (the
per-pixel set-up only), 1, 2 and 3, and times each on the bench's flash frame
(``core.synthetic``) with the default sample kernel (``cycles``), 24 spp on
average (12–36 per pixel). The differences between consecutive rows are the
stages' costs, in ns per sample of the whole call (2 threads). The cut
copies still store their stage's outputs, so the compiler cannot drop the
work; their results are meaningless and not used. Run from the repo root:

    .venv/bin/python docs/checks/kernel_stages.py [WxH] [spp]
"""

import importlib.util
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cvsss.core.backends.numba import sampling as estimator_numba
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.params import SSSParams
from cvsss.core.profiles.factory import ProfileCache
from cvsss.core.synthetic import scene_frame

STAGES = (
    "                # Stage 1a: R2 point",
    "                # Stage 2a: the landing pixel",
    "                # Stage 3: per-channel weights",
    "                # Stage 4: gather and sum",
)
LOOP = "            for k0 in range(1, m + 1, BATCH):"
END = "            mf = np.float64(m)"
# What each cut copy adds to its sum so that the cut stage's stores stay live.
KEEP = (
    "            s0 += pa + nz + t_map[li, 0, 2]\n",
    "                s0 += fb[_ROW_R]\n",
    "                s0 += fb[_ROW_ZQ]\n",
    "                s0 += b_w[0, 0]\n",
)


def variants(source: str) -> dict[str, str]:
    """Source of the kernel module cut after each stage (``full``: unchanged)."""
    source = source.replace("from ..", "from cvsss.core.").replace("from .", "from cvsss.core.mc.")
    source = source.replace("cache=True", "cache=False")
    end = source.index(END)
    out = {"set-up": source[: source.index(LOOP)] + KEEP[0] + source[end:]}
    for n in (1, 2, 3):
        cut = source.index(STAGES[n])
        out[f"stages 1-{n}"] = source[:cut] + KEEP[n] + source[end:]
    out["full"] = source
    return out


def main() -> None:
    w, h = (int(v) for v in (sys.argv[1] if len(sys.argv) > 1 else "640x360").split("x"))
    spp = int(sys.argv[2]) if len(sys.argv) > 2 else 24
    params = SSSParams()
    frame = scene_frame("flash", 2, w, h)
    profile = ProfileCache(params, None).get(frame)
    geom = geometry_of(frame, profile, surface_distance=True, backend="numba")
    rng = np.random.default_rng(0)
    counts = rng.integers(spp // 2, spp * 3 // 2 + 1, geom.size)
    counts[geom.gamma_max < params.eps_u] = 0
    total = int(counts.sum())
    print(f"{w}x{h}: {geom.size} SSS pixels, {total} samples")
    source = Path(estimator_numba.__file__).read_text()
    original = estimator_numba.build_for
    previous = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        try:
            for name, text in variants(source).items():
                path = Path(tmp) / f"kernel_{len(name)}_{abs(hash(name))}.py"
                path.write_text(text)
                spec = importlib.util.spec_from_file_location(path.stem, path)
                module = importlib.util.module_from_spec(spec)
                spec.loader.exec_module(module)
                estimator_numba.build_for = lambda n, p=0, m=module: m.pixel_sums

                def run():
                    estimate_distant(
                        geom,
                        frame.lighting,
                        frame.depth,
                        profile,
                        counts,
                        frame=2,
                        seed=0,
                        depth_slope=params.depth_slope,
                        backend="numba",
                        disk=True,
                    )

                run()  # compile
                best = np.inf
                for _ in range(7):
                    t0 = time.perf_counter()
                    run()
                    best = min(best, time.perf_counter() - t0)
                ns = best * 1e9 / total
                print(f"{name:>12}: {ns:6.2f} ns/sample  (+{ns - previous:5.2f})")
                previous = ns
        finally:
            estimator_numba.build_for = original


if __name__ == "__main__":
    main()

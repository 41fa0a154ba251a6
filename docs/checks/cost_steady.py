"""The bench's cost rows over more frames: ns per sample once the adaptive counts settle.

``make bench`` times its cost rows on frames 2–3 of the flash sequence
(``BenchConfig.cost_frames = 3``), where the adaptive methods still take
about 49 spp; a few frames later ``as_ccv`` takes about 15. A pixel costs the
compiled kernel a fixed part besides its samples (``kernel_per_pixel.py``),
so the ratio to the gather roofline grows as the counts fall. This script
runs the same cost section (:func:`core.bench.section_cost`: interleaved
configurations, the gather timed right after each frame) over FRAMES frames
on the backends given and prints, per size and method, the mean spp, ns per
sample, the paired gather and their ratio (median over frames 2…FRAMES).
Run from the repo root:

    .venv/bin/python docs/checks/cost_steady.py [FRAMES] [--backends numba,numpy]
"""

import argparse

from cvsss.core.bench import BenchConfig
from cvsss.core.bench.cost import section_cost


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("frames", nargs="?", type=int, default=6)
    ap.add_argument("--backends", default="numba")
    a = ap.parse_args()
    cfg = BenchConfig(backends=tuple(a.backends.split(",")), cost_frames=a.frames)
    out = section_cost(cfg)
    for backend, sizes in out["by_backend"].items():
        for size, rows in sizes.items():
            print(f"{backend} {size}, frames 2-{a.frames}:")
            for method, r in rows.items():
                print(
                    f"  {method:>6}: {r['spp']:5.1f} spp  {r['ns_per_sample']:6.2f} ns/sample  "
                    f"gather {r['gather_ns_per_sample']:5.2f} ns  {r['ratio_to_gather']:5.2f}x"
                )


if __name__ == "__main__":
    main()

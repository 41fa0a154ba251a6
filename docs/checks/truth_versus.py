"""One method over the demo's rendered passes against Cycles ground truth, to compare revisions.

Runs ``METHOD`` (default ``as_ccv``, default parameters, the compiled backend)
over every pass EXR of each scene ``make demo`` rendered
(``out/demo/SCENE/passes``, ground truth in ``out/demo/SCENE/ground_truth``)
with :func:`core.run.run_folder` into ``OUT/SCENE``, and prints per scene the
mean spp and the mean PSNR against Cycles ground truth over the ground-truth
frames after the first (warm history), the same rule as the demo report's
quality table. ``--json`` saves them; ``--compare A.json B.json`` prints, per
scene, the frames whose spp differ and the per-frame PSNR differences. Its
figures use default parameters, not the demo's configuration, so they need
not equal the report's; they compare revisions. Another revision runs through
a worktree (see ``steady_frame.py``)::

    PYTHONPATH=/tmp/revpkg .venv/bin/python docs/checks/truth_versus.py /tmp/tv/rev --json /tmp/tv/rev.json
    .venv/bin/python docs/checks/truth_versus.py /tmp/tv/this --json /tmp/tv/this.json
    .venv/bin/python docs/checks/truth_versus.py --compare /tmp/tv/rev.json /tmp/tv/this.json
"""

import argparse
import json
from pathlib import Path

import numpy as np

import cvsss
from cvsss.core.method import MethodOptions
from cvsss.core.params import SSSParams
from cvsss.core.run import RunSpec, run_folder

SCENES = ("flash", "regular", "boids")


def run(out: Path, demo: Path, method: str) -> dict:
    result = {}
    for scene in SCENES:
        folder = demo / scene
        rows = run_folder(
            folder / "passes",
            out / scene,
            RunSpec((method,), SSSParams(backend="numba"), MethodOptions()),
            existing="overwrite",
            ground_truth=folder / "ground_truth",
        )
        mine = [r for r in rows if r["method"] == method]
        gt = [float(r["psnr_gt_db"]) for r in mine if r.get("psnr_gt_db") not in (None, "")][1:]
        spp = [float(r["spp"]) for r in mine]
        result[scene] = {"frames": len(mine), "spp": spp, "psnr_gt_warm": gt}
        print(
            f"{scene}: {len(mine)} frames, mean {np.mean(spp):.3f} spp, PSNR vs Cycles GT "
            f"(warm frames) {np.mean(gt):.3f} dB {[round(g, 3) for g in gt]}"
        )
    return result


def compare(a: dict, b: dict) -> None:
    for scene in SCENES:
        x, y = a[scene], b[scene]
        frames = [i for i, (s, t) in enumerate(zip(x["spp"], y["spp"])) if s != t]
        diffs = [round(t - s, 4) for s, t in zip(x["psnr_gt_warm"], y["psnr_gt_warm"])]
        print(f"{scene}: frames with other spp {frames}, PSNR differences (dB) {diffs}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("out", nargs="?", help="output folder of the runs")
    ap.add_argument("--demo", type=Path, default=Path("out/demo"))
    ap.add_argument("--method", default="as_ccv")
    ap.add_argument("--json", type=Path)
    ap.add_argument("--compare", nargs=2, type=Path)
    a = ap.parse_args()
    if a.compare:
        compare(*(json.loads(p.read_text()) for p in a.compare))
        return
    if a.out is None:
        ap.error("give an output folder, or --compare A.json B.json")
    print(cvsss.__file__)
    result = run(Path(a.out), a.demo, a.method)
    if a.json:
        a.json.write_text(json.dumps(result))


if __name__ == "__main__":
    main()

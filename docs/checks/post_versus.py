"""``cvsss post`` end to end, this checkout against a revision: wall and CPU time.

Writes the first ``--frames`` frames of the bench's flash sequence
(``core.synthetic``: a still scene whose light flashes) as pass EXRs at each
size, checks REV out in a temporary git worktree, and runs ``cvsss post
PASSES --method METHOD`` in a fresh process with each, alternately
``--rounds`` times (after one untimed run each, which fills the worktree's
numba cache), so that a slow spell of a shared machine hits both. Prints per
size and revision the wall time of the whole command (minimum and median), its
CPU time (user + system, minimum) and whether both wrote the same pixels, the
same checkpoint arrays and the same metric rows (timings aside). The command
reads the passes, processes, writes the result EXRs, the checkpoints and
``metrics.csv``: what a user waits for. Run from the repo root:

    .venv/bin/python docs/checks/post_versus.py REV [WxH ...] [--frames N] [--rounds N]
"""

import argparse
import csv
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from cvsss.core.io import checkpoint
from cvsss.core.io.exr import read_result, write_passes
from cvsss.core.synthetic import scene_frame

TIMING = {"sampling_ms", "frame_ms"}


def post(package: Path | None, passes: Path, out: Path, method: str) -> tuple[float, float]:
    """Wall and CPU seconds of one ``cvsss post`` run in a fresh process."""
    env = dict(os.environ)
    env.pop("PYTHONPATH", None)
    if package is not None:
        env["PYTHONPATH"] = str(package)  # the revision's cvsss before the editable install
    code = "import sys; from cvsss.sss_addon.cli.main import main; sys.exit(main(sys.argv[1:]))"
    argv = ["post", str(passes), "--method", method, "--out", str(out), "--quiet", "--overwrite"]
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, "-c", code, *argv], env=env, check=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def rows(path: Path) -> list[dict]:
    with open(path) as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def same_output(a: Path, b: Path, method: str) -> bool:
    """The same pixels, checkpoint arrays and untimed metric rows."""
    names = sorted(p.name for p in (a / method).glob("*.exr"))
    if names != sorted(p.name for p in (b / method).glob("*.exr")):
        return False
    for name in names:
        x, y = read_result(a / method / name), read_result(b / method / name)
        if set(x) != set(y) or not all(
            np.array_equal(x[k], y[k], equal_nan=True) for k in x if k != "header"
        ):
            return False
    _, ax = checkpoint.load(a / method / ".checkpoint.npz")
    _, ay = checkpoint.load(b / method / ".checkpoint.npz")
    if ax.keys() != ay.keys() or not all(np.array_equal(ax[k], ay[k]) for k in ax):
        return False
    return rows(a / "metrics.csv") == rows(b / "metrics.csv")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rev")
    ap.add_argument("sizes", nargs="*", default=["1280x720", "1920x1080"])
    ap.add_argument("--frames", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--method", default="as_ccv")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        tree = tmp / "tree"
        subprocess.run(["git", "worktree", "add", "-q", "--detach", str(tree), a.rev], check=True)
        try:
            (tmp / "pkg").mkdir()
            (tmp / "pkg" / "cvsss").symlink_to(tree)
            for size in a.sizes:
                w, h = (int(v) for v in size.split("x"))
                passes = tmp / f"passes_{size}"
                for n in range(1, a.frames + 1):
                    write_passes(passes / f"{n:04d}.exr", scene_frame("flash", n, w, h))
                runs = {a.rev: tmp / "pkg", "this checkout": None}
                outs = {name: tmp / f"out_{size}_{i}" for i, name in enumerate(runs)}
                times: dict[str, list[tuple[float, float]]] = {name: [] for name in runs}
                for r in range(a.rounds + 1):
                    for name, package in runs.items():
                        t = post(package, passes, outs[name], a.method)
                        if r:  # the first round fills the numba caches
                            times[name].append(t)
                same = same_output(*outs.values(), a.method)
                print(f"{size}, {a.frames} frames, {a.method} (s):")
                for name, ts in times.items():
                    walls, cpus = [t[0] for t in ts], [t[1] for t in ts]
                    print(
                        f"  {name:>14}: wall min {min(walls):6.2f}  median {np.median(walls):6.2f}"
                        f"  | CPU min {min(cpus):6.2f}"
                    )
                print(f"  same pixels, checkpoints and metric rows: {same}")
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(tree)], check=True)


if __name__ == "__main__":
    main()

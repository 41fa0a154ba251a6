"""The first render on a machine: the numba passes compiled in the background while Blender
renders, before the first post-process, or inside it.

Renders the flash demo scene (``demo_blend``) through ``render_sequence`` (what
``cvsss render`` and the Render Sequence operator run) with ``as_ccv`` on the
numba backend, each time in a fresh process with an empty ``NUMBA_CACHE_DIR``,
so that every run compiles the kernels as a fresh install does. Variants:

``background``
    as shipped: the job starts ``sss_addon.precompile.start_background`` (a
    low-priority process compiles every kernel while Cycles renders the first
    frame) and ``ensure_compiled`` waits for it before the first post-process;
``foreground``
    ``CVSSS_BACKGROUND_COMPILE=0``: ``ensure_compiled`` compiles the kernels the frame
    size needs before the first post-process, in this process;
``inline``
    neither: the first post-process compiles what it calls, silently;
``loaded`` (with ``--idle S``)
    the UI's case: the background compile starts as when the add-on
    registers in Blender's UI (every kernel), S seconds pass (the user at
    work), then the job runs; only the job is timed.

Runs alternate between the variants (a slow spell of a shared machine hits
all). ``--threads N`` renders with N Cycles threads (a stand-in for a GPU
render that leaves CPU cores free; default: all). Prints each run's wall time
of the whole ``render_sequence`` call and of its first frame, and the lines
the job logs about the compile. Run from the repo root:

    .venv/bin/python docs/checks/first_use.py [--res 320x180] [--samples 64] [--frames 2] [--rounds 1] [--threads 0] [--idle 0]
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

VARIANTS = ("background", "foreground", "inline")


def child(
    variant: str, res: str, samples: int, frames: int, threads: int, idle: float, out: Path
) -> None:
    import bpy

    import cvsss
    from cvsss.core.methods import METHODS
    from cvsss.sss_addon import precompile
    from cvsss.sss_addon.blender.standalone import render_sequence

    cvsss.register()
    if variant == "loaded":  # what register() does in the UI (bpy here is background)
        precompile.start_background("auto", tuple(METHODS))
        time.sleep(idle)
    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    bpy.ops.sss.build_demo(scene_name="flash")
    scene = bpy.context.scene
    w, h = (int(v) for v in res.split("x"))
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    scene.cycles.samples = samples
    if threads:
        scene.render.threads_mode, scene.render.threads = "FIXED", threads
    if variant == "inline":
        precompile.ensure_compiled = lambda requested, methods, pixels, log: None
    lines: list[tuple[float, str]] = []
    began = time.perf_counter()

    def log(text: str) -> None:
        lines.append((time.perf_counter() - began, text))

    render_sequence(
        scene,
        (1, frames),
        out,
        ["as_ccv"],
        {"backend": "numba"},
        "CYCLES",
        True,
        log,
        reference=False,
        ground_truth=False,
    )
    wall = time.perf_counter() - began
    first = next(t for t, text in lines if " as_ccv:" in text)
    compiled = [text for _, text in lines if "numba passes" in text]
    print("REPORT " + json.dumps({"wall": wall, "first": first, "compiled": compiled}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", default="320x180")
    ap.add_argument("--samples", type=int, default=64)
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--threads", type=int, default=0)
    ap.add_argument("--idle", type=float, default=0.0)
    ap.add_argument("--child", choices=(*VARIANTS, "loaded"), help=argparse.SUPPRESS)
    ap.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.child, a.res, a.samples, a.frames, a.threads, a.idle, a.out)
        return
    print(
        f"flash demo, {a.res}, {a.samples} Cycles samples, {a.frames} frame(s), "
        f"{a.threads or 'all'} Cycles thread(s), as_ccv on numba"
    )
    for _ in range(a.rounds):
        for variant in (*VARIANTS, "loaded") if a.idle else VARIANTS:
            with tempfile.TemporaryDirectory() as tmp:
                env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "numba"))
                background = variant in ("background", "loaded")
                env["CVSSS_BACKGROUND_COMPILE"] = "1" if background else "0"
                run = subprocess.run(
                    [sys.executable, __file__, "--child", variant, "--res", a.res,
                     "--samples", str(a.samples), "--frames", str(a.frames),
                     "--threads", str(a.threads), "--idle", str(a.idle),
                     "--out", str(Path(tmp) / "out")],
                    capture_output=True, text=True, env=env, check=False,
                )  # fmt: skip
                if run.returncode:
                    sys.exit(run.stdout[-2000:] + run.stderr[-2000:])
                line = next(x for x in run.stdout.splitlines() if x.startswith("REPORT "))
                report = json.loads(line.removeprefix("REPORT "))
                print(
                    f"  {variant:>10}: whole call {report['wall']:6.1f} s, first frame done at "
                    f"{report['first']:6.1f} s  {' '.join(report['compiled'])}"
                )


if __name__ == "__main__":
    main()

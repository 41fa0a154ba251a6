"""The first F12 with Apply on Render on a fresh install, against a plain F12.

For each extension zip given (``make extension``'s Linux x64 zip, with or without the
numba passes it ships), in a fresh process with an empty Blender user folder and an
empty per-user cache (as a machine that never ran the add-on): installs the zip as
Blender's *Install from Disk* does, builds the flash demo scene, then times
``bpy.ops.render.render()`` (F12, a still shown, not written) in this order:

``plain``      Apply on Render off (Blender's first render of the process)
``plain``      again
``apply 1``    Apply on Render on: the first use of the add-on's post-process
``apply 2``    again (the kernels are loaded in this process now)
``plain``      once more

and prints every time, the first and second Apply on Render less the median of the
last two plain renders, numba's cache hits and misses in Blender's process, and the
add-on's lines about the kernels. ``--sessions 2`` then starts Blender again on the
same user folder (the add-on installed, its caches as the first session left them)
and times the same renders. Zips alternate within a round (a slow spell of a shared
machine hits all). Run from the repo root:

    .venv/bin/python docs/checks/first_f12.py ZIP [ZIP ...] [--res 320x180] [--samples 16]
        [--warmup 0] [--rounds 1] [--sessions 1]
"""

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = "first_f12"


def child(zip_path: str, work: Path, res: str, samples: int, warmup: int, again: bool) -> None:
    import bpy

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    prefs = bpy.context.preferences
    prefs.extensions.repos.new(
        name="first f12", module=REPO, custom_directory=str(work / "repo"), source="USER"
    )
    began = time.perf_counter()
    if again:  # the next session: installed already, Blender enables it when it starts
        installed = bpy.ops.preferences.addon_enable(module=f"bl_ext.{REPO}.cvsss")
    else:
        installed = bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo=REPO, enable_on_install=True
        )
    install_s = time.perf_counter() - began
    # The zip's wheels (numba, llvmlite) first, as in a Blender that has no numba of its own.
    sys.path[:0] = [p for p in sys.path if os.path.join("extensions", ".local") in p]
    bpy.ops.sss.build_demo(scene_name="flash")
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    w, h = (int(v) for v in res.split("x"))
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    scene.cycles.samples = samples
    scene.render.filepath = str(work / "render" / "f_")
    s = scene.sss_settings
    s.output_dir = str(work / "out")
    s.warmup_frames = warmup
    scene.frame_set(1)
    times = []
    for name, apply in (
        ("plain", False),
        ("plain", False),
        ("apply 1", True),
        ("apply 2", True),
        ("plain", False),
    ):
        s.apply_on_render = apply
        t0 = time.perf_counter()
        result = bpy.ops.render.render()
        times.append([name, time.perf_counter() - t0, sorted(result)])
        sys.stdout.flush()
    package = f"bl_ext.{REPO}.cvsss"
    kernels = [
        module
        for name, module in sorted(sys.modules.items())
        if name.startswith(package + ".core.backends.numba.")
    ]
    hits = misses = 0
    missed = []
    if kernels:
        import numba

        for module in kernels:
            for value in vars(module).values():
                if isinstance(value, numba.core.registry.CPUDispatcher):
                    hits += sum(value.stats.cache_hits.values())
                    m = sum(value.stats.cache_misses.values())
                    misses += m
                    if m:
                        missed.append(value.py_func.__name__)
    precompile = sys.modules[package + ".sss_addon.precompile"]
    process = precompile._background.get("process")
    shipped = sys.modules.get(package + ".core.backends.shipped")  # None: no such module
    report = {
        "install": sorted(installed),
        "install_s": install_s,
        "times": times,
        "hits": hits,
        "misses": misses,
        "missed": sorted(set(missed)),
        "background": process is not None,
        "shipped": getattr(shipped, "attached", None),
        "numba": getattr(sys.modules.get("numba"), "__file__", None),
        "cache_location": str(sys.modules[package + ".core.backends.cache"].location()),
    }
    if process is not None and process.poll() is None:
        process.terminate()
    print("REPORT " + json.dumps(report), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("zips", nargs="+", type=Path)
    ap.add_argument("--res", default="320x180")
    ap.add_argument("--samples", type=int, default=16)
    ap.add_argument("--warmup", type=int, default=0, help="Apply on Render's warm-up frames")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument(
        "--sessions", type=int, default=1, help="Blender sessions per install (2: a restart)"
    )
    ap.add_argument("--child", help=argparse.SUPPRESS)
    ap.add_argument("--again", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--work", type=Path, help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.child:
        child(a.child, a.work, a.res, a.samples, a.warmup, a.again)
        return
    print(f"flash demo, {a.res}, {a.samples} Cycles samples, warm-up {a.warmup} frame(s), F12")
    for _ in range(a.rounds):
        for path in a.zips:
            with tempfile.TemporaryDirectory() as tmp:
                for session in range(a.sessions):
                    _session(path, Path(tmp), a, again=session > 0)


def _session(path: Path, work: Path, a, again: bool) -> None:
    """One Blender session (a process) in the user folder ``work``; prints its line."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_")}
    env.pop("CVSSS_BACKGROUND_COMPILE", None)  # the add-on's own behaviour
    env.update(
        BLENDER_USER_RESOURCES=str(work / "user"),
        XDG_CACHE_HOME=str(work / "cache"),  # core.mc.backend.cache_dir
        LOCALAPPDATA=str(work / "cache"),
        HOME=str(work / "home"),
    )
    run = subprocess.run(
        [sys.executable, __file__, str(path.resolve()), "--child", str(path.resolve()),
         "--work", str(work), "--res", a.res, "--samples", str(a.samples),
         "--warmup", str(a.warmup), *(["--again"] if again else [])],
        capture_output=True, text=True, env=env, check=False, cwd=work,
    )  # fmt: skip
    line = [x for x in run.stdout.splitlines() if x.startswith("REPORT ")]
    if run.returncode or not line:
        sys.exit(run.stdout[-3000:] + run.stderr[-3000:])
    r = json.loads(line[0].removeprefix("REPORT "))
    plain = statistics.median(t for n, t, _ in r["times"][3:] + r["times"][1:2] if n == "plain")
    first, second = r["times"][2][1], r["times"][3][1]
    said = [x for x in run.stdout.splitlines() if "numba passes" in x]
    print(
        f"  {path.name}{' (restarted)' if again else ''}: "
        + ", ".join(f"{n} {t:.2f}" for n, t, _ in r["times"])
        + f" s; apply 1 - plain {first - plain:+.2f} s, apply 2 - plain "
        f"{second - plain:+.2f} s; numba hits {r['hits']} misses {r['misses']} "
        f"{r['missed']}; shipped {r['shipped']}; background compile {r['background']}"
    )
    for x in said:
        print(f"      {x}")


if __name__ == "__main__":
    main()

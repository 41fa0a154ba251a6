"""Compile the numba passes for the extension to ship, and put them into its zip.

``make extension`` runs both steps (the loading side is core/backends/shipped.py)::

    .venv/bin/python tools/ship_passes.py build . build/shipped_passes [CPU ...]
    .venv/bin/python tools/ship_passes.py add build/shipped_passes dist/cvsss-*.zip

``build`` compiles every pass of the add-on at the given root once per CPU model
(default: every model of ``shipped.targets()`` for this machine's architecture) into
the folder; ``add`` puts those builds into the zip made for this platform. The
process work lives here, not in core, which stays pure computation.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

from cvsss.core.backends import shipped
from cvsss.core.backends.shipped import BUILD_PACKAGE, FOLDER, MANIFEST, PASSES, targets


def build(root: Path, out: Path, cpu: str) -> dict:
    """Compile every pass of the add-on at ``root`` for CPU model ``cpu`` and write that
    shipped build to ``out``/``cpu``; its manifest.

    The compile runs in a process of its own (numba reads its CPU settings when it
    is imported): ``sss_addon/compile_passes.py``, which imports the add-on as
    :data:`BUILD_PACKAGE`, with an empty cache and the shipped passes off.
    """
    requires = targets()[cpu]
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(
            os.environ,
            NUMBA_CACHE_DIR=tmp,
            NUMBA_CPU_NAME=cpu,
            NUMBA_CPU_FEATURES="",  # the model's own features, none of this machine's
            CVSSS_SHIPPED_PASSES="0",
        )
        script = root / "sss_addon" / "compile_passes.py"
        run = subprocess.run(
            [sys.executable, str(script), str(root), BUILD_PACKAGE],
            env=env,
            capture_output=True,
            text=True,
            check=False,
        )
        if run.returncode or '"seconds"' not in run.stdout:
            raise RuntimeError(f"compiling the passes failed: {run.stdout}{run.stderr}")
        (folder,) = (p for p in Path(tmp).iterdir() if p.is_dir())
        return shipped.write_build(folder, out / cpu, root, cpu, requires)


def add(folder: Path, zips: list[Path]) -> Path:
    """Put the shipped builds in ``folder`` into the one of the extension ``zips`` built
    for their platform (``blender_ext.py build --split-platforms``); that zip's path."""
    builds = sorted(p for p in folder.iterdir() if (p / MANIFEST).is_file())
    wanted = {shipped.blender_platform(json.loads((p / MANIFEST).read_text())) for p in builds}
    if len(wanted) != 1:
        raise RuntimeError(f"{folder}: builds for {sorted(wanted) or 'no platform'}")
    (wanted,) = wanted
    for path in zips:
        with zipfile.ZipFile(path) as z:
            built = tomllib.loads(z.read("blender_manifest.toml").decode())
            names = set(z.namelist())
        if built.get("build", {}).get("generated", {}).get("platforms") != [wanted]:
            continue
        if f"{PASSES.replace('.', '/')}/__init__.py" not in names:
            raise RuntimeError(f"{path.name} holds no {PASSES}")
        base = "/".join([*PASSES.split(".")[:-1], FOLDER.name])
        with zipfile.ZipFile(path, "a", zipfile.ZIP_DEFLATED, compresslevel=9) as z:
            for build_ in builds:  # each manifest after its files: it vouches for them
                files = sorted(build_.iterdir(), key=lambda p: p.name == MANIFEST)
                for file in files:
                    z.write(file, f"{base}/{build_.name}/{file.name}")
        return path
    raise RuntimeError(f"no zip for {wanted} among {[p.name for p in zips]}")


def main(argv: list[str]) -> None:
    """``build <add-on root> <folder> [<cpu>...]``: compile the shipped builds (default:
    every model of :func:`targets`) into ``folder``; ``add <folder> <zip>...``: put them
    into the zip of their platform."""
    if argv[:1] == ["build"] and len(argv) >= 3:
        for cpu in argv[3:] or targets():
            print(json.dumps(build(Path(argv[1]).resolve(), Path(argv[2]), cpu)), flush=True)
    elif argv[:1] == ["add"] and len(argv) >= 3:
        print(add(Path(argv[1]), [Path(a) for a in argv[2:]]))
    else:
        sys.exit(main.__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])

"""``cvsss render --workers N | --scheduler ADDR [--chunk 8]``: passes in frame chunks on Dask.

Pass rendering is independent per frame. The range is cut into chunks of
``--chunk`` consecutive frames; each chunk is one Dask task that runs one
Blender process (``python -m cvsss.sss_addon.cli.main render BLEND --frames
A-B --out OUT --passes-only …``), so every chunk starts from the saved .blend
with its own bpy state. Every chunk writes into the one ``OUT/passes/``
folder; pass files are written atomically and reused when they exist, so a
chunk that runs again (a worker died, the command was rerun) renders only the
frames still missing. On Linux the Blender process dies with its worker
(``setpriv --pdeathsig``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path

#: Lines of a failed chunk's output quoted in the error.
TAIL_LINES = 20


class PassRenderError(RuntimeError):
    """A chunk's Blender process failed."""


def chunks(frames: Sequence[int], size: int) -> list[tuple[int, int]]:
    """Consecutive runs of at most ``size`` frames, as inclusive (first, last) pairs.

    >>> chunks([1, 2, 3, 4, 5, 9, 10], 2)
    [(1, 2), (3, 4), (5, 5), (9, 10)]
    """
    if size < 1:
        raise ValueError(f"chunk size must be >= 1, got {size}")
    out: list[tuple[int, int]] = []
    for f in frames:
        if out and f == out[-1][1] + 1 and f - out[-1][0] < size:
            out[-1] = (out[-1][0], f)
        else:
            out.append((f, f))
    return out


def chunk_argv(blend: Path, out: Path, first: int, last: int, job, range_start: int) -> list[str]:
    """The command that renders the passes of frames ``first``–``last`` of ``job``.

    The job's resolved settings are passed on, so the chunk renders exactly what
    the whole range would.
    """
    argv = [
        sys.executable,
        "-m",
        "cvsss.sss_addon.cli.main",
        "render",
        os.fspath(blend),
        "--frames",
        f"{first}-{last}",
        "--out",
        os.fspath(out),
        "--passes-only",
        "--range-start",
        str(range_start),
        "--engine",
        job.engine,
        "--denoise-passes" if job.denoise_passes else "--no-denoise-passes",
        "--denoise" if job.denoise is not None else "--no-denoise",
        "--thin-walks",
        job.thin_walks.lower(),
        "--quiet",
    ]
    if job.ground_truth:
        argv += [
            "--ground-truth",
            "--ground-truth-spp",
            str(job.ground_truth_samples),
            "--ground-truth-every",
            str(job.ground_truth_every),
            "--ground-truth-method",
            job.ground_truth_method.lower(),
        ]
    else:
        argv.append("--no-ground-truth")
    if job.overwrite:
        argv.append("--overwrite")
    if job.autoexec is not None:
        argv.append("--enable-autoexec" if job.autoexec else "--disable-autoexec")
    return argv


def _with_parent_death(argv: list[str]) -> list[str]:
    """``argv`` under util-linux ``setpriv --pdeathsig KILL`` where there is one: a
    Blender process whose worker was killed stops too, rather than rendering on
    beside the chunk's re-run."""
    setpriv = shutil.which("setpriv") if sys.platform.startswith("linux") else None
    return [setpriv, "--pdeathsig", "KILL", *argv] if setpriv else argv


def render_chunk(argv: list[str]) -> dict:
    """Run one chunk's Blender process (a Dask task); raises with its output's tail."""
    began = time.perf_counter()
    proc = subprocess.run(_with_parent_death(argv), capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        tail = (proc.stdout + proc.stderr).strip().splitlines()[-TAIL_LINES:]
        frames = argv[argv.index("--frames") + 1]
        raise PassRenderError(
            f"pass render of frames {frames} failed (exit {proc.returncode}):\n" + "\n".join(tail)
        )
    return {"argv": argv, "seconds": time.perf_counter() - began}


def render_chunks(
    executor,
    blend: str | os.PathLike,
    job,
    chunk: int,
    log: Callable[[str], None] | None = None,
) -> None:
    """Render the passes of ``job`` (a validated render Job) in chunks on the cluster.

    Raises
    ------
    PassRenderError
        A chunk's Blender process failed (its output's last lines are quoted).
    """
    blend = Path(blend).expanduser().absolute()
    runs = chunks(job.frames, chunk)
    start = job.frames[0]
    handles = {
        executor.submit(render_chunk, chunk_argv(blend, job.out, a, b, job, start)): (a, b)
        for a, b in runs
    }
    if log:
        log(f"passes: {len(job.frames)} frame(s) in {len(runs)} chunk(s) of at most {chunk}")
    began = time.perf_counter()
    for done, handle in enumerate(executor.as_completed(list(handles)), 1):
        report = handle.result()
        if log:
            a, b = handles[handle]
            log(
                f"passes: chunk {done}/{len(runs)} (frames {a}-{b}) done in "
                f"{report['seconds']:.1f} s [elapsed {time.perf_counter() - began:.0f} s]"
            )

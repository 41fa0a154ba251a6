"""``cvsss post --workers N | --scheduler tcp://HOST:PORT [--tile 256]``: the tiled post on Dask.

The client (this process) reads each frame's passes, and per frame computes
the halo (core.tiling.halo_px), crops the tile windows and scatters them once
for every method; each method's tiles run on the workers and take the
previous frame's tile states straight from the workers that hold them. The
client gathers the tile results, assembles the whole frame (core.tiling) and
writes it, the metric rows and the checkpoints exactly as ``cvsss post``
does (core.run.SequenceRun), so the outputs are the same bit for bit, the
run resumes with ``--resume`` (with or without workers) and a frame whose work
a dying worker took with it is submitted again.
"""

from __future__ import annotations

import os
from collections.abc import Callable

from ...core.method import MethodOptions
from ...core.params import SSSParams
from ...core.run import RunSpec, run_folder
from ...core.tiling import TiledProcessor, TileSession
from ..progress import printer
from .cluster import open_cluster

#: Default tile side in pixels (``--tile``).
DEFAULT_TILE = 256


def tiled_processors(executor, tile: int, halo: int | None = None, log=None) -> Callable:
    """A ``processors`` factory for core.run whose methods share one TileSession."""
    sessions: dict = {}

    def make(name: str, params: SSSParams, options: MethodOptions) -> TiledProcessor:
        key = (params, options)
        if key not in sessions:
            sessions[key] = TileSession(executor, tile, params, options, halo=halo, log=log)
        return TiledProcessor(name, params, options, sessions[key])

    make.sessions = sessions  # the bench reads their statistics
    return make


def post_distributed(
    passes: str | os.PathLike,
    out: str | os.PathLike,
    spec: RunSpec,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    tile: int = DEFAULT_TILE,
    log: Callable[[str], None] | None = None,
    wrap: Callable | None = None,
    **kwargs,
) -> list[dict]:
    """:func:`core.run.run_folder` with every method's frames processed as tiles on Dask.

    Parameters
    ----------
    passes, out, spec : as run_folder
    workers : local cluster of this many worker processes on 127.0.0.1, or
    scheduler : address of a running Dask scheduler (``tcp://HOST:PORT``)
    tile : tile side in pixels
    log : progress printer
    wrap : callable processors -> processors, optional (e.g. the finished frames
        denoised in this process: ``cvsss post --denoise``)
    kwargs : passed to run_folder (existing, allow_gaps, warn, ground_truth, submit)
    """
    warn = kwargs.get("warn")
    with open_cluster(workers, scheduler, log=log) as executor:
        make = tiled_processors(executor, tile, log=warn or log)
        if wrap is not None:
            make = wrap(make)
        return run_folder(
            passes, out, spec, log=printer(log), processors=make, lookahead=True, **kwargs
        )

"""The moving scene and the whole-image / tiled runs the tiling tests and the backend
tests share (imported as ``tiling_helpers``: pytest puts tests/core on the path)."""

from __future__ import annotations

import dataclasses

import numpy as np

from cvsss.core import synthetic
from cvsss.core.frame import Frame
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.tiling import InlineExecutor, TiledProcessor, TileSession

TIMINGS = ("sampling_ms", "update_ms", "total_ms")
W, H = 96, 64
STEP = (3, 2)  # content moves this far (x, y) per frame


def moving_frame(number: int, width: int = W, height: int = H, step=STEP) -> Frame:
    """The moving flash scene with a band of pixels whose motion points off screen."""
    return synthetic.moving_frame(number, width, height, step, offscreen_rows=4)


FRAMES = [moving_frame(n) for n in (1, 2, 3)]
FAST = SSSParams(reference_spp=48, fixed_spp=24, beta_max=32)


def run_whole(name, params, options, frames):
    proc = make_processor(name, params, options)
    return [proc.process(f) for f in frames], proc.state()


def run_tiled(name, params, options, frames, tile=24, halo=None):
    session = TileSession(InlineExecutor(), tile, params, options, halo=halo)
    proc = TiledProcessor(name, params, options, session)
    out = []
    for f in frames:
        proc.start(f)
        out.append(proc.process(f))
    return out, proc.state(), session


def differences(a, b) -> list[str]:
    """Names of the result fields that differ (timings aside)."""
    bad = []
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name in TIMINGS:
            continue
        if isinstance(x, np.ndarray):
            if x.dtype != y.dtype or x.shape != y.shape or not np.array_equal(x, y):
                bad.append(f.name)
        elif x != y:
            bad.append(f.name)
    return bad


def same_state(a: dict, b: dict) -> bool:
    return a.keys() == b.keys() and all(
        a[k].dtype == b[k].dtype and np.array_equal(a[k], b[k]) for k in a
    )

"""The 1024-spp reference of a sequence, computed once per affine lighting family."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence

import numpy as np

from ..frame import Frame
from ..methods import make_processor
from ..params import SSSParams
from .config import Log, progress


# -- reference ---------------------------------------------------------------------
def _same(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    return (a is None and b is None) or (
        a is not None and b is not None and np.array_equal(a, b, equal_nan=True)
    )


def _affine_coefficients(frames: Sequence[Frame], tol: float = 1e-5):
    """``(a, b, s)`` with ``B_t = B_a + s_t (B_b − B_a)`` for every frame, or None.

    Also requires the same geometry, albedo, materials and Subsurface Weight in
    every frame and the same relation for Combined.
    """
    if len(frames) < 3:
        return None
    f0 = frames[0]
    for f in frames[1:]:
        if (
            f.shape != f0.shape
            or f.camera != f0.camera
            or f.materials != f0.materials
            or f.motion is not None
            or not np.array_equal(f.depth, f0.depth)
            or not np.array_equal(f.material, f0.material)
            or not np.array_equal(f.albedo, f0.albedo)
            or not _same(f.sss_weight, f0.sss_weight)
        ):
            return None
    total = np.array([float(f.lighting.sum(dtype=np.float64)) for f in frames])
    a, b = int(np.argmin(total)), int(np.argmax(total))
    base = frames[a].lighting.astype(np.float64)
    dirn = frames[b].lighting.astype(np.float64) - base
    cbase = frames[a].combined.astype(np.float64)
    cdir = frames[b].combined.astype(np.float64) - cbase
    norm = float(np.sum(dirn * dirn))
    if norm == 0.0:
        return None
    scale = max(float(np.abs(frames[b].lighting).max()), 1e-30)
    cscale = max(float(np.abs(frames[b].combined).max()), 1e-30)
    s = []
    for f in frames:
        st = float(np.sum((f.lighting - base) * dirn)) / norm
        if np.abs(f.lighting - (base + st * dirn)).max() > tol * scale:
            return None
        if np.abs(f.combined - (cbase + st * cdir)).max() > tol * cscale:
            return None
        s.append(st)
    return a, b, np.array(s)


def reference_composites(
    frames: Sequence[Frame], params: SSSParams, log: Log = None, start: float | None = None
) -> tuple[Callable[[int], np.ndarray], dict]:
    """The reference composite of each frame (see module docstring) and how it was made.

    Returns
    -------
    ref : callable i -> (H, W, 3) float32 composite of ``frames[i]``
    info : dict (``mode``: ``"affine"`` or ``"per_frame"``, ``spp``, ``seconds``)
    """
    t0 = time.perf_counter()
    proc = make_processor("reference", params)
    affine = _affine_coefficients(frames)
    if affine is not None:
        a, b, s = affine
        ra = proc.process(dataclasses.replace(frames[a], number=0)).composite
        rb = proc.process(dataclasses.replace(frames[b], number=0)).composite
        diff = rb - ra

        def ref(i: int) -> np.ndarray:
            return np.maximum(ra + np.float32(s[i]) * diff, 0.0)

        info = {"mode": "affine", "basis_frames": [frames[a].number, frames[b].number]}
    else:
        comps = [proc.process(f).composite for f in frames]
        ref = comps.__getitem__
        info = {"mode": "per_frame"}
    info.update(spp=params.reference_spp, seconds=time.perf_counter() - t0)
    progress(
        log,
        start,
        f"reference ({info['mode']}, {params.reference_spp} spp) in {info['seconds']:.1f} s",
    )
    return ref, info

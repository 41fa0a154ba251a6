"""The roofline the sampling step is held against: random local gathers from the
lighting image, as many as the step's samples (``gather_ns_per_sample``)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np


def best_of(fn: Callable[[], Any], repeats: int = 3) -> float:
    best = math.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def gather_indices(counts: np.ndarray, seed: int = 0, radius: int = 16) -> np.ndarray:
    """Flat pixel indices of ``counts.sum()`` random local gathers (the roofline's reads).

    Parameters
    ----------
    counts : (H, W) int, samples per pixel
    seed : int, offset stream
    radius : int, offsets are uniform in ``[−radius, radius]²`` pixels, clipped
        to the image

    Returns
    -------
    (counts.sum(),) int64, pixel ``p`` contributes ``counts[p]`` consecutive reads.
    """
    h, w = counts.shape
    c = counts.reshape(-1)
    pixels = np.flatnonzero(c > 0)
    reps = c[pixels]
    y, x = np.divmod(pixels, w)
    # int32 coordinates, in place: the bench draws these for every timed frame
    # (3.5x faster than int64 arrays per sample, 0.3 s for 20 M samples).
    off = np.random.default_rng(seed).integers(
        -radius, radius + 1, (2, int(reps.sum())), dtype=np.int32
    )
    qy = np.repeat(y.astype(np.int32), reps)
    qy += off[0]
    np.clip(qy, 0, h - 1, out=qy)
    qx = np.repeat(x.astype(np.int32), reps)
    qx += off[1]
    np.clip(qx, 0, w - 1, out=qx)
    q = qy.astype(np.int64)
    q *= w
    q += qx
    return q


def gather_ns_per_sample(
    lighting: np.ndarray, counts: np.ndarray, seed: int = 0, radius: int = 16, repeats: int = 5
) -> float:
    """Cost of ``counts.sum()`` random local gathers from ``lighting`` with ``np.take``.

    Parameters
    ----------
    lighting : (H, W, 3) float32
    counts : (H, W) int, samples per pixel (the sampling step's counts)
    radius : int, offsets are uniform in ``[−radius, radius]²`` pixels

    Returns
    -------
    float, ns per gathered sample (best of ``repeats``); nan when no samples.
    """
    q = gather_indices(counts, seed, radius)
    if q.size == 0:
        return math.nan
    light = np.ascontiguousarray(lighting.reshape(-1, 3), dtype=np.float32)
    return best_of(lambda: np.take(light, q, axis=0), repeats) * 1e9 / q.size

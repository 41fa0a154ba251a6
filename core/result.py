"""What a method returns for a frame, and the one composite every method uses.

:class:`FrameResult` holds the shaded lighting, the composite and the per-pixel
maps of one processed frame; :func:`assemble` builds it from the per-SSS-pixel
arrays of any method (Monte Carlo or separable), so the composite
``Combined − albedo·B + albedo·L`` is written in one place.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .backends.twins import compiled_module, compiled_side, numpy_side
from .frame import Frame, compact_slots, slot_keys
from .geometry import Geometry, pixel_weights, take_rows

_BIG = float(np.finfo(np.float32).max)


@dataclass
class FrameResult:
    """Output of one processed frame. Images are (H, W[, 3]), EXR row order.

    Attributes
    ----------
    number : int, frame number
    method : str
    sss : (H, W, 3) float32, L: subsurface-scattered lighting (B off SSS pixels), linear
    composite : (H, W, 3) float32, ``Combined − albedo·B + albedo·L`` on SSS pixels, linear
    counts : (H, W) int32, distant samples per pixel (separable: reads per pixel)
    alpha : (H, W) float32, CV coefficient used (1 for CCV, 0 where none)
    gamma : (H, W, 3) float32, distant energy ratio per channel (read-only: frames that
        reuse a still scene's Geometry share it, see core.geometry.GeometryCache)
    variance : (H, W) float32, tracked variance σ² after the update (luminance²)
    valid_history : (H, W) bool, the history used for the counts was valid
    mask : (H, W) bool, SSS pixels (read-only, shared like ``gamma``)
    spp : float, mean count over SSS pixels
    samples : int, samples taken (separable: pixel reads)
    sampling_ms : float, wall time of the sampling step (separable: both passes) only
    update_ms : float, wall time of history + CV bookkeeping
    total_ms : float, wall time of the whole ``process()`` call
    distant_share : float, share of SSS pixels with max γ ≥ ε_u
    fallback_share : float, share of samples the follow-surface tests rejected (they
        read the centre, or stand for hidden surface)
    repaired : int, input values replaced because non-finite or negative
    fallback, draws : int, the terms of ``fallback_share``: samples (separable: tap
        reads) that fell back, of ``draws``
    distant_pixels : int, SSS pixels with max γ ≥ ε_u (``distant_share`` × SSS pixels)

    The frame-level figures of a cropped frame (core.tiling) count the pixels of
    its core only, so those of tiles add up to the whole image's.
    """

    number: int
    method: str
    sss: np.ndarray
    composite: np.ndarray
    counts: np.ndarray
    alpha: np.ndarray
    gamma: np.ndarray
    variance: np.ndarray
    valid_history: np.ndarray
    mask: np.ndarray
    spp: float
    samples: int
    sampling_ms: float
    update_ms: float
    total_ms: float
    distant_share: float
    fallback_share: float
    repaired: int = 0
    fallback: int = 0
    draws: int = 0
    distant_pixels: int = 0


@numpy_side("composite")
def composite(
    frame: Frame,
    index: np.ndarray,
    shaded: np.ndarray,
    weight: np.ndarray | None = None,
    backend: str = "numpy",
) -> tuple[np.ndarray, np.ndarray]:
    """The composite and the lighting image with ``shaded`` put in at ``index``.

    Parameters
    ----------
    frame : Frame (lighting B, albedo, Combined; linear)
    index : (P,) int, flat indices of the SSS pixels
    shaded : (P, 3) float, L at those pixels (linear, >= 0)
    weight : (P,) float in [0, 1], Subsurface Weight w (None: 1)
    backend : one of core.params.BACKENDS; where it resolves to numba, float64
        ``shaded`` is composited in one compiled pass with the same float64
        operations (:func:`_composite_compiled`: the same images)

    Returns
    -------
    composite : (H, W, 3) float32, ``Combined − albedo·B + albedo·((1 − w)·B + w·L)``
        on SSS pixels, as Cycles mixes diffuse and subsurface; ``Combined``
        elsewhere; clipped to [0, float32 max]
    sss : (H, W, 3) float32, L on SSS pixels and B elsewhere
    """
    shaded = np.clip(np.nan_to_num(shaded, nan=0.0, posinf=_BIG), 0.0, _BIG)
    shape = frame.lighting.shape[:2]
    b = take_rows(frame.lighting, index, shape).astype(np.float64)
    albedo = take_rows(frame.albedo, index, shape)
    out = frame.combined.copy()
    flat = out.reshape(-1, 3)
    change = shaded - b
    if weight is not None and not np.all(weight == 1.0):
        change *= np.asarray(weight, dtype=np.float64)[:, None]
    flat[index] = np.clip(take_rows(out, index, shape) + albedo * change, 0.0, _BIG)
    sss = frame.lighting.copy()
    sss.reshape(-1, 3)[index] = shaded
    return np.maximum(out, 0.0, out=out), sss


def relit(frame: Frame, mask: np.ndarray, lighting: np.ndarray) -> np.ndarray:
    """The composite of ``frame`` with ``lighting`` as L on the SSS pixels ``mask``.

    What a method's composite would have been had it shaded those pixels with
    ``lighting`` (a denoised copy of its :attr:`FrameResult.sss`, say): the same
    formula and Subsurface Weights as :func:`composite`, whatever the method.

    Parameters
    ----------
    frame : Frame (lighting B, albedo, Combined, Material Index; linear), uncropped
    mask : (H, W) bool, the SSS pixels (:attr:`FrameResult.mask`)
    lighting : (H, W, 3) float, L (linear, >= 0); read on ``mask`` only

    Returns
    -------
    (H, W, 3) float32, as :func:`composite`'s composite
    """
    index = np.flatnonzero(mask)
    mat = compact_slots(frame.material.reshape(-1)[index], slot_keys(frame.materials))
    shaded = np.asarray(lighting, np.float64).reshape(-1, 3)[index]
    return composite(frame, index, shaded, pixel_weights(frame, index, mat))[0]


def _float64_shaded(frame, index, shaded, weight=None, backend="numpy") -> bool:
    """The compiled composite takes float64 ``shaded`` (the estimators' own)."""
    return np.asarray(shaded).dtype == np.float64


@compiled_side("composite", supports=_float64_shaded)
def _composite_compiled(
    frame: Frame,
    index: np.ndarray,
    shaded: np.ndarray,
    weight: np.ndarray | None = None,
    backend: str = "numpy",
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`composite` in two compiled passes (a dozen NumPy passes over the image
    and fancy-indexed rows otherwise): the same images."""
    return compiled_module("image").composite(
        frame.combined, frame.lighting, frame.albedo, index, shaded, weight
    )


def assemble(
    frame: Frame,
    geom: Geometry,
    method: str,
    shaded: np.ndarray,
    counts: np.ndarray,
    *,
    eps_u: float,
    samples: int,
    fallback: int,
    draws: int,
    sampling_ms: float,
    started: float,
    update_ms: float = 0.0,
    alpha: np.ndarray | None = None,
    variance: np.ndarray | None = None,
    valid: np.ndarray | None = None,
    backend: str = "numpy",
) -> FrameResult:
    """A :class:`FrameResult` from the per-SSS-pixel arrays of a method.

    Parameters
    ----------
    frame, geom : the frame and its Geometry (P SSS pixels)
    method : str, method name
    shaded : (P, 3) float, L per SSS pixel (linear)
    counts : (P,) int, samples (or reads) per SSS pixel
    eps_u : float, ε_u of the distant-share statistic
    samples : int, samples taken
    fallback, draws : int, samples (or reads) that fell back to the centre, of ``draws``
    sampling_ms, update_ms : float, wall times (ms)
    started : float, ``time.perf_counter()`` when the caller's ``process()`` began:
        ``total_ms`` is the time from it to the end of this call (the composite and
        the maps included)
    alpha, variance : (P,) float, optional (0 where not given)
    valid : (P,) bool, optional (False where not given)
    backend : one of core.params.BACKENDS, for the composite and the float maps
        (compiled where it resolves to numba; the same images)
    """
    n = geom.size
    comp, sss = composite(frame, geom.index, shaded, geom.weight, backend)
    zeros = np.zeros(n)
    # A crop's frame-level figures are those of its core pixels (core.tiling).
    core = slice(None) if geom.core is None else geom.core
    counted = np.asarray(counts)[core]
    distant = geom.gamma_max[core] >= eps_u
    pixels = int(distant.size)
    result = FrameResult(
        number=frame.number,
        method=method,
        sss=sss,
        composite=comp,
        counts=geom.to_image(counts, 0, np.int32),
        alpha=geom.to_image(zeros if alpha is None else alpha, backend=backend),
        gamma=geom.gamma_image(backend),
        variance=geom.to_image(zeros if variance is None else variance, backend=backend),
        valid_history=geom.to_image(np.zeros(n, bool) if valid is None else valid, False, bool),
        mask=geom.mask_image,
        spp=float(np.mean(counted)) if pixels else 0.0,
        samples=int(samples),
        sampling_ms=sampling_ms,
        update_ms=update_ms,
        total_ms=0.0,
        distant_share=float(np.mean(distant)) if pixels else 0.0,
        fallback_share=fallback / draws if draws else 0.0,
        repaired=frame.repaired,
        fallback=int(fallback),
        draws=int(draws),
        distant_pixels=int(np.count_nonzero(distant)),
    )
    result.total_ms = (time.perf_counter() - started) * 1e3
    return result

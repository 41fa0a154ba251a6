"""The user's frame against Cycles' ground truth: what a display shows, and the subsurface effect.

The figures of ``cvsss compare`` (docs/explanation/accuracy.md §3): a frame
the user renders (Cycles or EEVEE as set, or Apply on Render) against the same
frame path-traced by Cycles with each material's own subsurface method.

Display rule, one exposure per frame
    ``k = 1/p99(max_c GT)`` over the *whole* ground-truth frame
    (:func:`frame_exposure`); both images times k, sRGB OETF, clipped to
    [0, 1] (:func:`display`); RGB PSNR with peak 1 (:func:`psnr_display`).
    Unlike :func:`.metrics.psnr_gt`, whose exposure follows the pixels
    compared, every figure of a frame (whole, subsurface, rest) shares the one
    exposure the whole frame is shown with.
Subsurface pixels
    Where the ground truth with and without subsurface differ by more than 1 %
    of its peak ``1/k`` in some channel (:func:`subsurface_mask`): the user's
    scene carries no material mask, and this also counts the light that
    scattering moves onto neighbouring surfaces.
The subsurface effect
    ``D = frame − frame without subsurface`` (same engine and settings) against
    ``D_GT = GT − GT without subsurface``; ``s = mean(GT without subsurface) /
    mean(frame without subsurface)`` over the subsurface pixels matches the
    engine's lighting level to Cycles' (EEVEE's differs), and
    ``effect_dB = −10·log10(mean over subsurface pixels and channels of
    (k·s·D − k·D_GT)²)`` (:func:`effect_db`): linear, not display-encoded, so
    that a difference is not bent by the OETF.

By object
    :func:`object_errors` sums a frame's squared errors (display, and the
    effect's) over each object's subsurface pixels, from an Object Index
    pass: which objects a figure's gain or loss comes from.

Every function takes linear, scene-referred RGB; none imports Blender.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ..color import srgb_encode
from .metrics import PSNR_CAP_DB, gt_exposure

#: Subsurface pixels: GT with and without subsurface differ by more than this share of 1/k.
MASK_FRACTION = 0.01

#: Samples per pixel of the ground truth these figures are taken against (``cvsss
#: compare``, the demo's "what you had / what you get"). Its own noise adds to every
#: row's error alike, so it narrows the gap between two renders in dB; in a scene lit
#: by small lights (candle flames) a 1024-spp ground truth's noise on the subsurface
#: pixels is as large as a denoised 16-spp frame's error
#: (docs/explanation/accuracy.md §3.5).
TRUTH_SAMPLES = 4096


def _rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image, dtype=np.float64)
    if image.ndim != 3 or image.shape[-1] < 3:
        raise ValueError(f"an image must be (H, W, 3) or (H, W, 4), got shape {image.shape}")
    return image[..., :3]


def mse_db(mse: float) -> float:
    """PSNR (peak 1) of a mean squared error: nan when not finite, capped at
    :data:`.metrics.PSNR_CAP_DB`."""
    if not np.isfinite(mse):
        return float("nan")
    if mse <= 10.0 ** (-PSNR_CAP_DB / 10.0):
        return PSNR_CAP_DB
    return float(-10.0 * np.log10(mse))


def frame_exposure(ground_truth: np.ndarray) -> float:
    """The frame's exposure ``k = 1/p99(max_c GT)`` over every pixel (1 for a black frame).

    Parameters
    ----------
    ground_truth : (H, W, 3) or (H, W, 4) float, linear (alpha ignored)

    Returns
    -------
    float, 1 / (linear radiance)
    """
    return gt_exposure(_rgb(ground_truth))


def display(image: np.ndarray, k: float) -> np.ndarray:
    """What a display shows: ``sRGB_OETF(clip(k · image, 0, 1))``.

    Parameters
    ----------
    image : (H, W, 3) or (H, W, 4) float, linear (alpha dropped)
    k : float, exposure (:func:`frame_exposure` of the ground truth)

    Returns
    -------
    (H, W, 3) float64 in [0, 1]; NaN counts as 0.

    >>> display(np.full((1, 1, 3), 0.25), 2.0).round(4).tolist()
    [[[0.7354, 0.7354, 0.7354]]]
    """
    return srgb_encode(_rgb(image) * float(k))


def psnr_display(
    test: np.ndarray, ground_truth: np.ndarray, k: float, mask: np.ndarray | None = None
) -> float:
    """RGB PSNR of ``test`` against ``ground_truth``, both shown with exposure ``k``.

    Parameters
    ----------
    test, ground_truth : (H, W, 3) or (H, W, 4) float, linear
    k : float, the frame's exposure (:func:`frame_exposure`)
    mask : (H, W) bool, pixels compared; None for the whole frame

    Returns
    -------
    float, dB (peak 1); ``nan`` when the mask is empty; capped at
    :data:`.metrics.PSNR_CAP_DB`.
    """
    diff = _display_difference(test, ground_truth, k, mask)
    if diff.size == 0:
        return float("nan")
    return mse_db(float(np.mean(diff**2)))


def _display_difference(
    test: np.ndarray, ground_truth: np.ndarray, k: float, mask: np.ndarray | None = None
) -> np.ndarray:
    """``display(test) − display(ground_truth)``: (H, W, 3), or (n, 3) on ``mask``'s pixels."""
    a, b = display(test, k), display(ground_truth, k)
    if a.shape != b.shape:
        raise ValueError(f"test is {a.shape[:2]} pixels, the ground truth {b.shape[:2]}")
    if mask is not None:
        mask = np.asarray(mask, dtype=bool)
        a, b = a[mask], b[mask]
    return a - b


def subsurface_mask(
    ground_truth: np.ndarray,
    ground_truth_off: np.ndarray,
    k: float,
    fraction: float = MASK_FRACTION,
) -> np.ndarray:
    """Subsurface pixels: ``max_c |GT − GT without subsurface| > fraction / k``.

    Parameters
    ----------
    ground_truth, ground_truth_off : (H, W, 3) or (H, W, 4) float, linear; Cycles with
        and without subsurface (same seed and samples)
    k : float, the frame's exposure; ``1/k`` is the peak the fraction is of
    fraction : float, share of the peak (default 1 %)

    Returns
    -------
    (H, W) bool
    """
    diff = np.abs(_rgb(ground_truth) - _rgb(ground_truth_off)).max(axis=-1)
    return np.nan_to_num(diff, nan=0.0) * float(k) > float(fraction)


def lighting_scale(ground_truth_off: np.ndarray, frame_off: np.ndarray, mask: np.ndarray) -> float:
    """``s = mean(GT without subsurface) / mean(frame without subsurface)`` over ``mask``.

    The mean runs over the mask's pixels and the three channels. 1 when the
    engine lights the scene as Cycles does; ``nan`` on an empty mask or a
    black frame.
    """
    mask = np.asarray(mask, dtype=bool)
    gt = _rgb(ground_truth_off)[mask]
    ours = _rgb(frame_off)[mask]
    if gt.size == 0:
        return float("nan")
    mean = float(np.mean(ours))
    return float(np.mean(gt)) / mean if mean > 0 else float("nan")


def effect_db(
    frame: np.ndarray,
    frame_off: np.ndarray,
    ground_truth: np.ndarray,
    ground_truth_off: np.ndarray,
    mask: np.ndarray,
    k: float,
    s: float | None = None,
) -> float:
    """How well the change subsurface makes matches Cycles' (the module doc's effect).

    Parameters
    ----------
    frame, frame_off : (H, W, 3|4) float, linear; the engine's frame with and
        without subsurface (same settings)
    ground_truth, ground_truth_off : (H, W, 3|4) float, linear; Cycles', likewise
    mask : (H, W) bool, the subsurface pixels (:func:`subsurface_mask`)
    k : float, the frame's exposure
    s : float, optional; default :func:`lighting_scale`

    Returns
    -------
    float, dB: ``−10·log10(mean((k·s·D − k·D_GT)²))`` over the mask's pixels and
    channels; ``nan`` on an empty mask or undefined ``s``; capped at
    :data:`.metrics.PSNR_CAP_DB`.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return float("nan")
    if s is None:
        s = lighting_scale(ground_truth_off, frame_off, mask)
    if not np.isfinite(s):
        return float("nan")
    diff = _effect_difference(frame, frame_off, ground_truth, ground_truth_off, mask, k, s)
    return mse_db(float(np.mean(diff**2)))


def _effect_difference(frame, frame_off, ground_truth, ground_truth_off, mask, k, s):
    """(n, 3) ``k·s·D − k·D_GT`` on ``mask``'s pixels (:func:`effect_db`'s arguments)."""
    d = (_rgb(frame) - _rgb(frame_off))[mask]
    d_gt = (_rgb(ground_truth) - _rgb(ground_truth_off))[mask]
    return float(k) * (s * d - d_gt)


@dataclass(frozen=True)
class FrameFigures:
    """The figures of one frame against its ground truth.

    Attributes
    ----------
    psnr_whole_db : float, dB, the whole frame
    psnr_subsurface_db : float, dB, the subsurface pixels
    psnr_rest_db : float, dB, every other pixel (what subsurface does not touch)
    effect_db : float, dB, the subsurface effect (nan without a frame without subsurface)
    lighting_scale : float, ``s`` of the effect (nan without one)
    subsurface_share : float in [0, 1], share of the frame's pixels that are subsurface pixels
    exposure : float, ``k`` (1 / linear radiance)
    """

    psnr_whole_db: float
    psnr_subsurface_db: float
    psnr_rest_db: float
    effect_db: float
    lighting_scale: float
    subsurface_share: float
    exposure: float

    def to_dict(self) -> dict:
        return asdict(self)


def frame_figures(
    frame: np.ndarray,
    ground_truth: np.ndarray,
    ground_truth_off: np.ndarray,
    frame_off: np.ndarray | None = None,
) -> FrameFigures:
    """Every figure of one frame (module doc), with the frame's one exposure.

    Parameters
    ----------
    frame : (H, W, 3|4) float, linear, the user's frame
    ground_truth, ground_truth_off : (H, W, 3|4) float, linear, Cycles with and without
        subsurface
    frame_off : (H, W, 3|4) float, linear, optional; the same engine and settings
        without subsurface (for the effect)

    Returns
    -------
    FrameFigures
    """
    k = frame_exposure(ground_truth)
    mask = subsurface_mask(ground_truth, ground_truth_off, k)
    effect = scale = float("nan")
    if frame_off is not None:
        scale = lighting_scale(ground_truth_off, frame_off, mask)
        effect = effect_db(frame, frame_off, ground_truth, ground_truth_off, mask, k, scale)
    return FrameFigures(
        psnr_whole_db=psnr_display(frame, ground_truth, k),
        psnr_subsurface_db=psnr_display(frame, ground_truth, k, mask),
        psnr_rest_db=psnr_display(frame, ground_truth, k, ~mask),
        effect_db=effect,
        lighting_scale=scale,
        subsurface_share=float(mask.mean()),
        exposure=k,
    )


def object_errors(
    frame: np.ndarray,
    ground_truth: np.ndarray,
    ground_truth_off: np.ndarray,
    objects: np.ndarray,
    frame_off: np.ndarray | None = None,
    figures: FrameFigures | None = None,
) -> dict[int, dict]:
    """Each object's share of a frame's error on the subsurface pixels: which objects a
    figure's gain or loss comes from.

    Parameters
    ----------
    frame, ground_truth, ground_truth_off, frame_off : as :func:`frame_figures`
    objects : (H, W) int, the object each pixel shows (an Object Index pass; 0: none)
    figures : FrameFigures, optional
        :func:`frame_figures` of the same images: its exposure and lighting scale are
        used instead of being computed again.

    Returns
    -------
    dict, object number -> ``pixels`` (its subsurface pixels, :func:`subsurface_mask`),
    ``display_sse`` (the squared display error of :func:`psnr_display`, the mean over
    the channels, summed over those pixels) and ``effect_sse`` (likewise the effect's
    ``(k·s·D − k·D_GT)²``, :func:`effect_db`; nan without ``frame_off``). An object's
    PSNR on its subsurface pixels is ``−10·log10(sse / pixels)``. Objects without
    subsurface pixels are left out.
    """
    k = figures.exposure if figures is not None else frame_exposure(ground_truth)
    mask = subsurface_mask(ground_truth, ground_truth_off, k)
    objects = np.asarray(objects)
    if objects.shape != mask.shape:
        raise ValueError(f"objects is {objects.shape}, the frame {mask.shape}")
    numbers = objects[mask].astype(np.int64)
    if numbers.size == 0:
        return {}
    if numbers.min() < 0:
        raise ValueError("object numbers must be >= 0")
    shown = _display_difference(frame, ground_truth, k, mask)
    display_sse = np.bincount(numbers, np.mean(shown**2, axis=-1))
    effect_sse = np.full(display_sse.shape, np.nan)
    if frame_off is not None:
        s = (
            figures.lighting_scale
            if figures is not None
            else lighting_scale(ground_truth_off, frame_off, mask)
        )
        if np.isfinite(s):
            change = _effect_difference(
                frame, frame_off, ground_truth, ground_truth_off, mask, k, s
            )
            effect_sse = np.bincount(numbers, np.mean(change**2, axis=-1), display_sse.size)
    counts = np.bincount(numbers, minlength=display_sse.size)
    return {
        int(n): {
            "pixels": int(counts[n]),
            "display_sse": float(display_sse[n]),
            "effect_sse": float(effect_sse[n]),
        }
        for n in np.flatnonzero(counts)
    }


def mean_figures(figures: list[FrameFigures]) -> dict:
    """The mean of each figure over frames (NaN frames left out; dB averaged as dB, as
    the demo report does); ``{}`` for no frames."""
    if not figures:
        return {}
    out = {}
    for name in figures[0].to_dict():
        values = np.array([getattr(f, name) for f in figures], dtype=np.float64)
        values = values[np.isfinite(values)]
        out[name] = float(values.mean()) if values.size else float("nan")
    return out

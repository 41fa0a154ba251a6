"""Per-frame metrics: PSNR against our reference and against Cycles ground truth.

Two quality figures, always reported side by side and labelled:

- *self-referenced* (:func:`psnr`): luminance PSNR over SSS pixels against
  our own 1024-spp ``reference`` on the same passes. It isolates the
  estimator's Monte Carlo noise.
- *against ground truth* (:func:`psnr_gt`): RGB PSNR against the same frame
  path-traced by Cycles with its own subsurface on (docs/explanation/accuracy.md §1). It is what a
  Blender user sees, model error included.

The ground-truth display rule: per frame, exposure ``k = 1/p99(max_c GT)``
(the 99th percentile, over the compared pixels, of the brightest channel of
the ground truth, so one firefly or a bright sky does not decide it), both
images times k, sRGB transfer, clipped to [0, 1], RGB, peak 1.
"""

from __future__ import annotations

import numpy as np

from ..color import display_luma, srgb_encode

#: PSNR reported when the images are identical on the mask (avoids inf in CSV/JSON).
PSNR_CAP_DB = 100.0


def psnr(test: np.ndarray, reference: np.ndarray, mask: np.ndarray, exposure: float = 1.0) -> float:
    """Luminance PSNR over ``mask``, display-referred (exposure, sRGB, clip, peak 1).

    Parameters
    ----------
    test, reference : (H, W, 3) float, linear scene-referred
    mask : (H, W) bool, pixels to compare (SSS pixels)
    exposure : float

    Returns
    -------
    float, dB; ``nan`` when the mask is empty; capped at 100 dB.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return float("nan")
    a = display_luma(np.asarray(test)[mask], exposure)
    b = display_luma(np.asarray(reference)[mask], exposure)
    mse = float(np.mean((a - b) ** 2))
    if mse <= 10.0 ** (-PSNR_CAP_DB / 10.0):
        return PSNR_CAP_DB
    return float(10.0 * np.log10(1.0 / mse))


def gt_exposure(ground_truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """``k = 1/p99(max_c GT)`` over ``mask`` (all pixels when None); 1 for a black frame."""
    gt = np.asarray(ground_truth, dtype=np.float64)
    peak = np.nan_to_num(gt.max(axis=-1), nan=0.0, posinf=0.0)
    values = peak if mask is None else peak[np.asarray(mask, dtype=bool)]
    if values.size == 0:
        return 1.0
    p99 = float(np.percentile(values, 99.0))
    return 1.0 / p99 if p99 > 0 else 1.0


def psnr_gt(test: np.ndarray, ground_truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """RGB PSNR against Cycles ground truth with the display rule of the module doc.

    Parameters
    ----------
    test, ground_truth : (H, W, 3) float, linear scene-referred
    mask : (H, W) bool, pixels compared (SSS pixels), or None for the whole image

    Returns
    -------
    float, dB; ``nan`` when the mask is empty; capped at 100 dB. The exposure
    k comes from the ground truth over the same pixels.
    """
    sel = (slice(None),) if mask is None else np.asarray(mask, dtype=bool)
    gt = np.asarray(ground_truth, dtype=np.float64)[sel].reshape(-1, 3)
    ours = np.asarray(test, dtype=np.float64)[sel].reshape(-1, 3)
    if gt.size == 0:
        return float("nan")
    k = gt_exposure(gt)
    mse = float(np.mean((srgb_encode(ours * k) - srgb_encode(gt * k)) ** 2))
    if mse <= 10.0 ** (-PSNR_CAP_DB / 10.0):
        return PSNR_CAP_DB
    return float(10.0 * np.log10(1.0 / mse))


def channel_ratio(test: np.ndarray, ground_truth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(3,) mean of ours over mean of the ground truth per channel on ``mask`` (linear).

    1 is right on average; 1.08 is 8 % too bright. ``nan`` where the ground
    truth's mean is 0 or the mask is empty.
    """
    mask = np.asarray(mask, dtype=bool)
    if not mask.any():
        return np.full(3, np.nan)
    ours = np.asarray(test, dtype=np.float64)[mask].mean(axis=0)
    gt = np.asarray(ground_truth, dtype=np.float64)[mask].mean(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(gt > 0, ours / gt, np.nan)


def _neighbour_edges(
    material: np.ndarray, depth: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(H, W) bool masks of what the 8-neighbourhood holds: ``farther`` (the background
    or a depth more than 10 % farther), ``nearer`` (a depth more than 10 % nearer),
    ``other`` (another material). The image border repeats the edge pixels."""
    mat = np.asarray(material)
    z = np.asarray(depth, dtype=np.float64)
    h, w = z.shape
    farther = np.zeros((h, w), dtype=bool)
    nearer = np.zeros((h, w), dtype=bool)
    other = np.zeros((h, w), dtype=bool)
    pad_m = np.pad(mat, 1, mode="edge")
    pad_z = np.pad(z, 1, mode="edge")
    with np.errstate(invalid="ignore"):
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                if dx == dy == 0:
                    continue
                nm = pad_m[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
                nz = pad_z[1 + dy : 1 + dy + h, 1 + dx : 1 + dx + w]
                farther |= ~np.isfinite(nz) | (nz - z > 0.1 * z)
                nearer |= z - nz > 0.1 * z
                other |= nm != mat
    return farther, nearer, other


def silhouette(mask: np.ndarray, material: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """(H, W) bool: SSS pixels at a silhouette or material edge.

    An SSS pixel whose 8-neighbourhood holds a pixel of another material, the
    background, or a depth more than 10 % away (an occlusion edge) — where
    screen-space scattering runs out of surface (the rims of docs/explanation/accuracy.md §2).
    The image border does not count as an edge.
    """
    farther, nearer, other = _neighbour_edges(material, depth)
    return np.asarray(mask, dtype=bool) & (farther | nearer | other)


#: Kinds of :func:`edge_kinds`, in order of precedence.
EDGE_KINDS = ("outer", "occluded", "contact")


def edge_kinds(mask: np.ndarray, material: np.ndarray, depth: np.ndarray) -> dict[str, np.ndarray]:
    """The :func:`silhouette` pixels split by what lies across the edge.

    ``outer``: the background or a surface more than 10 % farther — the SSS
    surface ends there (its own silhouette, where its hidden back side begins);
    ``occluded``: a surface more than 10 % nearer covers it; ``contact``: another
    material at about the same depth (objects that touch, such as a block resting
    on a table top). A pixel takes the first kind that applies, in this order;
    the three masks partition :func:`silhouette`.

    Returns
    -------
    dict kind -> (H, W) bool
    """
    mask = np.asarray(mask, dtype=bool)
    farther, nearer, other = _neighbour_edges(material, depth)
    outer = mask & farther
    occluded = mask & nearer & ~outer
    contact = mask & other & ~outer & ~occluded
    return {"outer": outer, "occluded": occluded, "contact": contact}


def median3(values: np.ndarray) -> np.ndarray:
    """Third-order median filter over a 1D series (edges keep their window of 2).

    >>> median3(np.array([1.0, 9.0, 2.0, 3.0])).tolist()
    [5.0, 2.0, 3.0, 2.5]
    """
    v = np.asarray(values, dtype=np.float64)
    if v.size < 3:
        return v.copy()
    out = np.empty_like(v)
    out[1:-1] = np.median(np.stack([v[:-2], v[1:-1], v[2:]]), axis=0)
    out[0] = np.median(v[:2])
    out[-1] = np.median(v[-2:])
    return out

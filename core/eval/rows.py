"""The metric rows of a run: one per frame and method (``metrics.csv``).

Columns (:data:`METRICS_FIELDS`):

``spp``, ``sampling_ms``, ``frame_ms``
    The mean sample count over SSS pixels, the wall time of the sampling step and of
    the method's whole post-process of the frame (ms, this machine).
``psnr_db``
    *self-referenced*: luminance PSNR over SSS pixels of the composite against the
    ``reference`` method, display-referred (:func:`core.eval.metrics.psnr`); empty
    on frames without a reference.
``psnr_gt_db``, ``psnr_gt_full_db``, ``ratio_r/g/b``, ``rim_ratio``, ``rim_outer_ratio``, ``rim_contact_ratio``
    *against ground truth* (Cycles' own subsurface, where a ground-truth frame is
    given): RGB PSNR over SSS pixels and over the whole image, the per-channel mean
    ratio ours/ground truth on SSS pixels, and the luminance ratio on silhouette SSS
    pixels — all of them, the outer silhouettes (background or a farther surface
    across the edge) and the contact edges (another material at the same depth), see
    :func:`core.eval.metrics.edge_kinds`; empty without.
``light_change``, ``flicker``
    Temporal behaviour: the relative change of the mean lighting B over the SSS pixels
    since the previous frame of the run (the same for every method; marks flashes and
    switches), and the method's *flicker*: the mean absolute frame-to-frame change of
    the composite's luminance over the SSS pixels whose passes did not change
    (luminance of Combined within 0.5 %), relative to their mean luminance — what
    animators see as shimmer. Empty on the first frame and after a gap.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence

import numpy as np

from ..color import luminance
from ..result import FrameResult
from .metrics import channel_ratio, psnr, psnr_gt

METRICS_FIELDS = (
    "frame",
    "method",
    "spp",
    "sampling_ms",
    "frame_ms",
    "psnr_db",
    "psnr_gt_db",
    "psnr_gt_full_db",
    "ratio_r",
    "ratio_g",
    "ratio_b",
    "rim_ratio",
    "rim_outer_ratio",
    "rim_contact_ratio",
    "light_change",
    "flicker",
)


def format_value(value: float | None, digits: int = 4) -> str:
    """A metric as CSV text: ``digits`` decimals, empty for None or NaN."""
    if value is None or value != value:  # None or NaN
        return ""
    return f"{value:.{digits}f}"


def format_metrics(rows: Sequence[dict]) -> str:
    """CSV text of metric rows (``METRICS_FIELDS`` columns)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRICS_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: row.get(k, "") for k in METRICS_FIELDS})
    return buf.getvalue()


def method_row(
    number: int, method: str, result: FrameResult, reference: FrameResult | None, exposure: float
) -> tuple[dict, float | None]:
    """The row of one method on one frame, and its self-referenced PSNR (None without a
    reference on this frame). ``exposure``: ``SSSParams.exposure``."""
    value = (
        psnr(result.composite, reference.composite, result.mask, exposure)
        if reference is not None
        else None
    )
    row = {
        "frame": number,
        "method": method,
        "spp": format_value(result.spp),
        "sampling_ms": format_value(result.sampling_ms, 3),
        "frame_ms": format_value(result.total_ms, 3),
        "psnr_db": format_value(value, 3),
    }
    return row, value


def temporal_columns(
    mask: np.ndarray,
    ours_y: np.ndarray,
    combined_y: np.ndarray,
    light_mean: float,
    last: tuple[np.ndarray, float, np.ndarray],
) -> dict:
    """``light_change`` and ``flicker`` of a frame against the method's previous frame.

    Parameters
    ----------
    mask : (H, W) bool, the SSS pixels
    ours_y, combined_y : (H, W) float32, luminance of the composite and of Combined
    light_mean : float, mean lighting luminance over the SSS pixels
    last : (Combined's luminance, mean lighting, composite's luminance) of the previous
        frame, as above
    """
    last_combined, last_light, last_y = last
    row = {}
    if last_light > 0:
        row["light_change"] = format_value(abs(light_mean - last_light) / last_light)
    with np.errstate(invalid="ignore", divide="ignore"):
        stable = mask & (np.abs(combined_y - last_combined) <= np.float32(0.005) * combined_y)
    if stable.any():
        level = float(ours_y[stable].astype(np.float64).mean())
        if level > 0:
            change = np.abs(ours_y[stable].astype(np.float64) - last_y[stable])
            row["flicker"] = format_value(float(change.mean()) / level, 6)
    return row


def ground_truth_columns(
    result: FrameResult, ground_truth: np.ndarray, rims: dict[str, np.ndarray]
) -> dict:
    """The ground-truth columns of a metric row (see the module doc).

    ``rims`` holds the silhouette pixels by kind (:func:`core.eval.metrics.edge_kinds`).
    """
    ratio = channel_ratio(result.composite, ground_truth, result.mask)
    gt_y = luminance(np.asarray(ground_truth, np.float64))
    ours_y = luminance(np.asarray(result.composite, np.float64))

    def rim(where: np.ndarray) -> float:
        if not where.any():
            return float("nan")
        gt_rim = float(gt_y[where].mean())
        return float(ours_y[where].mean()) / gt_rim if gt_rim > 0 else float("nan")

    every = rims["outer"] | rims["occluded"] | rims["contact"]
    return {
        "psnr_gt_db": format_value(psnr_gt(result.composite, ground_truth, result.mask), 3),
        "psnr_gt_full_db": format_value(psnr_gt(result.composite, ground_truth), 3),
        "ratio_r": format_value(float(ratio[0])),
        "ratio_g": format_value(float(ratio[1])),
        "ratio_b": format_value(float(ratio[2])),
        "rim_ratio": format_value(rim(every)),
        "rim_outer_ratio": format_value(rim(rims["outer"])),
        "rim_contact_ratio": format_value(rim(rims["contact"])),
    }

"""The figures the demo computes from its results: per-method means of the metric rows,
PSNR on one material or around moving shadows, and the equal-time verdict."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ....core.eval.metrics import median3, psnr, psnr_gt
from ....core.io.exr import read_combined, read_frame, read_result

#: A frame whose mean lighting changed by at least this share is a flash or a switch.
SWITCH = 0.25


def floats(rows: Sequence[dict], key: str) -> list[float]:
    """The ``key`` column of metric rows as floats, rows without it skipped."""
    return [float(r[key]) for r in rows if r.get(key) not in ("", None)]


def nanmean(values: Sequence[float]) -> float:
    """Mean of ``values``, NaN when there are none."""
    return float(np.mean(values)) if len(values) else math.nan


def summarize(rows: Sequence[dict]) -> dict:
    """Per method, the means of a scene's metric rows (see core.run for the columns).

    ``sampling_ms`` is the mean of the 3rd-order median-filtered per-frame times
    (P Sec. 7); every other mean skips frames without the figure: ``psnr_db``
    (self-referenced), ``psnr_gt_db`` / ``psnr_gt_full_db`` / ``rim_ratio`` /
    ``rim_outer_ratio`` / ``rim_contact_ratio`` / ``ratio`` (against Cycles ground truth), ``flicker``, ``psnr_switch_db``
    (self-referenced, on the frames right after a flash or switch:
    ``light_change`` >= :data:`SWITCH`), ``psnr_gt_first_db`` (the first
    ground-truth frame) and ``frame_ms`` (the whole post-process of a frame).
    """
    by = defaultdict(list)
    for r in rows:
        by[r["method"]].append(r)
    out = {}
    for method, rs in by.items():
        spp = np.array([float(r["spp"]) for r in rs])
        ms = median3(np.array([float(r["sampling_ms"]) for r in rs]))
        switch = [r for r in rs if r.get("light_change") and float(r["light_change"]) >= SWITCH]
        gt_rows = [r for r in rs if r.get("psnr_gt_db")]
        out[method] = {
            "spp": float(spp.mean()),
            "spp_max": float(spp.max()),
            "spp_median": float(np.median(spp)),
            "sampling_ms": float(ms.mean()),
            "frame_ms": nanmean(floats(rs, "frame_ms")),
            "psnr_db": nanmean(floats(rs, "psnr_db")),
            "psnr_gt_db": nanmean(floats(rs, "psnr_gt_db")),
            "psnr_gt_full_db": nanmean(floats(rs, "psnr_gt_full_db")),
            "psnr_gt_first_db": float(gt_rows[0]["psnr_gt_db"]) if gt_rows else math.nan,
            "psnr_gt_warm_db": nanmean(floats(gt_rows[1:], "psnr_gt_db")),
            "rim_ratio": nanmean(floats(rs, "rim_ratio")),
            "rim_outer_ratio": nanmean(floats(rs, "rim_outer_ratio")),
            "rim_contact_ratio": nanmean(floats(rs, "rim_contact_ratio")),
            "ratio": [nanmean(floats(rs, f"ratio_{c}")) for c in "rgb"],
            "flicker": nanmean(floats(rs, "flicker")),
            "psnr_switch_db": nanmean(floats(switch, "psnr_db")),
            "gt_frames": [int(r["frame"]) for r in gt_rows],
            "psnr_gt_frames": floats(gt_rows, "psnr_gt_db"),
        }
    return out


#: The demo material with Subsurface Weight 0.5 (the regular scene's candles).
HALF_WEIGHT_MATERIAL = "cvsss Wax"


def material_psnr_gt(
    scene_dir: Path, gt_frames: Sequence[int], methods: Sequence[str], material: str
) -> dict | None:
    """Mean PSNR against ground truth on one material's pixels with weight < 1, per method."""
    values: dict = defaultdict(list)
    for f in gt_frames:
        passes = scene_dir / "passes" / f"{f:04d}.exr"
        gt_path = scene_dir / "ground_truth" / f"{f:04d}.exr"
        if not (passes.is_file() and gt_path.is_file()):
            continue
        frame = read_frame(passes)
        spec = next((s for s in frame.materials.values() if s.name == material), None)
        if spec is None or spec.weight >= 1.0:
            return None
        mask = frame.material == spec.slot
        if not mask.any():
            continue
        gt = read_combined(gt_path)
        for m in methods:
            res = scene_dir / m / f"{f:04d}.exr"
            if res.is_file():
                values[m].append(psnr_gt(read_result(res)["Composite"], gt, mask))
    if not all(values.get(m) for m in methods):
        return None
    return {m: float(np.mean(values[m])) for m in methods}


def shadow_band_psnr(scene_dir: Path, frames: int, methods: Sequence[str]) -> dict | None:
    """Self-referenced PSNR in a band around moving shadow edges, per method.

    On the frames with a reference, the band is the SSS pixels whose lighting
    B changed by more than 20 % since the previous frame, grown by 2 pixels:
    where a moving shadow would leave a trail.
    """
    values: dict = defaultdict(list)
    for f in range(2, frames + 1):
        ref = scene_dir / "reference" / f"{f:04d}.exr"
        if not ref.is_file():
            continue
        now = read_frame(scene_dir / "passes" / f"{f:04d}.exr")
        before = read_frame(scene_dir / "passes" / f"{f - 1:04d}.exr")
        y_now, y_before = now.lighting.sum(axis=-1), before.lighting.sum(axis=-1)
        with np.errstate(divide="ignore", invalid="ignore"):
            change = np.abs(y_now - y_before) > 0.2 * np.maximum(y_now, y_before)
        band = change.copy()
        for _ in range(2):
            grown = band.copy()
            grown[1:] |= band[:-1]
            grown[:-1] |= band[1:]
            grown[:, 1:] |= band[:, :-1]
            grown[:, :-1] |= band[:, 1:]
            band = grown
        reference = read_result(ref)
        band &= reference["Mask"] > 0
        # Only frames where something moved in a part of the picture, not a global flash.
        if band.sum() < 20 or band.mean() > 0.5 * (reference["Mask"] > 0).mean():
            continue
        for m in methods:
            res = scene_dir / m / f"{f:04d}.exr"
            if res.is_file():
                values[m].append(psnr(read_result(res)["Composite"], reference["Composite"], band))
    if not all(values.get(m) for m in methods):
        return None
    return {m: float(np.mean(values[m])) for m in methods}


def conclusion(rows: Sequence[dict]) -> str:
    """One sentence on the equal-time table: who wins at the least time and at the best quality."""
    if not rows:
        return ""
    best = max(rows, key=lambda r: r["psnr_gt_db"])
    fastest = min(rows, key=lambda r: r["seconds"])
    ours = [r for r in rows if not r["what"].startswith("Cycles")]
    best_ours = max(ours, key=lambda r: r["psnr_gt_db"]) if ours else None
    text = (
        f"closest to Cycles ground truth: {best['what']} ({best['psnr_gt_db']:.1f} dB, "
        f"{best['seconds']:.2f} s/frame); fastest: {fastest['what']} ({fastest['seconds']:.2f} "
        f"s/frame, {fastest['psnr_gt_db']:.1f} dB)"
    )
    if best_ours is not None and best_ours is not best:
        text += (
            f"; our best: {best_ours['what']} ({best_ours['psnr_gt_db']:.1f} dB, "
            f"{best_ours['seconds']:.2f} s/frame)"
        )
    return text + "."

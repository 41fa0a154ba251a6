"""The demo against Cycles: ground truth, denoised passes and the equal-time comparison.

For each Blender demo scene (issue "Faithful to Cycles"), beside the passes:

``ground_truth/####.exr``
    Cycles with its own Christensen-Burley subsurface on, ``samples`` per
    pixel, denoising off, on every ``every``-th frame (frames 1, 1 + every, …).
``denoised/passes/####.exr``
    The same SSS-off passes with Blender's OIDN on the passes the post reads
    (``--denoise-passes``), for frames 1 … the last equal-time frame.
``equal_time/cycles_<spp>[_oidn]/####.exr``
    Cycles with subsurface on at 16/32/64/128 spp, without and with OIDN, on
    the equal-time frames: what a user would render instead of us.
``timing.json``
    Wall time per frame of every render above (seconds, this machine).

:func:`equal_time_rows` turns them, with the metrics of the post-process
runs, into the equal-time table: wall time per frame and PSNR against the
ground truth on SSS pixels, for Cycles and for SSS-off passes + each method.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.eval.metrics import psnr_gt
from ...core.eval.users_frame import TRUTH_SAMPLES
from ...core.io.atomic import write_text
from ...core.io.exr import read_combined, read_result

Log = Callable[[str], None] | None


@dataclass(frozen=True)
class TruthPlan:
    """What the demo renders against Cycles (see the module doc).

    Attributes
    ----------
    every : ground truth on every k-th frame (0: none)
    samples : ground-truth samples per pixel (docs/explanation/accuracy.md: >= 1024)
    equal_time_frames : frames of the equal-time table (must carry ground truth)
    equal_time_spp : Cycles samples per pixel compared
    users_frames : frames of the "what you had / what you get" table (0: none;
        :mod:`.demo.users`)
    users_samples : samples per pixel of that table's ground truth (it judges denoised
        frames, whose error is small beside a 1024-spp ground truth's noise:
        :data:`core.eval.users_frame.TRUTH_SAMPLES`)
    """

    every: int = 20
    samples: int = 1024
    equal_time_frames: tuple[int, ...] = (21, 41)
    equal_time_spp: tuple[int, ...] = (16, 32, 64, 128)
    methods: tuple[str, ...] = field(default=("none", "separable", "as_ccv", "as_ccv_t"))
    users_frames: int = 2
    users_samples: int = TRUTH_SAMPLES

    def ground_truth_frames(self, frames: int) -> list[int]:
        return [] if self.every < 1 else list(range(1, frames + 1, self.every))

    def table_frames(self, frames: int) -> list[int]:
        gt = set(self.ground_truth_frames(frames))
        return [f for f in self.equal_time_frames if f in gt]


def read_timing(scene_dir: Path) -> dict:
    try:
        return json.loads((Path(scene_dir) / "timing.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}


def write_timing(scene_dir: Path, timing: dict) -> None:
    write_text(Path(scene_dir) / "timing.json", json.dumps(timing, indent=2, sort_keys=True))


def render_truth(scene, scene_dir: Path, frames: int, plan: TruthPlan, log: Log = None) -> None:
    """Render the ground truth, the denoised passes and the Cycles equal-time frames.

    ``scene`` is the built demo scene (bpy); frames already on disk with the
    same settings are reused. Timings go to ``timing.json``.
    """
    # Imported here: they import bpy, which the rest of the demo (synthetic source) runs without.
    from ..blender import ground_truth as gt
    from ..blender import materials as sss_materials
    from ..blender import render

    scene_dir = Path(scene_dir)
    timing = read_timing(scene_dir)
    view_layer = render.render_view_layer(scene)
    mats = sss_materials.participating(scene, view_layer)
    folder = scene_dir / "ground_truth"
    for f in plan.ground_truth_frames(frames):
        if gt.ground_truth_done(folder, f, plan.samples, "BURLEY"):
            continue
        t0 = time.perf_counter()
        # The demo's materials are Christensen-Burley: forced, its records stay valid.
        gt.render_ground_truth(scene, f, folder, mats, view_layer, plan.samples, "BURLEY")
        timing.setdefault("ground_truth", {})[str(f)] = time.perf_counter() - t0
        write_timing(scene_dir, timing)
        if log:
            log(f"ground truth {f}: {timing['ground_truth'][str(f)]:.1f} s ({plan.samples} spp)")
    table = plan.table_frames(frames)
    if not table:
        return
    job = render.make_job(
        scene, (1, max(table)), scene_dir / "denoised", methods=("none",), denoise_passes=True
    )
    for step in render.iter_passes(job):
        if step.rendered:
            timing.setdefault("denoised", {})[str(step.frame)] = step.seconds
    write_timing(scene_dir, timing)
    for spp in plan.equal_time_spp:
        for oidn in (False, True):
            name = f"cycles_{spp}" + ("_oidn" if oidn else "")
            for f in table:
                path = scene_dir / "equal_time" / name / f"{f:04d}.exr"
                record = path.with_suffix(".json")
                if path.is_file() and record.is_file() and str(f) in timing.get(name, {}):
                    continue
                t0 = time.perf_counter()
                gt.render_ground_truth(
                    scene, f, path.parent, mats, view_layer, spp, "BURLEY", denoise=oidn
                )
                timing.setdefault(name, {})[str(f)] = time.perf_counter() - t0
                write_timing(scene_dir, timing)
    if log:
        log(f"equal-time frames {', '.join(map(str, table))}: Cycles at {plan.equal_time_spp} spp")


def _rows(path: Path) -> list[dict]:
    with open(path, newline="", encoding="utf-8") as fh:
        return list(csv.DictReader(fh))


def _mean(values) -> float:
    values = [v for v in values if v == v]
    return float(np.mean(values)) if values else float("nan")


def equal_time_rows(scene_dir: Path, frames: int, plan: TruthPlan, pass_samples: int) -> list[dict]:
    """The equal-time table of one scene: ``{"what", "seconds", "psnr_gt_db"}`` rows.

    Wall time per frame: Cycles renders as timed; ours = the pass render
    (mean over the frames rendered in this run, ``timing.json``) plus the
    method's post-process (``frame_ms`` of metrics.csv, mean over the table's
    frames). PSNR against the ground truth over SSS pixels (the passes'
    SSS mask), mean over the table's frames.
    """
    scene_dir = Path(scene_dir)
    table = plan.table_frames(frames)
    timing = read_timing(scene_dir)
    if not table:
        return []
    truth = {f: read_combined(scene_dir / "ground_truth" / f"{f:04d}.exr") for f in table}
    masks = {
        f: read_result(scene_dir / "none" / f"{f:04d}.exr")["Mask"] > 0
        for f in table
        if (scene_dir / "none" / f"{f:04d}.exr").is_file()
    }
    out = []
    for spp in plan.equal_time_spp:
        for oidn in (False, True):
            name = f"cycles_{spp}" + ("_oidn" if oidn else "")
            psnrs, secs = [], []
            for f in table:
                path = scene_dir / "equal_time" / name / f"{f:04d}.exr"
                if not path.is_file() or f not in masks:
                    continue
                psnrs.append(psnr_gt(read_combined(path), truth[f], masks[f]))
                secs.append(timing.get(name, {}).get(str(f), float("nan")))
            if psnrs:
                what = f"Cycles subsurface, {spp} spp" + (" + OIDN" if oidn else "")
                out.append({"what": what, "seconds": _mean(secs), "psnr_gt_db": _mean(psnrs)})
    for label, sub, key in (
        (f"SSS-off passes ({pass_samples} spp)", scene_dir, "passes"),
        (f"SSS-off passes ({pass_samples} spp) + OIDN", scene_dir / "denoised", "denoised"),
    ):
        if not (sub / "metrics.csv").is_file():
            continue
        pass_s = _mean(list(timing.get(key, {}).values()))
        rows = [r for r in _rows(sub / "metrics.csv") if int(r["frame"]) in table]
        for method in plan.methods:
            mine = [r for r in rows if r["method"] == method]
            if not mine:
                continue
            post = _mean([float(r["frame_ms"]) / 1e3 for r in mine if r.get("frame_ms")])
            psnr = _mean([float(r["psnr_gt_db"]) for r in mine if r.get("psnr_gt_db")])
            out.append(
                {"what": f"{label} + {method}", "seconds": pass_s + post, "psnr_gt_db": psnr}
            )
    return out


def format_equal_time(rows: Sequence[dict]) -> str:
    """Markdown table of :func:`equal_time_rows`."""
    lines = [
        "| what | s / frame | PSNR vs Cycles GT, SSS pixels (dB) |",
        "| --- | ---: | ---: |",
    ]
    for r in rows:
        lines.append(f"| {r['what']} | {r['seconds']:.2f} | {r['psnr_gt_db']:.2f} |")
    return "\n".join(lines)

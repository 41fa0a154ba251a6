"""The demo's "what you had / what you get" table: ``cvsss compare`` on each demo scene.

Issue 44 measures every change by the user's frame against what they had.
For each Blender demo scene (with its ground truth on), on a few consecutive
frames from the first equal-time frame (21), the demo renders what a user
of the saved ``<scene>.blend`` gets with F12 or ``blender -b -a``:

- plain Cycles at the scene's samples (16) with Blender's denoiser, and
  plain EEVEE at its render samples (16);
- Apply on Render with the add-on's default settings on each engine (its
  warm-up frames and set-up included in the time, as the user pays them);
- each engine without subsurface (for the subsurface effect);

and Cycles' ground truth with and without subsurface at
``--compare-ground-truth-spp`` samples (:mod:`...blender.compare`). The files are under
``<scene>/users_frame/``; the rows and targets go to ``truth.json``
(``users_frame``) and the table to ``report.md``.

Cost, per scene and frame compared, at 320×180 on 2 cores: two ground-truth
renders (with and without subsurface; their time grows with the samples, about
40 s and 30 s at 1024 spp, four times that at the default 4096) and the EEVEE
renders (about 25 s each at 16 samples on a CPU without a GPU);
``--compare-frames 0`` (Makefile ``COMPARE_FRAMES=0``) leaves the table out.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from pathlib import Path

from ....core.eval.users_table import format_table, format_targets

#: First frame compared (the first equal-time frame: the scenes' lights have started).
FIRST = 21


def compare_range(frames: int, count: int, first: int = FIRST) -> tuple[int, int] | None:
    """The ``count`` consecutive frames compared in a demo of ``frames`` frames (1 …
    frames): from ``first`` when they fit, else the last ``count``; None for none.

    >>> compare_range(120, 2), compare_range(3, 2), compare_range(3, 0)
    ((21, 22), (2, 3), None)
    """
    if count < 1 or frames < 1:
        return None
    count = min(count, frames)
    start = first if first + count - 1 <= frames else frames - count + 1
    return start, start + count - 1


def users_frame(
    scene_name: str,
    scene_dir: Path,
    frames: int,
    count: int,
    truth_samples: int,
    log: Callable[[str], None] | None,
) -> dict | None:
    """Run the comparison of the module doc on ``<scene_dir>/<scene_name>.blend``.

    Returns
    -------
    dict with ``frames``, ``rows``, ``targets`` and ``describe`` (the report's
    paragraph), or None when ``count`` is 0.
    """
    span = compare_range(frames, count)
    if span is None:
        return None
    # Imported here: they import bpy, which the synthetic demo runs without.
    import bpy

    from ...blender.compare import compare_scene, describe
    from ...blender.standalone import ensure_registered
    from ...blender.users_frame import Setting

    unregister = ensure_registered()
    try:
        bpy.ops.wm.open_mainfile(filepath=str(Path(scene_dir) / f"{scene_name}.blend"))
        report = compare_scene(
            bpy.context.scene,
            span,
            Path(scene_dir) / "users_frame",
            [Setting("CYCLES", None, denoise=True), Setting("EEVEE", None)],
            ("material",),
            truth_samples=truth_samples,
            log=(lambda text: log(f"{scene_name}: {text}")) if log else None,
        )
    finally:
        if unregister is not None:
            unregister()
    return {
        "frames": report["frames"],
        "rows": report["rows"],
        "targets": report["targets"],
        "describe": describe(report),
    }


def format_users_frame(scene: str, extra: dict, reference: dict | None = None) -> list[str]:
    """The report's section of one scene: the paragraph, the table, the targets.

    ``reference``: the scene's summary row of the ``reference`` method (its PSNR against
    the ground truth); where a PSNR target is missed, the section gives the PSNR the
    post's converged estimate itself reaches against Cycles, a ceiling no sample count
    or denoiser lifts.
    """
    frames = extra["frames"]
    lines = [
        "",
        f"### {scene}: what you had / what you get (frames {frames[0]}-{frames[-1]})",
        "",
        extra["describe"],
        "",
        format_table(extra["rows"]),
        "",
        format_targets(extra["targets"]) or "(no target applies)",
    ]
    missed = any(t["met"] is False and "time" not in t["target"] for t in extra["targets"])
    sss = (reference or {}).get("psnr_gt_db", math.nan)
    whole = (reference or {}).get("psnr_gt_full_db", math.nan)
    if missed and math.isfinite(sss):
        lines += [
            "",
            f"The post's converged estimate on this scene's raw passes (`reference`, 1024 "
            f'spp, over the ground-truth frames; the table "Against Cycles ground truth" '
            f"above) reaches {sss:.2f} dB PSNR against Cycles on subsurface pixels, "
            f"{whole:.2f} dB whole: the screen-space model's ceiling on this scene, which no "
            "sample count or denoiser lifts.",
        ]
    return lines

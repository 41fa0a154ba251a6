"""What the user had against what they get, on their own scene: ``cvsss compare``.

:func:`compare_scene` renders a scene's frames with every :class:`.users_frame.Setting`
and method variant asked for — plain, with Apply on Render, and without
subsurface (:mod:`.users_frame`) — and Cycles' ground truth with and without
subsurface, measures every frame (:mod:`core.eval.users_frame`) and writes
``users_frame.json`` and ``users_frame.md`` (:mod:`core.eval.users_table`:
the table, issue 44's targets and, for a missed one, the figures beside it,
down to each object's subsurface pixels).

Layout under the output folder::

    users_frame.json, users_frame.md
    ground_truth/<variant>/####.exr   Cycles with subsurface (+ ####.json: what it is of)
    ground_truth/off/####.exr         Cycles without subsurface
    ground_truth/objects/####.exr     which object each pixel shows (+ ####.json: the names)
    renders/<setting>/off_####.exr            the setting without subsurface
    renders/<setting>/<variant>_plain_####.exr
    renders/<setting>/<variant>_apply_on_render_####.exr

Ground-truth frames whose record matches (same .blend, samples, method) are
reused; the user's renders are always made again, as they are timed. The ground
truth takes :data:`TRUTH_SAMPLES` samples per pixel unless told otherwise.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import bpy
import numpy as np

from ...core.eval.users_frame import TRUTH_SAMPLES, frame_figures, mean_figures, object_errors
from ...core.eval.users_table import check_targets, format_table, format_targets
from ...core.io.atomic import write_text
from ...core.io.exr import read_pass, read_rgb
from .. import precompile
from . import materials as sss_materials
from . import thin_parts
from .apply_on_render.session import warm_up_pays
from .errors import RenderError
from .passes import output_size, render_view_layer
from .properties import settings_to_params
from .users_frame import (
    SEED,
    MethodSwitch,
    Setting,
    Timing,
    blend_digest,
    frame_file,
    materials_method,
    render_objects,
    render_truth,
    render_user,
    resolve_variants,
)

Log = Callable[[str], None] | None

#: Value of the ``format`` field of ``users_frame.json``.
REPORT_FORMAT = "cvsss-users-frame/1"


def apply_on_render_settings(scene) -> dict:
    """The add-on settings Apply on Render renders with (the scene's)."""
    s = scene.sss_settings
    return {
        "method": s.method,
        # The warm-up it runs before an animation: none for a method reusing no estimates.
        "warmup_frames": int(s.warmup_frames) if warm_up_pays(s.method) else 0,
        "denoise_passes": bool(s.use_denoise_passes),
        # On EEVEE passes: the finished frame's subsurface pixels denoised.
        "denoise_subsurface": bool(s.use_denoise_subsurface),
        # Who renders the subsurface of parts thin for their Random Walk material.
        "thin_walks": s.thin_walks,
    }


def load_kernels(scene, log: Log) -> float:
    """Load (or compile) the numba kernels Apply on Render will use; seconds.

    A Blender session pays this once, at its first Apply on Render frame; it is
    measured apart so that it does not land on whichever setting is rendered first.
    """
    settings = scene.sss_settings
    params = settings_to_params(settings, settings.method)
    width, height = output_size(scene)
    began = time.perf_counter()
    precompile.ensure_compiled(params.backend, (settings.method,), width * height, log)
    return time.perf_counter() - began


class _Comparison:
    """One scene's comparison: its materials, variants, frames and folders."""

    def __init__(self, scene, frames, out: Path, variants, truth_samples: int, log: Log):
        if scene.camera is None:
            raise RenderError(f"scene {scene.name!r} has no active camera")
        self.scene = scene
        self.view_layer = render_view_layer(scene)
        self.materials = sss_materials.scene_materials(scene, self.view_layer)
        taking_part = sss_materials.participating(scene, self.view_layer)
        if not taking_part:
            raise RenderError(f"scene {scene.name!r} has no material with subsurface")
        self.own = materials_method(taking_part)
        self.pairs = resolve_variants(variants, self.own)
        self.numbers = list(range(frames[0], frames[1] + 1))
        self.frames = frames
        self.out = Path(out)
        self.truth = self.out / "ground_truth"
        self.renders = self.out / "renders"
        self.truth_samples = int(truth_samples)
        self.say = log or (lambda _text: None)
        self.rows: list[dict] = []
        self.objects: dict[int, tuple] = {}  # frame -> (Object Index (H, W), {number: name})

    def _switch(self, variant: str, method: str) -> MethodSwitch:
        return MethodSwitch(self.materials, None if variant == "material" else method)

    def _truth_frame(self, folder: str, frame: int, method: str, subsurface: bool) -> None:
        scene = self.scene
        record = {
            "subsurface": method if subsurface else "off",
            "blend_sha256": blend_digest(bpy.data.filepath),
            "size": list(output_size(scene)),
            "scene": scene.name,
        }
        began = time.perf_counter()
        rendered = render_truth(
            scene,
            self.view_layer,
            frame,
            self.truth / folder / f"{frame:04d}.exr",
            self.truth_samples,
            subsurface=subsurface,
            materials=self.materials,
            record=record,
        )
        if rendered:
            what = f"{folder} ({method})" if subsurface else "without subsurface"
            self.say(f"ground truth {what}, frame {frame}: {time.perf_counter() - began:.1f} s")

    def render_truths(self) -> None:
        for variant, method in self.pairs:
            with self._switch(variant, method):
                for f in self.numbers:
                    self._truth_frame(variant, f, method, subsurface=True)
        for f in self.numbers:
            self._truth_frame("off", f, self.own, subsurface=False)
        for f in self.numbers:
            path = self.truth / "objects" / f"{f:04d}.exr"
            names = render_objects(self.scene, self.view_layer, f, path, self.materials)
            index = read_pass(path, "Object Index")
            self.objects[f] = (np.rint(index).astype(np.int64), names)

    def _render(self, setting: Setting, prefix: Path, kind: str) -> Timing:
        timing = render_user(
            self.scene,
            self.view_layer,
            setting,
            self.frames,
            prefix,
            apply_on_render=kind == "apply_on_render",
            subsurface=kind != "off",
            materials=self.materials,
        )
        self.say(
            f"{prefix.parent.name} {prefix.name.rstrip('_')}: "
            f"{timing.to_dict()['seconds_per_frame']:.2f} s / frame"
        )
        return timing

    def render_setting(self, setting: Setting) -> None:
        """The setting without subsurface, then plain and Apply on Render per variant (one
        after the other, so that both meet the machine in the same state)."""
        folder = self.renders / setting.folder
        off = self._render(setting, folder / "off_", "off")
        for variant, method in self.pairs:
            with self._switch(variant, method):
                timings = {
                    kind: self._render(setting, folder / f"{variant}_{kind}_", kind)
                    for kind in ("plain", "apply_on_render")
                }
                whole = self._whole(setting)
            for kind, timing in timings.items():
                self._measure(kind, setting, variant, method, folder / f"{variant}_{kind}_", timing)
                if kind == "apply_on_render":
                    self.rows[-1]["cycles_renders"] = whole
            self._measure("off", setting, variant, method, folder / "off_", off)

    def _whole(self, setting: Setting) -> list[str]:
        """The objects whose subsurface Cycles renders in Apply on Render's frame of
        ``setting``, the method variant applied (:func:`.thin_parts.thin_objects`)."""
        settings = self.scene.sss_settings
        if not thin_parts.cycles_renders(settings.thin_walks, setting.engine):
            return []
        return [obj.name for obj, _ in thin_parts.thin_objects(self.scene)]

    def _measure(self, kind, setting: Setting, variant, method, prefix: Path, timing) -> None:
        figures = {}
        objects: dict[str, dict] = {}
        off_prefix = self.renders / setting.folder / "off_"
        for f in self.numbers:
            frame = read_rgb(frame_file(prefix, f))
            truth = read_rgb(self.truth / variant / f"{f:04d}.exr")
            truth_off = read_rgb(self.truth / "off" / f"{f:04d}.exr")
            frame_off = read_rgb(frame_file(off_prefix, f))
            figures[f] = frame_figures(frame, truth, truth_off, frame_off)
            index, names = self.objects[f]
            errors = object_errors(frame, truth, truth_off, index, frame_off, figures[f])
            for number, sums in errors.items():
                total = objects.setdefault(names.get(number, ""), dict.fromkeys(sums, 0))
                for key, value in sums.items():
                    total[key] += value
        row = {
            "kind": kind,
            "engine": setting.engine,
            "samples": setting.samples,
            "denoise": setting.denoise,
            "variant": variant,
            "method": method,
            "frames": self.numbers,
            "figures": {str(f): v.to_dict() for f, v in figures.items()},
            "mean": mean_figures(list(figures.values())),
            "objects": objects,
            **timing.to_dict(),
        }
        if kind == "apply_on_render":
            row["post_method"] = self.scene.sss_settings.method
        self.rows.append(row)


def compare_scene(
    scene,
    frames: tuple[int, int],
    out: str | Path,
    settings: Sequence[Setting],
    variants: Sequence[str] = ("material",),
    truth_samples: int = TRUTH_SAMPLES,
    log: Log = print,
) -> dict:
    """Render ``scene``'s frames every way of the module doc, measure, write the report.

    Parameters
    ----------
    scene : bpy.types.Scene, with a camera and at least one subsurface material
    frames : (first, last), inclusive
    out : folder of the module doc's layout
    settings : the engines and samples to compare (:class:`.users_frame.Setting`;
        samples None: the scene's)
    variants : method variants (:data:`.users_frame.VARIANTS`)
    truth_samples : the ground truth's samples per pixel
    log : progress printer, or None

    Returns
    -------
    dict, the report as written to ``users_frame.json``: ``rows`` (the table's,
    :mod:`core.eval.users_table`), ``targets`` and what was compared.

    Raises
    ------
    RenderError
        No camera, no subsurface material, a cancelled or refused render.
    """
    run = _Comparison(scene, frames, out, variants, truth_samples, log)
    settings = list(dict.fromkeys(s.resolved(scene) for s in settings))
    run.render_truths()
    kernels = load_kernels(scene, log)
    for setting in settings:
        run.render_setting(setting)
    report = {
        "format": REPORT_FORMAT,
        "scene": scene.name,
        "blend": bpy.data.filepath or None,
        "frames": run.numbers,
        "size": list(output_size(scene)),
        "blender": bpy.app.version_string,
        "materials_method": run.own,
        "ground_truth": {"engine": "CYCLES", "samples": run.truth_samples, "seed": SEED},
        "apply_on_render": apply_on_render_settings(scene),
        "kernel_seconds": kernels,
        "rows": run.rows,
        "targets": check_targets(run.rows),
    }
    write_report(run.out, report)
    return report


def write_report(out: Path, report: dict) -> None:
    """``users_frame.json`` (NaN as null) and ``users_frame.md``."""
    out = Path(out)
    write_text(out / "users_frame.json", json.dumps(finite(report), indent=2) + "\n")
    text = [
        f"# {report['scene']}: what you had, what you get",
        "",
        describe(report),
        "",
        format_table(report["rows"]),
        "",
        format_targets(report["targets"]) or "(no target applies to these settings)",
        "",
    ]
    write_text(out / "users_frame.md", "\n".join(text))


def describe(report: dict) -> str:
    """The paragraph above the table: frames, ground truth, Apply on Render, the rules."""
    aor = report["apply_on_render"]
    width, height = report["size"]
    frames = report["frames"]
    return (
        f"Frames {frames[0]}-{frames[-1]} at {width}x{height}. Ground truth: Cycles, "
        f"{report['ground_truth']['samples']} spp, with the subsurface method the row's "
        f"materials have (their own: {report['materials_method']}; a Random Walk or "
        "Christensen-Burley row switches every Principled BSDF, ground truth included), "
        "denoising off, seed "
        f"{report['ground_truth']['seed']}. Apply on Render: {aor['method']}, warm-up "
        f"{aor['warmup_frames']} frame(s) before an animation"
        f"{'; on EEVEE its subsurface pixels denoised' if aor.get('denoise_subsurface') else ''}"
        f"{'; thin parts left to Cycles' if aor.get('thin_walks') == 'CYCLES' else ''}"
        ". PSNR in display space (exposure 1/p99 of the "
        "ground truth's brightest channel, sRGB, clipped); subsurface pixels: the ground truth "
        "with and without subsurface differ by more than 1 % of its peak; effect: the change "
        "subsurface makes, scaled to Cycles' lighting, against Cycles' change. s / frame: wall "
        "time of the render over the frames delivered, set-up and warm-up included (in "
        "brackets: after the first frame began). The compiled passes were loaded once before, in "
        f"{report['kernel_seconds']:.2f} s."
    )


def finite(value):
    """``value`` with NaN and infinities as None, in nested dicts and lists (JSON has neither)."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [finite(v) for v in value]
    return value

"""Where the demo's passes come from: the demo_blend scenes rendered by Blender, or the
analytic scenes of core.synthetic; and the stamp that says whether passes on disk fit.

Pass frames already on disk are reused when they were made with the same
settings (``<out>/<scene>/demo.json``); changed settings or ``overwrite``
make them again (:func:`pass_cache`).
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path

from ....core.io.atomic import make_folder, write_text
from ....core.io.exr import write_passes
from ....core.synthetic import sequence
from ..truth import TruthPlan, read_timing, render_truth, write_timing

SYNTHETIC_SCENES = ("flash", "regular")
BLENDER_SCENES = ("flash", "regular", "boids")
#: Where the passes come from -> the scenes it offers.
SOURCES = {"blender": BLENDER_SCENES, "synthetic": SYNTHETIC_SCENES}
#: Cycles samples per pixel of the demo passes (the same noisy input for every method).
CYCLES_SAMPLES = 16


class DemoError(RuntimeError):
    """A demo run that cannot go on (bad option, Blender missing, render refused)."""


def pass_cache(
    scene_dir: Path, stamp: dict, overwrite: bool, log: Callable[[str], None] | None
) -> Path:
    """Keep the pass frames of ``scene_dir`` only if they were made with ``stamp``'s settings.

    Frames made with other (or unknown) settings, or all with ``overwrite``,
    are deleted; the new stamp is written before any frame is made, so an
    interrupted run continues with the same settings. When only the pass
    configuration changed (``pass_format``: the passes the renderer writes),
    only the passes and the denoised passes go: the ground truth and the
    equal-time frames were rendered from the same scene and stay.
    """
    passes = scene_dir / "passes"
    stamp_path = scene_dir / "demo.json"
    try:
        old = json.loads(stamp_path.read_text())
    except (OSError, ValueError):
        old = None
    # The passes and everything rendered beside them (ground truth, denoised
    # passes, equal-time frames, their timings) were made from the same scene.
    made = [passes, scene_dir / "denoised/passes"]
    same_scene = not overwrite and isinstance(old, dict) and _same_scene(old, stamp)
    if not same_scene:
        made += [scene_dir / "ground_truth", scene_dir / "equal_time"]
    frames = [
        p
        for folder in made
        if folder.is_dir()
        for p in folder.rglob("*")
        if p.suffix in (".exr", ".json") and p.is_file()
    ]
    if (scene_dir / "timing.json").is_file() and not same_scene:
        frames.append(scene_dir / "timing.json")
    if frames and (overwrite or old != stamp):
        if log:
            why = (
                "--overwrite"
                if overwrite
                else (f"made with other settings ({stamp_path})" if old else "of unknown origin")
            )
            log(f"{stamp['scene']}: removing {len(frames)} pass file(s) {why}; making them again")
        for path in frames:
            path.unlink()
    make_folder(passes)
    write_text(stamp_path, json.dumps(stamp, indent=2))
    return passes


#: Stamp entries that only the pass render depends on (not the ground truth).
_PASS_ONLY = ("pass_format",)


def _same_scene(old: dict, new: dict) -> bool:
    """The two stamps differ at most in how the passes are rendered (:data:`_PASS_ONLY`)."""

    def scene(stamp: dict) -> dict:
        return {k: v for k, v in stamp.items() if k not in _PASS_ONLY}

    return scene(old) == scene(new)


def synthetic_passes(
    scene: str,
    scene_dir: Path,
    width: int,
    height: int,
    frames: int,
    overwrite: bool,
    log: Callable[[str], None] | None,
) -> None:
    stamp = {
        "source": "synthetic",
        "scene": scene,
        "width": width,
        "height": height,
        "frames": frames,
    }
    passes = pass_cache(scene_dir, stamp, overwrite, log)
    for frame in sequence(scene, frames, width, height):
        path = passes / f"{frame.number:04d}.exr"
        if not path.exists():
            write_passes(path, frame, overwrite=True)


def blender_passes(
    scene_name: str,
    scene_dir: Path,
    width: int,
    height: int,
    frames: int,
    *,
    engine: str = "CYCLES",
    samples: int = CYCLES_SAMPLES,
    overwrite: bool = False,
    log: Callable[[str], None] | None = print,
    truth: TruthPlan | None = None,
) -> Path:
    """Build the demo ``scene_name`` in a fresh file and render its passes.

    Parameters
    ----------
    scene_name : a key of ``demo_blend.scenes.SCENES``
    scene_dir : folder of this scene; passes go to ``scene_dir/passes``
    width, height : render size in pixels
    frames : frames 1..frames at 60 fps
    engine : ``"CYCLES"`` or ``"EEVEE"``
    samples : Cycles samples per pixel (EEVEE: its render samples)
    overwrite : render every frame again
    truth : TruthPlan, optional: also render the Cycles ground truth, the
        denoised passes and the equal-time frames (:mod:`..truth`)

    Returns
    -------
    Path of the pass folder. The current Blender file is replaced by an
    empty one with the built scene (it is never saved over a user's file;
    a copy goes to ``scene_dir/<scene_name>.blend``).
    """
    # Imported here: they import bpy, which the synthetic source runs without.
    import bpy

    from ....demo_blend import scenes
    from ...blender import passes as passes_module
    from ...blender import render, standalone

    scene_dir = Path(scene_dir)
    stamp = {
        "source": "blender",
        "scene": scene_name,
        "width": width,
        "height": height,
        "frames": frames,
        "engine": engine,
        "samples": samples,
        "blender": bpy.app.version_string,
        # A change to the passes rendered makes the passes again (not the ground truth).
        "pass_format": passes_module.PASS_FORMAT,
        # A change to the scene builders makes the frames again.
        "scenes_sha256": hashlib.sha256(Path(scenes.__file__).read_bytes()).hexdigest(),
    }
    pass_cache(scene_dir, stamp, overwrite, log)
    unregister = standalone.ensure_registered()
    try:
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
        scene = bpy.context.scene
        scenes.build(scene_name, scene, frames=frames)
        scene.render.resolution_x, scene.render.resolution_y = width, height
        scene.render.resolution_percentage = 100
        if getattr(scene, "cycles", None) is not None:
            scene.cycles.device = "CPU"
            scene.cycles.samples = samples
        if hasattr(scene, "eevee"):
            scene.eevee.taa_render_samples = samples
        bpy.ops.wm.save_as_mainfile(filepath=str(scene_dir / f"{scene_name}.blend"), copy=True)
        job = render.make_job(
            scene, (1, frames), scene_dir, methods=("as_ccv",), engine=engine, log=log
        )
        timing = read_timing(scene_dir)
        for step in render.iter_passes(job):
            if step.rendered:
                timing.setdefault("passes", {})[str(step.frame)] = step.seconds
        write_timing(scene_dir, timing)
        if truth is not None and engine == "CYCLES":
            render_truth(scene, scene_dir, frames, truth, log)
    except (render.RenderError, ValueError) as exc:
        raise DemoError(f"{scene_name}: {exc}") from None
    except RuntimeError as exc:  # a Blender operator failed (save, bake, render)
        reason = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
        raise DemoError(f"{scene_name}: Blender failed: {reason}") from None
    finally:
        if unregister is not None:
            unregister()
    return scene_dir / "passes"

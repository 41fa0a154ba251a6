"""Apply on Render's time per delivered frame against the plain render's (issue 44).

The plain render is Cycles with its own subsurface (Random Walk) and its
denoiser; Apply on Render renders the same scene's passes and delivers the
finished frames, denoised as the scene asks, warm-up included (as the
add-on decides for the method and the *Warm-up Frames* setting). Two cases,
each through ``bpy.ops.render.render`` in background mode as ``blender -b``
runs it, PNG output:

- an animation of ``--frames`` frames (``-a``): seconds per delivered frame;
- an F12 still (``-f``, ``write_still``).

Rounds interleave the four renders (plain and Apply on Render, animation and
still) so that the machine's drift hits both; the first round is not timed
(it compiles the numba passes and loads OpenImageDenoise). It prints the
medians, their ratio and where Apply on Render's time went (the add-on's
steps; the rest is Blender's pass render). From the repository root::

    python tools/measure/apply_on_render_cost.py --size 128x72 --spp 16 --frames 8 --rounds 3
    python tools/measure/apply_on_render_cost.py --size 128x72 --spp 64 --method as_ccv_t
    python tools/measure/apply_on_render_cost.py --compositor --multilayer
    python tools/measure/apply_on_render_cost.py --size 1280x720 --frames 4 --json out.json
    python tools/measure/apply_on_render_cost.py --blend out/users/boids.blend \
        --first-frame 21 --method-variant RANDOM_WALK --rounds 5

(``make bench`` runs it at 640×360 and 1280×720 and keeps the JSON beside the
bench's results: issue 46's Apply on Render cost.)

(``--compositor``: a compositor of a few nodes reading a pass; ``--multilayer``: a
multilayer EXR of a few passes, Cryptomatte among them, instead of PNG; ``--blend``:
a saved scene instead of the built one, e.g. one of
``tools/measure/users_frame_scenes.py``, rendered at ``--size`` and ``--spp`` with
Cycles' denoiser on, from ``--first-frame``; ``--method-variant``: every Principled
BSDF switched to that subsurface method, as ``cvsss compare --method-variants`` does.)

(``python`` with ``bpy`` 5.0 and the ``cvsss`` package importable.)
"""

from __future__ import annotations

import argparse
import collections
import functools
import json
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import bpy

sys.path.insert(0, str(Path(__file__).resolve().parent))
from scene import build_scene

import cvsss
from cvsss.sss_addon.blender.apply_on_render import session as aor_session
from cvsss.sss_addon.blender.users_frame import MethodSwitch

#: Seconds spent in the add-on's steps of the render being timed (name -> total).
SPENT: collections.Counter = collections.Counter()


def _timed(name: str, function):
    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        began = time.perf_counter()
        try:
            return function(*args, **kwargs)
        finally:
            SPENT[name] += time.perf_counter() - began

    return wrapper


def _timed_steps(name: str, function):
    """The same for a generator function: the time spent inside its steps."""

    @functools.wraps(function)
    def wrapper(*args, **kwargs):
        steps = function(*args, **kwargs)
        while True:
            began = time.perf_counter()
            try:
                item = next(steps)
            except StopIteration:
                SPENT[name] += time.perf_counter() - began
                return
            SPENT[name] += time.perf_counter() - began
            yield item

    return wrapper


def instrument() -> None:
    """Time the session's steps (the pass render is Blender's own, the rest)."""
    session = aor_session.Session
    session.warm_up_steps = _timed_steps("warm-up", session.warm_up_steps)
    session.process_next = _timed("post-process (incl. denoise)", session.process_next)
    denoiser = aor_session.FrameDenoiser
    denoiser.finished = _timed("  of which denoise", denoiser.finished)
    session.deliver_next = _timed("delivery", session.deliver_next)
    session.display = _timed("delivery", session.display)


def render(scene, out: Path, apply: bool, still: bool) -> float:
    """Seconds of one render of ``scene`` (animation or still) into ``out``."""
    scene.sss_settings.apply_on_render = apply
    scene.render.filepath = str(out / ("still" if still else "f_"))
    began = time.perf_counter()
    result = bpy.ops.render.render(animation=not still, write_still=still)
    seconds = time.perf_counter() - began
    if "FINISHED" not in result:
        raise SystemExit(f"the render did not finish: {result}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", default="128x72", help="WxH pixels (default 128x72)")
    parser.add_argument("--spp", type=int, default=16, help="Cycles samples (default 16)")
    parser.add_argument("--frames", type=int, default=8, help="animation length (default 8)")
    parser.add_argument("--rounds", type=int, default=3, help="timed rounds (default 3)")
    parser.add_argument("--method", default="as_ccv", help="cvsss method (default as_ccv)")
    parser.add_argument(
        "--warmup", type=int, default=None, help="Warm-up Frames (default: the setting's default)"
    )
    parser.add_argument(
        "--compositor",
        action="store_true",
        help="a compositor on the render (Color Balance, Glare, the Mist pass mixed in)",
    )
    parser.add_argument(
        "--multilayer",
        action="store_true",
        help="32-bit multilayer EXR output with Normal, Mist, Object Index and Cryptomatte "
        "passes (instead of PNG)",
    )
    parser.add_argument("--json", type=Path, help="also write the medians and runs here")
    parser.add_argument("--blend", type=Path, help="render this .blend's scene (never saved)")
    parser.add_argument(
        "--first-frame", type=int, default=None, help="with --blend: the first frame rendered"
    )
    parser.add_argument(
        "--method-variant",
        choices=("RANDOM_WALK", "BURLEY", "RANDOM_WALK_SKIN"),
        help="every Principled BSDF switched to this subsurface method",
    )
    args = parser.parse_args()
    width, height = (int(v) for v in args.size.lower().split("x"))
    if args.blend is None:
        scene = build_scene(width, height, args.spp, args.frames)
    else:
        scene = open_scene(args.blend, width, height, args.spp, args.frames, args.first_frame)
    cvsss.register()
    if args.method_variant:
        switch_methods(args.method_variant)
    settings = scene.sss_settings
    settings.method = args.method
    if args.warmup is not None:
        settings.warmup_frames = args.warmup
    scene.render.image_settings.file_format = "PNG"
    if args.multilayer:
        multilayer(scene)
    if args.compositor:
        compositor(scene)
    instrument()
    folder = Path(tempfile.mkdtemp(prefix="cvsss-cost-"))
    times: dict[str, list[float]] = collections.defaultdict(list)
    spent: dict[str, list[collections.Counter]] = collections.defaultdict(list)
    cases = [("animation", False), ("still", True)]
    for index in range(args.rounds + 1):
        for name, still in cases if index % 2 else cases[::-1]:
            for apply in (False, True) if index % 2 else (True, False):
                SPENT.clear()
                seconds = render(scene, folder / f"{index}-{name}-{apply}", apply, still)
                if index:
                    key = f"{name} {'apply' if apply else 'plain'}"
                    times[key].append(seconds)
                    if apply:
                        spent[name].append(SPENT.copy())
    frames = args.frames
    extras = [name for name in ("compositor", "multilayer") if getattr(args, name)]
    if args.blend is not None:
        extras.append(f"{args.blend.name} from frame {scene.frame_start}")
    if args.method_variant:
        extras.append(f"every Principled BSDF {args.method_variant}")
    print(
        f"{width}x{height}, {args.spp} spp, {args.method}, Warm-up Frames "
        f"{settings.warmup_frames}{''.join(', ' + e for e in extras)}; medians of "
        f"{args.rounds} interleaved rounds (load average at the end {_load()}):"
    )
    for name, per in (("animation", frames), ("still", 1)):
        plain = statistics.median(times[f"{name} plain"])
        apply = statistics.median(times[f"{name} apply"])
        what = f"animation of {frames} frames" if name == "animation" else "F12 still"
        print(
            f"  {what}: plain {plain / per:.3f} s per frame, Apply on Render "
            f"{apply / per:.3f} s per frame: ratio {apply / plain:.2f}"
        )
        steps = sorted({k for c in spent[name] for k in c})
        parts = ", ".join(
            f"{k} {statistics.median(c[k] for c in spent[name]) / per:.3f}" for k in steps
        )
        print(f"    Apply on Render's steps (s per frame): {parts}")
    print("  runs (s):", {k: [round(t, 2) for t in v] for k, v in times.items()})
    if args.json:
        per_frame = {"animation": frames, "still": 1}
        summary = {
            "size": f"{width}x{height}",
            "spp": args.spp,
            "method": args.method,
            "frames": frames,
            "warmup_frames": settings.warmup_frames,
            "rounds": args.rounds,
            "extras": extras,
            "load_average_end": _load(),
            "cases": {
                name: {
                    "plain_s_per_frame": statistics.median(times[f"{name} plain"]) / n,
                    "apply_s_per_frame": statistics.median(times[f"{name} apply"]) / n,
                    "ratio": statistics.median(times[f"{name} apply"])
                    / statistics.median(times[f"{name} plain"]),
                }
                for name, n in per_frame.items()
            },
            "runs_s": times,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        temporary = args.json.with_name(args.json.name + ".tmp")
        temporary.write_text(json.dumps(summary, indent=1) + "\n")
        os.replace(temporary, args.json)


def open_scene(path: Path, width: int, height: int, spp: int, frames: int, first: int | None):
    """The scene of the .blend at ``path``: ``width``×``height``, ``spp`` samples with
    Cycles' denoiser, ``frames`` frames from ``first`` (default: its own first frame)."""
    if not path.is_file():
        raise SystemExit(f"error: no such .blend: {path}")
    bpy.ops.wm.open_mainfile(filepath=str(path))
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.cycles.samples = spp
    scene.cycles.use_denoising = True
    if first is not None:
        scene.frame_start = first
    scene.frame_end = scene.frame_start + frames - 1
    return scene


def switch_methods(method: str) -> None:
    """Every Principled BSDF of the file (in node groups too) uses the subsurface ``method``."""
    MethodSwitch(bpy.data.materials, method).__enter__()  # the file is never saved


def multilayer(scene) -> None:
    """32-bit multilayer EXR output of the view layer's passes, a few of them on."""
    layer = scene.view_layers[0]
    layer.use_pass_normal = layer.use_pass_mist = layer.use_pass_object_index = True
    layer.use_pass_cryptomatte_object = True
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    settings.color_depth = "32"


def compositor(scene) -> None:
    """A compositor of the kind a user has: Color Balance and Glare on the image, the Mist
    pass added."""
    layer = scene.view_layers[0]
    layer.use_pass_mist = True
    group = bpy.data.node_groups.new("compositor", "CompositorNodeTree")
    group.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    layers = group.nodes.new("CompositorNodeRLayers")
    layers.scene, layers.layer = scene, layer.name
    balance = group.nodes.new("CompositorNodeColorBalance")
    glare = group.nodes.new("CompositorNodeGlare")
    mix = group.nodes.new("ShaderNodeMix")
    mix.data_type, mix.blend_type = "RGBA", "ADD"
    mix.inputs["Factor"].default_value = 0.1
    out = group.nodes.new("NodeGroupOutput")
    group.links.new(layers.outputs["Image"], balance.inputs["Image"])
    group.links.new(balance.outputs[0], glare.inputs["Image"])
    group.links.new(glare.outputs[0], mix.inputs[6])
    group.links.new(layers.outputs["Mist"], mix.inputs[7])
    group.links.new(mix.outputs[2], out.inputs[0])
    scene.compositing_node_group = group
    scene.render.use_compositing = True


def _load() -> str:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return "?"


if __name__ == "__main__":
    main()

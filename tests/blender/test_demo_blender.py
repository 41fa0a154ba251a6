"""The demo scenes (flash, regular, boids) and `cvsss demo` rendering them with Cycles."""

import csv
import json

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_frame  # noqa: E402
from cvsss.demo_blend import scenes  # noqa: E402
from cvsss.sss_addon.blender import materials  # noqa: E402
from cvsss.sss_addon.cli import main as cli  # noqa: E402
from cvsss.sss_addon.cli.demo import DEMO_METHODS  # noqa: E402

pytestmark = pytest.mark.bpy


def _energies(scene, light, frames):
    out = []
    for f in frames:
        scene.frame_set(f)
        out.append(light.energy)
    return out


def test_regular_lamp_switches_every_3_s_and_candles_flicker(fresh):
    scene = fresh
    scenes.build("regular", scene, frames=430)
    assert (scene.frame_start, scene.frame_end, scene.render.fps) == (1, 430, 60)
    lamp = bpy.data.lights["regular Lamp"]
    # On for t < 1 s, off for 1 <= t < 4 s, on for 4 <= t < 7 s (t = (frame - 1) / 60).
    frames = (1, 60, 61, 120, 240, 241, 300, 420, 421)
    expected = [on * scenes.LAMP_POWER for on in (1, 1, 0, 0, 0, 1, 1, 1, 0)]
    assert _energies(scene, lamp, frames) == pytest.approx(expected)
    candles = [bpy.data.lights[f"regular Candle Light {i}"] for i in range(3)]
    first = [_energies(scene, c, range(1, 41)) for c in candles]
    for values in first:
        assert np.ptp(values) > 0.1 * scenes.CANDLE_POWER  # it flickers…
        assert np.all(np.abs(np.diff(values)) < 0.2 * scenes.CANDLE_POWER)  # …smoothly
    assert first[0] != first[1]  # each candle its own seed
    wax = bpy.data.materials["cvsss Wax"]
    assert wax in materials.participating(scene)
    scenes.build("regular", scene, frames=430)  # deterministic: the same curves again
    candles = [bpy.data.lights[f"regular Candle Light {i}"] for i in range(3)]
    assert [_energies(scene, c, range(1, 41)) for c in candles] == first


def _boid_positions(scene, frame):
    scene.frame_set(frame)
    emitter = bpy.data.objects["boids Emitter"].evaluated_get(bpy.context.evaluated_depsgraph_get())
    particles = emitter.particle_systems[0].particles
    co = np.empty(len(particles) * 3, np.float32)
    particles.foreach_get("location", co)
    return co.reshape(-1, 3)


def test_boids_are_baked_flock_and_replay_identically(fresh):
    scene = fresh
    scenes.build("boids", scene, frames=8)
    emitter = bpy.data.objects["boids Emitter"]
    psys = emitter.particle_systems[0]
    assert psys.settings.physics_type == "BOIDS" and psys.point_cache.is_baked
    a3, a7 = _boid_positions(scene, 3), _boid_positions(scene, 7)
    assert a3.shape == (48, 3) and np.isfinite(a3).all()
    assert np.linalg.norm(a7 - a3, axis=1).mean() > 0.01  # they fly (metres)
    centre = np.array(bpy.data.objects["boids Goal"].location)
    assert np.linalg.norm(a3 - centre, axis=1).max() < 2.0  # around the candle, in view
    # Frame order does not matter once baked, and a rebuild replays the same flight.
    np.testing.assert_array_equal(_boid_positions(scene, 3), a3)
    scenes.build("boids", scene, frames=8)
    np.testing.assert_array_equal(_boid_positions(scene, 7), a7)


def test_demo_renders_the_blender_scene_and_reuses_its_passes(tmp_path):
    out = tmp_path / "demo"
    args = [
        "demo",
        "--out",
        str(out),
        "--scenes",
        "regular",
        "--frames",
        "3",
        "--samples",
        "2",
        "--reference-every",
        "2",
        "--reference-spp",
        "64",
        "--ground-truth-every",
        "2",
        "--ground-truth-spp",
        "16",
    ]
    table = ["--compare-frames", "1", "--compare-ground-truth-spp", "24"]
    assert cli.main([*args, "--res", "32x18", *table]) == 0
    args += ["--compare-frames", "0"]  # the table once: its EEVEE renders are slow on a CPU
    scene_dir = out / "regular"
    passes = sorted(p.name for p in (scene_dir / "passes").glob("*.exr"))
    assert passes == ["0001.exr", "0002.exr", "0003.exr"]
    frame = read_frame(scene_dir / "passes" / "0002.exr")
    assert frame.shape == (18, 32) and (frame.material > 0).any()
    assert (scene_dir / "regular.blend").stat().st_size > 10_000
    stamp = json.loads((scene_dir / "demo.json").read_text())
    assert stamp["width"] == 32 and stamp["samples"] == 2 and stamp["engine"] == "CYCLES"
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["regular"]) == set(DEMO_METHODS)
    rows = list(csv.DictReader(open(scene_dir / "metrics.csv")))
    assert [int(r["frame"]) for r in rows if r["method"] == "reference"] == [1, 3]
    # Cycles ground truth on frames 1 and 3, measured against in the rows of those frames.
    assert sorted(p.name for p in (scene_dir / "ground_truth").glob("*.exr")) == [
        "0001.exr",
        "0003.exr",
    ]
    with_gt = sorted({int(r["frame"]) for r in rows if r["psnr_gt_db"]})
    assert with_gt == [1, 3]
    assert "Against Cycles ground truth" in (out / "report.md").read_text()
    assert "regular: per frame" in (out / "report.md").read_text()
    # The quality knob against the ground truth: as_ccv at each swept σ0² and the default.
    truth = json.loads((out / "truth.json").read_text())["regular"]
    sigmas = [r["sigma0_sq"] for r in truth["quality"]]
    assert sigmas == sorted(sigmas, reverse=True) and 1e-4 in sigmas and len(sigmas) == 4
    assert all(r["spp"] > 0 and r["psnr_gt_warm_db"] > 0 for r in truth["quality"])
    assert "the quality knob against Cycles" in (out / "report.md").read_text()
    # What you had / what you get: plain Cycles + denoiser, plain EEVEE and Apply on Render
    # on each, on the last frame (frame 21 is beyond the 3 frames), with the floor without
    # subsurface; the report shows the table.
    users = truth["users_frame"]
    assert users["frames"] == [3]
    assert sorted((r["engine"], r["kind"], r["denoise"]) for r in users["rows"]) == [
        ("CYCLES", "apply_on_render", True),
        ("CYCLES", "off", True),
        ("CYCLES", "plain", True),
        ("EEVEE", "apply_on_render", False),
        ("EEVEE", "off", False),
        ("EEVEE", "plain", False),
    ]
    assert all(r["samples"] == 2 and r["seconds_per_frame"] > 0 for r in users["rows"])
    assert all(r["mean"]["psnr_whole_db"] > 5 for r in users["rows"])
    # That table's ground truth takes its own samples, the methods' keeps --ground-truth-spp.
    for variant in ("material", "off"):
        record = scene_dir / "users_frame" / "ground_truth" / variant / "0003.json"
        assert json.loads(record.read_text())["samples"] == 24
    assert json.loads((scene_dir / "ground_truth" / "0003.json").read_text())["samples"] == 16
    report = (out / "report.md").read_text()
    assert "### regular: what you had / what you get (frames 3-3)" in report
    assert "| EEVEE 2 samples, Christensen-Burley (the materials' own) | plain |" in report

    # Same settings: the pass frames are reused, the methods recomputed.
    mtimes = {p: p.stat().st_mtime_ns for p in (scene_dir / "passes").glob("*.exr")}
    assert cli.main([*args, "--res", "32x18"]) == 0
    assert {p: p.stat().st_mtime_ns for p in mtimes} == mtimes
    # Other settings: rendered again at the new size.
    assert cli.main([*args, "--res", "24x16"]) == 0
    assert read_frame(scene_dir / "passes" / "0003.exr").shape == (16, 24)

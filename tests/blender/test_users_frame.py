"""``cvsss compare``'s harness on a tiny scene: real renders, the table, the scene restored."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_rgb  # noqa: E402
from cvsss.sss_addon.blender import materials as sss_materials  # noqa: E402
from cvsss.sss_addon.blender.compare import compare_scene  # noqa: E402
from cvsss.sss_addon.blender.users_frame import Setting  # noqa: E402

pytestmark = pytest.mark.bpy

FRAMES = (1, 2)


def _methods(materials) -> dict[str, str]:
    """Material and node -> subsurface method of every Principled BSDF of ``materials``."""
    return {
        node.name + "@" + m.name: node.subsurface_method
        for m in materials
        for _, node in sss_materials.principled_nodes(m.node_tree)
    }


def _direct_render(scene, frame: int, path: Path) -> np.ndarray:
    """The frame rendered the plain way (F12, write still) with the harness's settings."""
    scene.cycles.samples = 4
    scene.cycles.use_denoising = True
    scene.frame_set(frame)
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    scene.render.filepath = str(path)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    return read_rgb(path)


def test_the_table_of_a_tiny_scene(demo, tmp_path, snapshot):
    scene_state, state_diff = snapshot
    scene = demo
    scene.sss_settings.warmup_frames = 1
    scene.frame_set(3)
    scene.render.filepath = str(tmp_path / "user" / "frame_")
    # The demo's subsurface materials use Christensen-Burley; the others Blender's default.
    taking = sss_materials.participating(scene)
    assert set(_methods(taking).values()) == {"BURLEY"}
    every = sss_materials.scene_materials(scene)
    before, methods = scene_state(scene), _methods(every)
    assert "RANDOM_WALK" in methods.values()
    scenes = {s.name for s in bpy.data.scenes}
    out = tmp_path / "compare"
    report = compare_scene(
        scene,
        FRAMES,
        out,
        [Setting("CYCLES", 4, denoise=True)],
        ("material", "RANDOM_WALK"),
        truth_samples=16,
        log=None,
    )
    # Everything is the user's again: settings, frame, methods, the add-on's switch.
    assert state_diff(before, scene_state(scene)) == []
    assert _methods(every) == methods
    assert not scene.sss_settings.apply_on_render
    assert {s.name for s in bpy.data.scenes} == scenes
    assert not (tmp_path / "user").exists()  # nothing went to the user's output path

    rows = report["rows"]
    kinds = [(r["variant"], r["kind"]) for r in rows]
    assert sorted(kinds) == sorted(
        (v, k) for v in ("material", "RANDOM_WALK") for k in ("plain", "apply_on_render", "off")
    )
    for row in rows:
        assert row["frames"] == [1, 2] and row["samples"] == 4 and row["denoise"]
        for key in ("psnr_whole_db", "psnr_subsurface_db", "psnr_rest_db", "effect_db"):
            assert math.isfinite(row["mean"][key]) and 5 < row["mean"][key] <= 100, (row, key)
        assert 0 < row["mean"]["subsurface_share"] < 1
        assert 0 < row["setup_seconds"] < row["total_seconds"]
        assert row["seconds_per_frame"] == pytest.approx(row["total_seconds"] / 2)
    # The materials' own method is Christensen-Burley; the variant switched them all.
    assert {r["method"] for r in rows if r["variant"] == "material"} == {"BURLEY"}
    assert {r["method"] for r in rows if r["variant"] == "RANDOM_WALK"} == {"RANDOM_WALK"}
    plain = next(r for r in rows if r["kind"] == "plain" and r["variant"] == "material")
    ours = next(r for r in rows if r["kind"] == "apply_on_render" and r["variant"] == "material")
    assert ours["post_method"] == "as_ocv"
    # Apply on Render pays its warm-up frame before the first one; plain Cycles does not.
    assert ours["setup_seconds"] > plain["setup_seconds"]
    # Both variants' ground truths differ (another method), the one without subsurface is shared.
    burley = read_rgb(out / "ground_truth" / "material" / "0001.exr")
    walk = read_rgb(out / "ground_truth" / "RANDOM_WALK" / "0001.exr")
    assert not np.array_equal(burley, walk)
    assert (out / "ground_truth" / "off" / "0002.exr").is_file()

    # Each row splits its subsurface pixels by object (an Object Index render per frame,
    # the objects' Pass Index the user's again, above): the scene's own objects, whose
    # pixels add up to the rows' subsurface share of both frames.
    names = {o.name for o in scene.objects}
    width, height = report["size"]
    carriers = {o.name for o in scene.objects if sss_materials.carries(o, set(taking))}
    for row in rows:
        objects = row["objects"]
        assert set(objects) <= names | {""} and set(objects) & carriers, objects
        pixels = sum(v["pixels"] for v in objects.values())
        assert pixels == pytest.approx(2 * row["mean"]["subsurface_share"] * width * height)
        assert all(v["display_sse"] >= 0 and v["effect_sse"] >= 0 for v in objects.values())
    # Apply on Render's rows name the objects Cycles renders: the demo's Suzanne, block
    # and apples are 8 to 50 d across for their Christensen-Burley material.
    assert {"flash Suzanne", "flash Marble"} <= set(ours["cycles_renders"]) <= carriers
    assert "flash Marble Top" not in ours["cycles_renders"]
    numbered = json.loads((out / "ground_truth" / "objects" / "0002.json").read_text())
    assert set(numbered.values()) == names

    # The files: the JSON (no NaN) and the Markdown table.
    saved = json.loads((out / "users_frame.json").read_text())
    assert saved["frames"] == [1, 2] and len(saved["rows"]) == 6
    assert saved["apply_on_render"] == {
        "method": "as_ocv",
        # The setting says 1, but as_ocv is not temporal: Apply on Render warms up
        # only methods that reuse their history's estimates.
        "warmup_frames": 0,
        "denoise_passes": False,
        "denoise_subsurface": True,
        "thin_walks": "CYCLES",
    }
    table = (out / "users_frame.md").read_text()
    assert "| Cycles 4 spp + denoiser, Christensen-Burley (the materials' own) | plain |" in table
    assert "Apply on Render (as_ocv)" in table
    assert {t["target"] for t in saved["targets"]} >= {"subsurface pixels >= plain + 1 dB"}

    # The plain render it measured is the user's own render of that frame.
    measured = read_rgb(out / "renders" / "cycles_4_denoised" / "material_plain_0002.exr")
    direct = _direct_render(scene, 2, tmp_path / "direct.exr")
    np.testing.assert_allclose(measured, direct, rtol=1e-5, atol=1e-6)


def test_a_scene_without_subsurface_is_refused(fresh, tmp_path):
    from cvsss.sss_addon.blender.errors import RenderError

    bpy.ops.mesh.primitive_cube_add()
    bpy.ops.object.camera_add(location=(0, -5, 0))
    fresh.camera = bpy.context.object
    with pytest.raises(RenderError, match="no material with subsurface"):
        compare_scene(fresh, (1, 1), tmp_path, [Setting("CYCLES", 1)], log=None)


def test_the_command_on_a_saved_file(demo_blend, tmp_path, capfd):
    import hashlib

    from cvsss.sss_addon.cli import main as cli

    digest = hashlib.sha256(demo_blend.read_bytes()).hexdigest()
    out = tmp_path / "out"
    argv = ["compare", demo_blend, "--frames", "2", "--out", out, "--engine", "cycles"]
    argv += ["--samples", "2", "--ground-truth-spp", "8", "--quiet"]
    assert cli.main(list(map(str, argv))) == 0, capfd.readouterr().err
    saved = json.loads((out / "users_frame.json").read_text())
    assert saved["blend"] == str(demo_blend) and saved["frames"] == [2]
    assert [(r["kind"], r["samples"]) for r in saved["rows"]] == [
        ("plain", 2),
        ("apply_on_render", 2),
        ("off", 2),
    ]
    assert hashlib.sha256(demo_blend.read_bytes()).hexdigest() == digest  # never saved
    # The ground truth of the same file is reused; an unreadable file is one line.
    truth = out / "ground_truth" / "material" / "0002.exr"
    mtime = truth.stat().st_mtime_ns
    assert cli.main(list(map(str, argv))) == 0
    assert truth.stat().st_mtime_ns == mtime
    broken = tmp_path / "broken.blend"
    broken.write_bytes(b"BLENDER-v500" + b"\0" * 64)
    capfd.readouterr()
    assert cli.main(["compare", str(broken), "--frames", "1", "--out", str(out)]) == 2
    err = capfd.readouterr().err
    assert err.startswith("error: ") and "not a readable .blend file" in err


def test_ground_truths_of_two_seeds_are_independent(demo, tmp_path, snapshot):
    """Another Cycles seed gives an independent ground truth (tools/measure/truth_noise.py
    measures a ground truth's own noise that way): the mean of two 4-spp ones is closer
    to a 256-spp one than either alone, by about half the squared error for independent
    noise (a repeated seed would give the same image, and no gain)."""
    from cvsss.sss_addon.blender.users_frame import render_truth

    scene_state, state_diff = snapshot
    scene = demo
    before = scene_state(scene)
    layer = scene.view_layers[0]
    materials = sss_materials.scene_materials(scene)

    def truth(name: str, samples: int, seed: int) -> np.ndarray:
        path = tmp_path / f"{name}.exr"
        render_truth(scene, layer, 2, path, samples, subsurface=True, materials=materials,
                     record={}, seed=seed)  # fmt: skip
        assert json.loads(path.with_suffix(".json").read_text())["seed"] == seed
        return read_rgb(path)

    converged = truth("converged", 256, 7)
    first, second, again = truth("a", 4, 0), truth("b", 4, 1), truth("c", 4, 0)
    assert np.array_equal(first, again)
    alone = [float(((x - converged) ** 2).mean()) for x in (first, second)]
    both = float((((first + second) / 2 - converged) ** 2).mean())
    assert both < 0.75 * min(alone), (both, alone)
    assert state_diff(before, scene_state(scene)) == []

"""Operators in real headless Blender: outputs equal the core's, and the scene is left as it was."""

import csv
import json
import os

import numba
import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_frame, read_result  # noqa: E402
from cvsss.core.methods import make_processor  # noqa: E402
from cvsss.core.profiles.burley import blender_shape  # noqa: E402
from cvsss.sss_addon.blender import images, passes, render  # noqa: E402
from cvsss.sss_addon.blender.images import MAPS  # noqa: E402
from cvsss.sss_addon.blender.properties import settings_to_params  # noqa: E402
from cvsss.sss_addon.cli import main as cli  # noqa: E402

pytestmark = pytest.mark.bpy

EXPECTED_PASSES = {
    "Combined",
    "Depth",
    "Material Index",
    "Object Index",
    "Vector",
    "Diffuse Direct",
    "Diffuse Indirect",
    "Diffuse Color",
}


def _image_rows(image) -> np.ndarray:
    """(H, W, 4) pixels of an image, top row first (EXR order)."""
    w, h = image.size
    pixels = np.empty(w * h * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    return pixels.reshape(h, w, 4)[::-1]


def _pass_names(path) -> set[str]:
    import OpenEXR

    names = set()
    for part in OpenEXR.File(str(path), header_only=True).parts:
        names.add(part.name().split(".", 1)[1])
    return names


def test_render_sequence_equals_core_and_restores_scene(demo, tmp_path, snapshot):
    scene_state, state_diff = snapshot
    scene = demo
    s = scene.sss_settings
    blend = tmp_path / "user.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    digest = blend.read_bytes()
    before = scene_state(scene)

    assert bpy.ops.sss.render_sequence() == {"FINISHED"}

    assert not state_diff(before, scene_state(scene))
    assert blend.read_bytes() == digest  # the .blend on disk is never written
    out = tmp_path / "out"
    for frame in (1, 2, 3):
        assert (out / "passes" / f"{frame:04d}.exr").is_file()
        assert (out / "passes" / f"{frame:04d}.json").is_file()
        for method in ("as_ocv", "reference"):
            assert (out / method / f"{frame:04d}.exr").is_file()
    assert not [p for p in (out / "passes").iterdir() if p.name.startswith(".")]
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert [(int(r["frame"]), r["method"]) for r in rows] == [
        (f, m) for f in (1, 2, 3) for m in ("reference", "as_ocv")
    ]

    # Operator ≡ command line: `cvsss post` on the same passes writes the same
    # layers, bit for bit (all of them), and the same metric rows.
    cli_out = tmp_path / "cli"
    argv = ["post", str(out / "passes"), "--out", str(cli_out), "--method", "as_ocv"]
    argv += ["--reference", "--reference-spp", "64", "--target-variance", "1e-6", "--quiet"]
    assert cli.main(argv) == 0
    for frame in (1, 2, 3):
        for method in ("reference", "as_ocv"):
            written = read_result(out / method / f"{frame:04d}.exr")
            again = read_result(cli_out / method / f"{frame:04d}.exr")
            layers = set(written) - {"header"}
            assert layers == {
                "Composite",
                "SSS",
                "Gamma",
                "SampleCount",
                "Alpha",
                "Variance",
                "ValidHistory",
                "Mask",
            }
            assert layers == set(again) - {"header"}
            for layer in layers:
                np.testing.assert_array_equal(written[layer], again[layer], err_msg=layer)
    cli_rows = list(csv.DictReader(open(cli_out / "metrics.csv")))
    drop = ("sampling_ms", "frame_ms")
    assert [{k: v for k, v in r.items() if k not in drop} for r in rows] == [
        {k: v for k, v in r.items() if k not in drop} for r in cli_rows
    ]
    # … and ≡ the core's processors called directly (the maps shown in Blender).
    processors = {m: make_processor(m, settings_to_params(s)) for m in ("reference", "as_ocv")}
    for frame in (1, 2, 3):
        f = read_frame(out / "passes" / f"{frame:04d}.exr")
        ref = processors["reference"].process(f)
        res = processors["as_ocv"].process(f)
    assert len(np.unique(res.counts)) > 3  # a non-trivial count map
    for name, (field, _) in MAPS.items():
        image = bpy.data.images[name]
        assert tuple(image.size) == (48, 32)
        assert image.is_float
        rows_top_first = _image_rows(image)
        expected = np.asarray(getattr(res, field), dtype=np.float32)
        got = rows_top_first[..., 0] if expected.ndim == 2 else rows_top_first[..., :3]
        np.testing.assert_array_equal(got, expected, err_msg=name)
    counts_image = _image_rows(bpy.data.images["SSS Sample Count"])[..., 0]
    np.testing.assert_array_equal(counts_image, res.counts)
    assert bpy.data.images["SSS Sample Count"].colorspace_settings.name == "Non-Color"
    # Statistics of the last frame.
    assert s.has_stats and s.last_frame == 3 and s.last_method == "as_ocv"
    assert s.last_spp == pytest.approx(res.spp)
    assert s.last_sampling_ms > 0
    assert s.last_psnr == pytest.approx(float(rows[-1]["psnr_db"]), abs=1e-3)
    assert 20 < s.last_psnr <= 100
    del ref


def test_render_passes_only_needed_passes_resumable(demo, tmp_path, snapshot, thick_parts):
    thick_parts()
    scene_state, state_diff = snapshot
    scene = demo
    skin = bpy.data.materials["cvsss Skin"]
    floor = bpy.data.materials["cvsss Floor"]
    skin.pass_index, floor.pass_index = 7, 3  # user values: must come back
    before = scene_state(scene)
    assert bpy.ops.sss.render_passes() == {"FINISHED"}
    assert not state_diff(before, scene_state(scene))

    folder = tmp_path / "out" / "passes"
    path = folder / "0002.exr"
    # and the share of thin points (the rims of the demo's Christensen-Burley materials are
    # left to Cycles: Thin Parts' default)
    assert _pass_names(path) == EXPECTED_PASSES | {"cvsss_thin"}
    sidecar = json.loads((folder / "0002.json").read_text())
    assert sidecar["frame"] == 2 and sidecar["engine"] == "CYCLES"
    assert sidecar["camera"]["width"] == 48 and sidecar["camera"]["height"] == 32
    assert sidecar["camera"]["lens"] == pytest.approx(scene.camera.data.lens)
    slots = {m["name"]: m["slot"] for m in sidecar["materials"]}
    assert set(slots) == {"cvsss Skin", "cvsss Marble", "cvsss Apple"}  # the floor takes no part
    assert sorted(slots.values()) == [1, 2, 3]
    (spec,) = (m for m in sidecar["materials"] if m["name"] == "cvsss Skin")
    bsdf = skin.node_tree.nodes["Principled BSDF"]
    expected_d = blender_shape(
        tuple(bsdf.inputs["Subsurface Radius"].default_value),
        bsdf.inputs["Subsurface Scale"].default_value,
    )
    np.testing.assert_allclose(spec["d"], expected_d)
    frame = read_frame(path)
    assert set(np.unique(frame.material)) == {0, *slots.values()}  # floor and background 0
    skin_px = frame.material == slots["cvsss Skin"]
    assert skin_px.any() and frame.motion is not None and np.isfinite(frame.depth[skin_px]).all()
    # Object Index: the marble block and the marble table top share a material but
    # are told apart; the background is 0.
    marble = frame.material == slots["cvsss Marble"]
    assert len(np.unique(frame.objects[marble])) >= 2
    assert (frame.objects[~np.isfinite(frame.depth)] == 0).all()
    assert (frame.objects[frame.material > 0] > 0).all()

    # Resumable: existing frames are kept unless overwrite.
    mtimes = {p.name: p.stat().st_mtime_ns for p in folder.iterdir()}
    assert bpy.ops.sss.render_passes() == {"FINISHED"}
    assert {p.name: p.stat().st_mtime_ns for p in folder.iterdir()} == mtimes
    (folder / "0003.exr").unlink()
    scene.sss_settings.overwrite = False
    assert bpy.ops.sss.render_passes() == {"FINISHED"}
    assert (folder / "0003.exr").is_file()
    assert (folder / "0001.exr").stat().st_mtime_ns == mtimes["0001.exr"]
    scene.sss_settings.overwrite = True
    assert bpy.ops.sss.render_passes() == {"FINISHED"}
    assert (folder / "0001.exr").stat().st_mtime_ns != mtimes["0001.exr"]
    assert not [p for p in folder.iterdir() if p.name.startswith(".")]


def test_normal_pass_optional(demo, tmp_path):
    demo.sss_settings.use_normal_pass = True
    demo.sss_settings.frame_end = 1
    assert bpy.ops.sss.render_passes() == {"FINISHED"}
    assert "Normal" in _pass_names(tmp_path / "out" / "passes" / "0001.exr")


def test_apply_frame_updates_images_in_place(demo, tmp_path):
    scene = demo
    scene.frame_set(2)
    assert bpy.ops.sss.apply_frame() == {"FINISHED"}
    assert scene.frame_current == 2
    assert (tmp_path / "out" / "passes" / "0002.exr").is_file()
    assert not (tmp_path / "out" / "as_ocv").exists()  # apply_frame writes no results
    pointers = {name: bpy.data.images[name].as_pointer() for name in MAPS}
    n_images = len(bpy.data.images)

    # Same passes through the core: a single frame starts without history.
    params = settings_to_params(scene.sss_settings)
    res = make_processor("as_ocv", params).process(
        read_frame(tmp_path / "out" / "passes" / "0002.exr")
    )
    np.testing.assert_array_equal(
        _image_rows(bpy.data.images["SSS Sample Count"])[..., 0], res.counts
    )
    sss = res.counts[res.mask]
    assert np.all((sss == 0) | (sss == params.initial_count))

    scene.render.resolution_x, scene.render.resolution_y = 40, 24
    scene.sss_settings.overwrite = True
    assert bpy.ops.sss.apply_frame() == {"FINISHED"}
    assert len(bpy.data.images) == n_images
    for name in MAPS:
        image = bpy.data.images[name]
        assert image.as_pointer() == pointers[name]
        assert tuple(image.size) == (40, 24)
        data = name != "SSS Result"
        assert (image.colorspace_settings.name == "Non-Color") == data
    assert not any(img.name.endswith(".001") for img in bpy.data.images)


def test_error_unwritable_output_leaves_scene(demo, tmp_path, snapshot):
    scene_state, state_diff = snapshot
    blocker = tmp_path / "a_file"
    blocker.write_text("not a folder")
    demo.sss_settings.output_dir = str(blocker / "out")
    before = scene_state(demo)
    for op in (bpy.ops.sss.render_sequence, bpy.ops.sss.render_passes, bpy.ops.sss.apply_frame):
        with pytest.raises(RuntimeError, match="cannot write to output folder"):
            op()
        assert not state_diff(before, scene_state(demo))
    assert blocker.read_text() == "not a folder"


def test_error_midway_restores_scene(demo, tmp_path, snapshot, monkeypatch):
    scene_state, state_diff = snapshot
    before = scene_state(demo)
    calls = []
    real = passes._render_still

    def failing(scene):
        calls.append(scene.frame_current)
        # The pass setup is in force while rendering...
        assert (
            bpy.data.materials["cvsss Skin"]
            .node_tree.nodes["Principled BSDF"]
            .inputs["Subsurface Weight"]
            .default_value
            == 0.0
        )
        assert scene.render.image_settings.file_format == "OPEN_EXR_MULTILAYER"
        if len(calls) == 2:
            raise RuntimeError("simulated render failure")
        real(scene)

    monkeypatch.setattr(passes, "_render_still", failing)
    with pytest.raises(RuntimeError, match="simulated render failure"):
        bpy.ops.sss.render_sequence()
    assert calls == [1, 2]
    assert not state_diff(before, scene_state(demo))
    out = tmp_path / "out"
    assert (out / "as_ocv" / "0001.exr").is_file()  # finished frames are kept
    assert not (out / "passes" / "0002.exr").exists()
    assert not [p for p in (out / "passes").iterdir() if p.name.startswith(".")]


def test_cancel_midway_restores_scene(demo, tmp_path, snapshot):
    scene_state, state_diff = snapshot
    before = scene_state(demo)
    job = render.job_from_scene(demo, images=True)
    steps = render.iter_sequence(job)
    step = next(steps)
    assert step.frame == 1 and step.index == 1 and step.total == 3
    # Between frames the scene is the user's (only the current frame moved).
    mid = state_diff(before, scene_state(demo))
    assert all(line.startswith("frame_current") for line in mid), mid
    steps.close()  # what ESC does in the modal operator
    assert not state_diff(before, scene_state(demo))
    out = tmp_path / "out"
    assert (out / "as_ocv" / "0001.exr").is_file()
    assert not (out / "passes" / "0002.exr").exists()
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert {r["frame"] for r in rows} == {"1"}


def test_linked_and_animated_weight_are_forced_to_zero_and_restored(demo, snapshot):
    scene_state, state_diff = snapshot
    skin = bpy.data.materials["cvsss Skin"]
    tree = skin.node_tree
    bsdf = tree.nodes["Principled BSDF"]
    weight = bsdf.inputs["Subsurface Weight"]
    value = tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 0.7
    tree.links.new(value.outputs[0], weight)
    # A second material whose weight is animated.
    other = bpy.data.materials.new("Animated SSS")
    other_weight = other.node_tree.nodes["Principled BSDF"].inputs["Subsurface Weight"]
    other_weight.default_value = 0.3
    other_weight.keyframe_insert("default_value", frame=1)
    other_weight.default_value = 0.9
    other_weight.keyframe_insert("default_value", frame=3)
    bpy.data.objects["flash Plane"].data.materials.append(other)
    demo.frame_set(1)
    before = scene_state(demo)

    mats = [skin, other]
    layer = demo.view_layers[0]
    # A user's own object numbering, which the render must put back.
    for obj in demo.objects:
        obj.pass_index = 7
    before = scene_state(demo)
    with passes.PassSetup(demo, mats, layer):
        demo.frame_set(2)
        assert weight.default_value == 0.0 and not weight.is_linked
        assert other_weight.default_value == 0.0
        assert skin.pass_index == 1 and other.pass_index == 2
        assert bpy.data.materials["cvsss Floor"].pass_index == 0
        assert layer.use_pass_material_index and layer.use_pass_vector and layer.use_pass_z
        # Objects numbered 1..N, those that carry a participating material first.
        numbers = sorted(o.pass_index for o in demo.objects)
        assert numbers == list(range(1, len(numbers) + 1))
        carriers = [
            o.pass_index for o in demo.objects if any(s.material in mats for s in o.material_slots)
        ]
        assert carriers and sorted(carriers) == list(range(1, len(carriers) + 1))
        assert layer.use_pass_object_index
        assert not layer.use_pass_normal and not demo.render.use_motion_blur
        assert not demo.cycles.use_denoising
    demo.frame_set(1)
    assert not state_diff(before, scene_state(demo))
    assert weight.is_linked and weight.links[0].from_node == value
    assert other_weight.default_value == pytest.approx(0.3)


def test_no_sss_material_is_an_error(fresh, tmp_path):
    scene = fresh
    from cvsss.demo_blend.scenes import diffuse_material

    mesh = bpy.data.meshes.new("m")
    obj = bpy.data.objects.new("o", mesh)
    scene.collection.objects.link(obj)
    mesh.materials.append(diffuse_material("grey", (0.5, 0.5, 0.5)))
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.sss_settings.output_dir = str(tmp_path / "out")
    with pytest.raises(RuntimeError, match="no material .* takes part"):
        bpy.ops.sss.render_sequence()
    # Forcing the material on makes it take part.
    bpy.data.materials["grey"].sss_material.mode = "ON"
    job = render.job_from_scene(scene)
    assert [m.name for m in job.materials] == ["grey"]


def test_output_dir_relative_to_blend(fresh, tmp_path):
    s = fresh.sss_settings
    assert render.resolve_output_dir(s).is_absolute()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "x.blend"))
    assert render.resolve_output_dir(bpy.context.scene.sss_settings) == tmp_path / "cvsss"
    os.remove(tmp_path / "x.blend")


class _WindowManager:
    """Stands in for the window manager of a UI session (bpy runs without one here)."""

    def __init__(self):
        self.progress, self.timers, self.handlers = [], [], []

    def event_timer_add(self, step, window=None):
        self.timers.append(object())
        return self.timers[-1]

    def event_timer_remove(self, timer):
        self.timers.remove(timer)

    def modal_handler_add(self, op):
        self.handlers.append(op)

    def progress_begin(self, low, high):
        self.progress.append(("begin", low, high))

    def progress_update(self, value):
        self.progress.append(value)

    def progress_end(self):
        self.progress.append("end")


def _modal_operator(op_class):
    """A plain object running the operator's modal code with recorded reports."""
    from cvsss.operators import sequence

    class Modal(sequence._SteppedOperator):
        steps = op_class.steps
        verb = op_class.verb
        samples = op_class.samples

        def __init__(self):
            self.reports = []

        def report(self, kind, text):
            self.reports.append((sorted(kind)[0], text))

    return Modal()


def test_modal_advances_one_frame_per_tick_and_esc_cancels(demo, tmp_path, snapshot):
    from types import SimpleNamespace

    from cvsss.operators.sequence import SSS_OT_render_sequence

    scene_state, state_diff = snapshot
    before = scene_state(demo)
    wm = _WindowManager()
    context = SimpleNamespace(
        scene=demo,
        view_layer=demo.view_layers[0],
        window="win",
        window_manager=wm,
        workspace=None,
        screen=None,
    )
    op = _modal_operator(SSS_OT_render_sequence)
    assert op.start_modal(context) == {"RUNNING_MODAL"}
    assert wm.handlers == [op] and len(wm.timers) == 1
    other = SimpleNamespace(type="MOUSEMOVE", value="NOTHING", timer=None)
    assert op.modal(context, other) == {"PASS_THROUGH"}
    tick = SimpleNamespace(type="TIMER", value="NOTHING", timer=wm.timers[0])
    assert op.modal(context, tick) == {"RUNNING_MODAL"}
    assert wm.progress == [("begin", 0, 3), 1]
    assert (tmp_path / "out" / "as_ocv" / "0001.exr").is_file()
    assert not (tmp_path / "out" / "passes" / "0002.exr").exists()
    esc = SimpleNamespace(type="ESC", value="PRESS", timer=None)
    assert op.modal(context, esc) == {"CANCELLED"}
    assert wm.timers == [] and wm.progress[-1] == "end"
    assert op.reports[-1][0] == "WARNING" and "1/3 frame(s)" in op.reports[-1][1]
    assert not state_diff(before, scene_state(demo))
    assert (tmp_path / "out" / "as_ocv" / "0001.exr").is_file()  # kept

    # A full modal run finishes after the last frame.
    op = _modal_operator(SSS_OT_render_sequence)
    assert op.start_modal(context) == {"RUNNING_MODAL"}
    results = [
        op.modal(context, SimpleNamespace(type="TIMER", value="NOTHING", timer=wm.timers[0]))
        for _ in range(4)
    ]
    assert results == [{"RUNNING_MODAL"}] * 3 + [{"FINISHED"}]
    assert op.reports[-1] == (
        "INFO",
        f"Processed 3/3 frame(s) into {tmp_path / 'out'}; sampling on "
        f"numba ({numba.__version__}, {numba.get_num_threads()} threads)",
    )
    assert not state_diff(before, scene_state(demo))


def test_invoke_in_background_runs_to_the_end(demo, tmp_path):
    assert bpy.ops.sss.render_passes("INVOKE_DEFAULT") == {"FINISHED"}
    assert sorted(p.name for p in (tmp_path / "out" / "passes").iterdir()) == [
        f"{f:04d}.{ext}" for f in (1, 2, 3) for ext in ("exr", "json")
    ]


def test_eevee_setup_writes_slots_through_an_aov_and_restores(demo, snapshot):
    scene_state, state_diff = snapshot
    skin = bpy.data.materials["cvsss Skin"]
    layer = demo.view_layers[0]
    before = scene_state(demo)
    n_nodes = len(skin.node_tree.nodes)
    with passes.PassSetup(demo, [skin], layer, engine="EEVEE"):
        assert demo.render.engine in ("BLENDER_EEVEE", "BLENDER_EEVEE_NEXT")
        names = [passes.AOV_NAME, passes.OBJECT_AOV, passes.COVER_AOV]
        assert [aov.name for aov in layer.aovs] == names
        nodes = {
            n.aov_name: n for n in skin.node_tree.nodes if n.bl_idname == "ShaderNodeOutputAOV"
        }
        assert sorted(nodes) == sorted(names)
        assert nodes[passes.AOV_NAME].inputs["Value"].default_value == 1.0
        (link,) = nodes[passes.COVER_AOV].inputs["Color"].links
        combine = link.from_node
        assert combine.bl_idname == "ShaderNodeCombineColor"
        assert combine.inputs["Red"].default_value == 1.0
        assert combine.inputs["Green"].default_value == 1.0  # slot 1, squared
        (link,) = combine.inputs["Blue"].links
        assert link.from_node.operation == "MULTIPLY"
        (link,) = nodes[passes.OBJECT_AOV].inputs["Value"].links
        assert link.from_node.bl_idname == "ShaderNodeObjectInfo"
        assert link.from_socket.name == "Object Index"
    assert len(skin.node_tree.nodes) == n_nodes and len(layer.aovs) == 0
    assert not state_diff(before, scene_state(demo))


@pytest.mark.slow
def test_eevee_render_reads_like_cycles(demo, tmp_path, thick_parts):
    """EEVEE passes read like Cycles ones (software GL: ~90 s, the shader compile)."""
    thick_parts()
    demo.sss_settings.engine = "EEVEE"
    demo.sss_settings.frame_end = 1
    assert bpy.ops.sss.render_sequence() == {"FINISHED"}
    frame = read_frame(tmp_path / "out" / "passes" / "0001.exr")
    assert set(np.unique(frame.material)) == {0, 1, 2, 3}
    assert np.isinf(frame.depth[frame.material == 0]).any()
    # The object AOV became the Object Index pass: each SSS material's pixels
    # show numbered objects (only SSS materials write it in EEVEE).
    assert frame.objects is not None
    for slot in (1, 2, 3):
        assert (frame.objects[frame.material == slot] > 0).mean() > 0.9
    # EEVEE filters the AOVs; the edge pixels it mixes still carry labels a surface
    # of the frame has: every (slot, object) pair is one Cycles' exact index passes
    # show on the same frame, and nearly all SSS pixels of the one render are SSS
    # pixels of the other.
    demo.sss_settings.engine = "CYCLES"
    demo.sss_settings.output_dir = str(tmp_path / "cycles")
    assert bpy.ops.sss.render_sequence() == {"FINISHED"}
    cycles = read_frame(tmp_path / "cycles" / "passes" / "0001.exr")

    def pairs(f):
        sss = f.material > 0
        return set(zip(f.material[sss].tolist(), f.objects[sss].tolist()))

    assert pairs(frame) <= pairs(cycles)
    both = (frame.material > 0) & (cycles.material > 0)
    assert both.sum() >= 0.9 * (frame.material > 0).sum()


def test_user_images_with_the_maps_names_are_left_alone(demo, tmp_path, snapshot):
    """An image of the user's named like a map keeps its name, file, pixels and users; the
    map takes Blender's next free name. An earlier version's map (untagged, unused) is
    adopted, and the maps are reused by the next run."""
    scene_state, state_diff = snapshot
    demo.sss_settings.frame_end = 1
    demo.sss_settings.use_reference = False
    png = tmp_path / "texture.png"
    source = bpy.data.images.new("texture", 4, 4)
    source.pixels.foreach_set(np.linspace(0, 1, 64, dtype=np.float32))
    source.filepath_raw = str(png)
    source.file_format = "PNG"
    source.save()
    texture = bpy.data.images.load(str(png))
    texture.name = "SSS Result"
    painted = bpy.data.images.new("SSS Sample Count", 8, 8)  # 8 bits, generated
    tree = bpy.data.materials["cvsss Skin"].node_tree
    for image in (texture, painted):
        tree.nodes.new("ShaderNodeTexImage").image = image
    old_map = bpy.data.images.new("SSS Gamma", 2, 2, float_buffer=True)  # an earlier run's
    pixels = np.empty(4 * 4 * 4, np.float32)
    texture.pixels.foreach_get(pixels)
    before = scene_state(demo)

    assert bpy.ops.sss.render_sequence() == {"FINISHED"}

    assert not state_diff(before, scene_state(demo))  # the texture nodes' images included
    assert texture.name == "SSS Result" and texture.source == "FILE"
    assert texture.filepath == str(png) and not texture.is_float
    again = np.empty_like(pixels)
    texture.pixels.foreach_get(again)
    np.testing.assert_array_equal(again, pixels)
    assert painted.name == "SSS Sample Count" and not painted.is_float
    assert tuple(painted.size) == (8, 8)
    maps = {name: images.find_map(name) for name in MAPS}
    assert maps["SSS Result"].name == "SSS Result.001"
    assert maps["SSS Sample Count"].name == "SSS Sample Count.001"
    assert maps["SSS Gamma"] == old_map  # adopted
    for name, image in maps.items():
        assert image.is_float and tuple(image.size) == (48, 32), name
    pointers = {name: image.as_pointer() for name, image in maps.items()}

    assert bpy.ops.sss.apply_frame() == {"FINISHED"}
    assert {name: images.find_map(name).as_pointer() for name in MAPS} == pointers
    assert not any(image.name.endswith(".002") for image in bpy.data.images)


def test_user_errors_are_one_message_without_traceback(demo, tmp_path, snapshot, capfd):
    scene_state, state_diff = snapshot
    demo.sss_settings.frame_end = 2
    demo.sss_settings.use_reference = False
    demo.render.resolution_percentage = 1  # 48x32 at 1 %: no pixel
    before = scene_state(demo)
    for op in (bpy.ops.sss.render_sequence, bpy.ops.sss.render_passes, bpy.ops.sss.apply_frame):
        with pytest.raises(RuntimeError, match=r"the output is 0x0 pixels \(Resolution 48x32"):
            op()
        assert not state_diff(before, scene_state(demo))
    demo.render.resolution_percentage = 100
    (tmp_path / "out" / "passes" / "0002.exr").mkdir(parents=True)  # a folder in its place
    before = scene_state(demo)
    with pytest.raises(RuntimeError, match=r"cannot write .*0002\.exr"):
        bpy.ops.sss.render_passes()
    assert not state_diff(before, scene_state(demo))
    captured = capfd.readouterr()
    assert "Traceback" not in captured.err + captured.out


def test_passes_made_with_other_settings_are_not_reused(demo, tmp_path, snapshot):
    """Without Overwrite a frame's passes are reused (a stopped render resumes) only while
    the scene would write the same sidecar: after another resolution or Subsurface Weight
    the job stops with a message instead of giving results of the old settings."""
    scene_state, state_diff = snapshot
    out = tmp_path / "o"
    exr = out / "passes" / "0001.exr"

    def run(overwrite=False):
        job = render.job_from_scene(
            demo, frames=(1, 2), out=out, methods=["none"], reference=False, overwrite=overwrite
        )
        return list(render.iter_sequence(job))

    assert [step.rendered for step in run()] == [True, True]
    written = exr.stat().st_mtime_ns
    assert [step.rendered for step in run()] == [False, False]  # the same scene: reused
    assert exr.stat().st_mtime_ns == written
    # Passes of another engine than the scene's (EEVEE passes of this Cycles scene) are
    # checked against the engine the job renders with.
    other = tmp_path / "eevee" / "passes"
    other.mkdir(parents=True)
    sidecar = json.loads((out / "passes" / "0001.json").read_text())
    sidecar["engine"] = passes.engine_identifier(demo, "EEVEE")
    sidecar.pop("thin_parts", None)  # EEVEE passes leave no thin parts to Cycles
    (other / "0001.json").write_text(json.dumps(sidecar))
    for engine, stale in (("EEVEE", False), ("CYCLES", True)):
        job = render.job_from_scene(demo, frames=(1, 1), out=other.parent, engine=engine)
        if stale:
            with pytest.raises(render.RenderError, match="another engine(,| than)"):
                render.check_passes(job, 1)
        else:
            render.check_passes(job, 1)
    marble = bpy.data.materials["cvsss Marble"].node_tree.nodes["Principled BSDF"]
    for change, what in (
        (lambda: setattr(demo.render, "resolution_x", 40), "camera than"),
        (
            lambda: setattr(marble.inputs["Subsurface Weight"], "default_value", 0.5),
            "camera, materials than",  # the two changes so far
        ),
    ):
        change()
        before = scene_state(demo)
        for op in (run, bpy.ops.sss.render_sequence, bpy.ops.sss.render_passes):
            if op is not run:
                demo.sss_settings.output_dir = str(out)
            with pytest.raises((RuntimeError, render.RenderError), match=f"another {what}"):
                op()
            assert not state_diff(before, scene_state(demo))
        assert exr.stat().st_mtime_ns == written
    assert [step.rendered for step in run(overwrite=True)] == [True, True]
    assert read_frame(exr).shape == (32, 40)
    assert [step.rendered for step in run()] == [False, False]

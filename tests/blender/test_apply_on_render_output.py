"""Apply on Render delivers the frame the user had: the scene's denoiser, its compositor,
its passes in a multilayer EXR, and the warm-up where it pays (real Cycles, tiny frames).

Expected values come from outside the code under test: ``cvsss render``'s composite
(standalone.render_sequence), Blender's own render with Apply on Render off, numpy
arithmetic, and a Denoise node tree built here.
"""

import tempfile
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_result  # noqa: E402
from cvsss.sss_addon.blender import standalone  # noqa: E402
from cvsss.sss_addon.blender.apply_on_render import handlers  # noqa: E402
from cvsss.sss_addon.blender.apply_on_render.notes import scene_notes  # noqa: E402
from cvsss.sss_addon.blender.apply_on_render.session import active_session  # noqa: E402
from cvsss.sss_addon.blender.denoise_frame import context_noise  # noqa: E402

pytestmark = pytest.mark.bpy

FRAMES = (1, 2)
#: A constant the test compositor multiplies the image by (per channel).
GAIN = (0.5, 1.0, 2.0)


@pytest.fixture
def scene(demo, tmp_path):
    """The flash demo at 48x27, 4 samples, frames 1–2, Apply on Render on, no warm-up,
    32-bit EXR output."""
    demo.render.resolution_x, demo.render.resolution_y = 48, 27
    demo.frame_start, demo.frame_end = FRAMES
    demo.frame_set(1)
    demo.sss_settings.apply_on_render = True
    demo.sss_settings.warmup_frames = 0
    _exr(demo, tmp_path / "render" / "f_", multilayer=False)
    return demo


def _exr(scene, path: Path, multilayer: bool) -> None:
    r = scene.render
    r.filepath = str(path)
    settings = r.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE" if multilayer else "IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER" if multilayer else "OPEN_EXR"
    settings.color_depth = "32"


def _read(path: Path) -> dict[str, np.ndarray]:
    exr = OpenEXR.File(str(path), separate_channels=True)
    return {k: np.asarray(c.pixels) for p in exr.parts for k, c in p.channels.items()}


def _stack(channels: dict, prefix: str, letters: str) -> np.ndarray:
    return np.stack([channels[prefix + c] for c in letters], -1)


def _animation(scene, folder: Path, snapshot=None) -> dict[int, dict[str, np.ndarray]]:
    """Render FRAMES as an animation into ``folder``: every channel of each frame's file.
    With ``snapshot`` (the fixture), the scene must come out as it went in."""
    scene.render.filepath = str(folder / "f_")
    before = snapshot[0](scene) if snapshot else None
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    if snapshot:
        assert snapshot[1](before, snapshot[0](scene)) == []
    return {
        f: _read(Path(scene.render.frame_path(frame=f))) for f in range(FRAMES[0], FRAMES[1] + 1)
    }


def _manifest(folder: Path, frame: int) -> dict[str, str]:
    """The Cryptomatte fields of a frame's EXR header (the manifest, hash, name)."""
    header = OpenEXR.File(str(folder / f"f_{frame:04d}.exr"), header_only=True).parts[0].header
    return {k: str(v) for k, v in header.items() if k.startswith("cryptomatte/")}


def _reference(scene, out: Path) -> dict[int, np.ndarray]:
    """Composite of ``cvsss render`` per frame (linear RGB, top row first)."""
    method = scene.sss_settings.method
    standalone.render_sequence(
        scene, FRAMES, out, [method], engine="CYCLES", reference=False, log=None
    )
    return {f: read_result(out / method / f"{f:04d}.exr")["Composite"] for f in FRAMES}


def _masks(scene, out: Path) -> dict[int, np.ndarray]:
    """The post's mask per frame of a :func:`_reference` run in ``out``: (H, W) bool."""
    method = scene.sss_settings.method
    return {f: read_result(out / method / f"{f:04d}.exr")["Mask"] > 0 for f in FRAMES}


def _datablocks() -> tuple:
    """Scenes, node groups and images (but the SSS maps the post shows, on purpose)."""
    return (
        sorted(s.name for s in bpy.data.scenes),
        sorted(g.name for g in bpy.data.node_groups),
        sorted(i.name for i in bpy.data.images if not i.name.startswith("SSS ")),
    )


def test_denoiser_and_multilayer_passes_as_the_scene_asks(
    scene, tmp_path, snapshot, delivered_denoise
):
    """With the scene's denoiser on, the delivered Combined is the finished frame denoised
    with the scene's prefilter and quality, guided by the pass render's Denoising Albedo
    and Normal (the pixels off the post's mask by a second denoise with stand-in noise on
    it); Noisy Image is the finished frame before it. With it off, Combined is the
    finished frame itself. A multilayer EXR holds the passes Blender's own render writes,
    and those the subsurface does not touch have its values."""
    layer = scene.view_layers[0]
    name = layer.name + "."
    layer.use_pass_mist = layer.use_pass_normal = layer.use_pass_object_index = True
    layer.use_pass_cryptomatte_object = True
    layer.cycles.denoising_store_passes = True
    for index, obj in enumerate(scene.objects):
        obj.pass_index = 40 + 3 * index  # the user's numbers, not the pass render's
    c = scene.cycles
    c.samples = 64  # from 64 samples the pixels off the post's mask are denoised again
    c.denoising_prefilter, c.denoising_quality = "FAST", "BALANCED"
    c.denoising_input_passes = "RGB_ALBEDO_NORMAL"
    expected = _reference(scene, tmp_path / "ref")
    masks = _masks(scene, tmp_path / "ref")
    _exr(scene, tmp_path / "x", multilayer=True)
    c.use_denoising = True
    scene.sss_settings.apply_on_render = False
    plain = _animation(scene, tmp_path / "plain")

    blocks = _datablocks()
    c.use_denoising = False
    scene.sss_settings.apply_on_render = True
    off = _animation(scene, tmp_path / "off", snapshot)
    c.use_denoising = True
    on = _animation(scene, tmp_path / "on", snapshot)
    assert _datablocks() == blocks and active_session() is None

    for frame in FRAMES:
        mask = masks[frame]
        assert 0 < mask.mean() < 1
        f = _stack(off[frame], name + "Combined.", "RGB")
        np.testing.assert_allclose(f, expected[frame], rtol=1e-6, atol=1e-7)
        noisy = _stack(on[frame], name + "Noisy Image.", "RGB")
        np.testing.assert_array_equal(noisy, f)
        denoised = _stack(on[frame], name + "Combined.", "RGB")
        # The stand-in noise: 5× the noise round the post's pixels, at most 0.5.
        sigma = min(5.0 * context_noise(noisy, mask), 0.5)
        assert sigma > 0.01
        want = delivered_denoise(
            noisy,
            _stack(on[frame], name + "Denoising Albedo.", "RGB"),
            _stack(on[frame], name + "Denoising Normal.", "XYZ"),
            mask,
            sigma,
            "Fast",
            "Balanced",
        )
        np.testing.assert_allclose(denoised, want, rtol=0, atol=1e-6)
        assert np.abs(denoised - f).max() > 1e-3  # the denoiser did something
        # The channels of Blender's own render, with the values of the passes the
        # subsurface leaves alone (Object Index back in the user's numbering).
        assert sorted(on[frame]) == sorted(plain[frame])
        crypto = [k for k in plain[frame] if ".CryptoObject" in k]
        assert crypto
        for channel in ("Mist.Z", "Object Index.X", *(k.removeprefix(name) for k in crypto)):
            np.testing.assert_array_equal(on[frame][name + channel], plain[frame][name + channel])
        assert _manifest(tmp_path / "on", frame) == _manifest(tmp_path / "plain", frame) != {}
        assert set(np.unique(on[frame][name + "Object Index.X"])) <= {
            0.0,
            *(float(o.pass_index) for o in scene.objects),
        }
        normal = _stack(on[frame], name + "Normal.", "XYZ")
        assert np.abs(normal - _stack(plain[frame], name + "Normal.", "XYZ")).mean() < 0.01


def _user_compositor(scene, side: Path):
    """The user's compositor: the Render Layers' Image times GAIN to the output, and a File
    Output node writing its Mist pass to ``side``."""
    scene.view_layers[0].use_pass_mist = True  # before the node: it offers the passes on
    group = bpy.data.node_groups.new("user compositor", "CompositorNodeTree")
    group.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    layers = group.nodes.new("CompositorNodeRLayers")
    layers.scene, layers.layer = scene, scene.view_layers[0].name
    mix = group.nodes.new("ShaderNodeMix")
    mix.data_type, mix.blend_type, mix.clamp_result = "RGBA", "MULTIPLY", False
    mix.inputs["Factor"].default_value = 1.0
    mix.inputs[7].default_value = (*GAIN, 1.0)  # B
    out = group.nodes.new("NodeGroupOutput")
    group.links.new(layers.outputs["Image"], mix.inputs[6])  # A
    group.links.new(mix.outputs[2], out.inputs[0])
    files = group.nodes.new("CompositorNodeOutputFile")
    files.directory = str(side)
    files.file_name = "mist_"
    files.format.media_type = "IMAGE"
    files.format.file_format = "OPEN_EXR"
    files.format.color_depth = "32"
    files.file_output_items.new("FLOAT", "Mist")
    group.links.new(layers.outputs["Mist"], files.inputs["Mist"])
    scene.compositing_node_group = group
    scene.render.use_compositing = True
    return group


def _side_files(folder: Path) -> dict[str, np.ndarray]:
    return {p.name: _read(p) for p in sorted(folder.iterdir())}


def test_the_users_compositor_runs_on_the_finished_frame(scene, tmp_path, snapshot):
    """The compositor's Render Layers Image is the finished frame (the delivered frame is
    the user's node applied to it), its other sockets the pass render's passes (a File
    Output node writes the Mist pass Blender's own render writes, once per frame); for
    an animation and for a still, with the scene, its compositor and the file's node
    groups as they were."""
    expected = _reference(scene, tmp_path / "ref")
    group = _user_compositor(scene, tmp_path / "side-plain")
    scene.sss_settings.apply_on_render = False
    _animation(scene, tmp_path / "plain")
    plain_side = _side_files(tmp_path / "side-plain")
    group.nodes["File Output"].directory = str(tmp_path / "side")
    scene.sss_settings.apply_on_render = True
    blocks = _datablocks()
    got = _animation(scene, tmp_path / "apply", snapshot)
    for frame in FRAMES:
        np.testing.assert_allclose(
            _stack(got[frame], "", "RGB"), expected[frame] * GAIN, rtol=1e-6, atol=1e-7
        )
    assert _side_files(tmp_path / "side").keys() == plain_side.keys()  # once per frame
    for name, channels in _side_files(tmp_path / "side").items():
        for key, pixels in channels.items():
            np.testing.assert_array_equal(pixels, plain_side[name][key])

    # F12 with write_still: the still goes through the compositor too.
    scene.frame_set(FRAMES[0])
    scene.render.filepath = str(tmp_path / "still")
    before = snapshot[0](scene)
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert snapshot[1](before, snapshot[0](scene)) == []
    still = _read(tmp_path / "still.exr")
    np.testing.assert_allclose(
        _stack(still, "", "RGB"), expected[FRAMES[0]] * GAIN, rtol=1e-6, atol=1e-7
    )
    assert _datablocks() == blocks and active_session() is None


def test_warm_up_only_where_it_pays(scene, tmp_path, capfd):
    """Warm-up frames are rendered before an animation of a method that reuses its
    history's estimates (a temporal one), never for the other methods, nor for a still."""
    scene.sss_settings.warmup_frames = 2
    capfd.readouterr()
    _animation(scene, tmp_path / "as_ocv")  # the fixture's method: no temporal reuse
    out = capfd.readouterr().out
    assert "no warm-up (as_ocv reuses no estimates)" in out
    assert "warm-up frame" not in out
    scene.sss_settings.method = "as_ocv_t"
    _animation(scene, tmp_path / "as_ocv_t")
    lines = [ln for ln in capfd.readouterr().out.splitlines() if "cvsss: warm-up frame" in ln]
    assert [ln.split()[3] for ln in lines] == ["-1", "0"]
    scene.render.filepath = str(tmp_path / "still")
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert "warm-up frame" not in capfd.readouterr().out
    assert (tmp_path / "still.exr").is_file()


def test_the_panel_says_what_differs_before_the_render(scene):
    """Each limit shows in the panel's notes exactly when the scene has it. The flash
    demo's Suzanne, marble block and apples (20.4, 20, 15 and 12 d of their
    Christensen-Burley materials across) go to Cycles whole, which the last note says,
    with Cycles' passes only."""
    whole = (
        "'flash Suzanne', 'flash Marble', 'flash Apple' and 1 more are 8 to 50 d across "
        "or under 8 d every way for Christensen-Burley: Cycles renders their subsurface"
    )
    assert scene_notes(scene) == [whole]
    layer = scene.view_layers[0]
    other = scene.view_layers.new("other")
    other.use = False
    group = _user_compositor(scene, Path(tempfile.gettempdir()))
    layers = group.nodes.new("CompositorNodeRLayers")
    layers.scene, layers.layer = scene, "other"
    layer.use_pass_diffuse_color = True
    scene.render.use_motion_blur = True
    layer.use_pass_material_index = True
    assert scene_notes(scene) == [
        "Motion blur is off (the post-process needs the Vector pass)",
        "The compositor's Render Layers of 'other' get no image",
        "The Diffuse passes hold no subsurface light (only Combined does)",
        whole,
    ]
    # Materials without subsurface that the user numbered apart: the pass render gives
    # them all 0, so the Material Index pass cannot tell them apart.
    others = [m for m in bpy.data.materials if not m.sss_material.participates]
    assert len(others) >= 2
    others[0].pass_index, others[1].pass_index = 3, 4
    assert scene_notes(scene)[-2].startswith("Material Index: the materials without")
    scene.render.use_compositing = False
    assert "The Diffuse passes hold no subsurface light (only Combined does)" not in (
        scene_notes(scene)
    )
    # EEVEE has no denoiser; Apply on Render denoises the subsurface pixels it adds.
    denoised = "The subsurface pixels are denoised with OpenImageDenoise (Denoise Subsurface)"
    assert denoised not in scene_notes(scene)
    assert whole in scene_notes(scene)
    scene.render.engine = "BLENDER_EEVEE"
    assert denoised in scene_notes(scene)
    assert whole not in scene_notes(scene)  # the post renders every part of EEVEE's passes
    scene.sss_settings.use_denoise_subsurface = False
    assert denoised not in scene_notes(scene)


def test_the_panel_notes_parts_thin_for_random_walk(scene, walk_everywhere):
    """The flash demo's subsurface objects, switched to Random Walk, are 2 (the marble
    table top, 2 cm) to 20.4 (Suzanne) mean free paths of their material thick (the
    marble's 1 cm in red, the demo's D_MAX): all five under 50. Only with Random Walk
    are they noted, in the scene's order; the note says who renders them (with Cycles,
    all of them: the frame as without the add-on). The top made 60 cm thick (60 mean free
    paths) drops out of the list, and the post has a part to render again."""
    head = (
        "'flash Marble Top', 'flash Suzanne', 'flash Marble' and 2 more are thin for Random "
        "Walk (under 50 mean free paths across): "
    )
    cycles = (  # with every part thin, no session: Blender renders as without the add-on
        "Every subsurface object is thin for Random Walk (under 50 mean free paths across): "
        "Cycles renders the frame as without the add-on"
    )
    post = (
        head + "Cycles loses light through the far side, the post keeps it (brighter than Cycles)"
    )
    assert not [n for n in scene_notes(scene) if "Random Walk" in n]  # Christensen-Burley
    walk_everywhere()
    assert [n for n in scene_notes(scene) if "Random Walk" in n] == [cycles]
    scene.sss_settings.thin_walks = "POST"
    assert [n for n in scene_notes(scene) if "Random Walk" in n] == [post]
    scene.sss_settings.thin_walks = "CYCLES"
    scene.render.engine = "BLENDER_EEVEE"  # EEVEE's passes: the post renders every part
    assert [n for n in scene_notes(scene) if "Random Walk" in n] == [post]
    scene.render.engine = "CYCLES"
    top = scene.objects["flash Marble Top"]
    top.scale.z *= 30.0  # 60 cm: 60 mean free paths
    bpy.context.view_layer.update()
    assert [n for n in scene_notes(scene) if "Random Walk" in n] == [
        "'flash Suzanne', 'flash Marble', 'flash Apple' and 1 more are thin for Random Walk "
        "(under 50 mean free paths across): Cycles renders their subsurface"
    ]


def _skin_thick() -> None:
    """Suzanne's skin three times less translucent (its Subsurface Scale a third): she is
    61 mean free paths across, over the thin bound of 50, so the post has a part to
    render while the rest of the flash demo switched to Random Walk stays thin."""
    bsdf = bpy.data.materials["cvsss Skin"].node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Subsurface Scale"].default_value /= 3.0


def _renders_as_without_the_addon(scene, tmp_path, snapshot, monkeypatch) -> list:
    """Render a still with Apply on Render off, then on: the second starts no session
    and equals the first bit for bit in every channel, and the scene comes out of each
    as it went in. Returns the list the stubbed ``start_session`` records its calls in
    (for renders the test makes afterwards)."""
    started = []
    monkeypatch.setattr(handlers, "start_session", lambda *a: started.append(a))
    frames = {}
    for on in (False, True):
        scene.sss_settings.apply_on_render = on
        scene.render.filepath = str(tmp_path / f"on_{on}")
        before = snapshot[0](scene)
        assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
        assert snapshot[1](before, snapshot[0](scene)) == []
        frames[on] = _read(tmp_path / f"on_{on}.exr")
    assert started == []
    assert frames[True].keys() == frames[False].keys()
    for key, pixels in frames[False].items():
        np.testing.assert_array_equal(frames[True][key], pixels, err_msg=key)
    return started


def test_with_every_part_thin_blender_renders_as_without_the_addon(
    scene, tmp_path, snapshot, monkeypatch, capsys, walk_everywhere
):
    """Switched to Random Walk, every subsurface object of the flash demo is thin (2 to
    20.4 mean free paths across): Cycles renders all of their subsurface, the post would
    change no pixel, so Apply on Render starts no session and Blender renders the frame
    as with the add-on off, bit for bit; the log and the panel say so. With one part
    thick (Suzanne's skin), the session runs again."""
    walk_everywhere()
    started = _renders_as_without_the_addon(scene, tmp_path, snapshot, monkeypatch)
    said = "every subsurface object is thin for Random Walk (under 50 mean free paths across)"
    assert said in capsys.readouterr().out
    assert any(n.lower().startswith(said.lower()) for n in scene_notes(scene))
    _skin_thick()
    assert not any(n.lower().startswith(said.lower()) for n in scene_notes(scene))
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert len(started) == 1


def test_without_subsurface_blender_renders_as_without_the_addon(
    scene, tmp_path, snapshot, monkeypatch, capsys
):
    """Every Principled BSDF at Subsurface Weight 0 (Blender's default material): nothing
    takes part, so a box left ticked starts no session and Blender renders the frame as
    with the add-on off, bit for bit, instead of refusing the render; the log and the
    panel say so. A weight keyframed from 0 (here) to 1 (the next frame) takes part."""
    nodes = [
        node
        for material in bpy.data.materials
        for node in (material.node_tree.nodes if material.node_tree else ())
        if node.bl_idname == "ShaderNodeBsdfPrincipled"
    ]
    for node in nodes:
        node.inputs["Subsurface Weight"].default_value = 0.0
    started = _renders_as_without_the_addon(scene, tmp_path, snapshot, monkeypatch)
    said = "no material takes part in subsurface scattering"
    assert said in capsys.readouterr().out
    assert any(n.lower().startswith(said) for n in scene_notes(scene))
    # The marble: its top (2 d) is no part Cycles renders whole.
    marble = bpy.data.materials["cvsss Marble"].node_tree.nodes["Principled BSDF"]
    weight = marble.inputs["Subsurface Weight"]
    weight.keyframe_insert("default_value", frame=1)
    weight.default_value = 1.0
    weight.keyframe_insert("default_value", frame=2)
    scene.frame_set(1)
    assert weight.default_value == 0.0
    assert not any(n.lower().startswith(said) for n in scene_notes(scene))
    assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
    assert len(started) == 1


def test_cycles_renders_parts_thin_for_random_walk(scene, tmp_path, snapshot, walk_everywhere):
    """Switched to Random Walk, the flash demo's 2-cm marble top is thin. Cycles' walk
    loses light through its far side: at 1024 spp its top returns 0.86 / 0.90 / 0.93 (R /
    G / B) of the top without subsurface (frame 21, docs/explanation/accuracy.md §2.3),
    while the post keeps 1.00–1.02. Left to Cycles (the default), the delivered top is
    that much darker than the post makes it, most in red, and the user's scene, slots and
    materials are back afterwards. ``cvsss render`` of the same frame composites the
    same frame (the setting is the scene's, for every way of rendering). Suzanne is made
    thick (:func:`_skin_thick`) so that the post has a part to render."""
    walk_everywhere()
    _skin_thick()
    scene.frame_set(21)
    scene.cycles.samples = 16
    scene.cycles.use_denoising = False
    layer = scene.view_layers[0]
    layer.use_pass_object_index = True
    top = scene.objects["flash Marble Top"]
    top.pass_index = 7
    _exr(scene, tmp_path / "x", multilayer=True)
    means, frames = {}, {}
    for who in ("CYCLES", "POST"):
        scene.sss_settings.thin_walks = who
        scene.render.filepath = str(tmp_path / who)
        before = snapshot[0](scene)
        blocks = sorted(bpy.data.materials.keys()), sorted(bpy.data.node_groups.keys())
        assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
        assert snapshot[1](before, snapshot[0](scene)) == [] and active_session() is None
        assert (sorted(bpy.data.materials.keys()), sorted(bpy.data.node_groups.keys())) == blocks
        got = _read(tmp_path / f"{who}.exr")  # a still: the path as given, and .exr
        mask = got[layer.name + ".Object Index.X"] == 7
        assert mask.sum() > 200  # the top fills much of the frame
        frames[who] = _stack(got, layer.name + ".Combined.", "RGB")
        means[who] = frames[who][mask].mean(0)
    ratio = means["CYCLES"] / means["POST"]
    assert 0.75 < ratio[0] < 0.93, ratio
    assert ratio[0] < ratio[2] < 1.0, ratio  # the walk loses the most in red
    scene.sss_settings.thin_walks = "CYCLES"
    method = scene.sss_settings.method
    standalone.render_sequence(
        scene, (21, 21), tmp_path / "cli", [method], engine="CYCLES", reference=False, log=None
    )
    composite = read_result(tmp_path / "cli" / method / "0021.exr")["Composite"]
    np.testing.assert_allclose(frames["CYCLES"], composite, rtol=1e-6, atol=1e-7)


def test_thin_parts_keep_the_users_material_index(scene, tmp_path, walk_everywhere):
    """Switched to Random Walk with Suzanne thick (:func:`_skin_thick`), the flash demo's
    marble and apples are thin: the pass render gives their objects copies of those
    materials. The multilayer file's Material Index still holds the user's numbers
    there, as Blender's own render with Apply on Render off writes them."""
    walk_everywhere()
    _skin_thick()
    for index, name in enumerate(("cvsss Marble", "cvsss Apple", "cvsss Skin"), start=5):
        bpy.data.materials[name].pass_index = index
    layer = scene.view_layers[0]
    layer.use_pass_material_index = True
    channel = layer.name + ".Material Index.X"
    got = {}
    for on in (False, True):
        scene.sss_settings.apply_on_render = on
        _exr(scene, tmp_path / f"on_{on}", multilayer=True)
        assert bpy.ops.render.render(write_still=True) == {"FINISHED"}
        got[on] = _read(tmp_path / f"on_{on}.exr")
    assert channel in got[False], sorted(got[False])
    assert set(np.unique(got[False][channel])) >= {5.0, 6.0, 7.0}
    np.testing.assert_array_equal(got[True][channel], got[False][channel])


def test_a_save_while_finishing_keeps_the_users_materials(
    scene, tmp_path, snapshot, monkeypatch, walk_everywhere
):
    """UI render of the flash demo switched to Random Walk (its thin top gets a copy of
    the marble for the pass render). A save between Blender's render and the finishing
    writes the user's scene: slots, materials and node groups as before the render, no
    copy. The finishing then takes the pass configuration again and delivers the frames
    a render without the save delivers. Suzanne is made thick (:func:`_skin_thick`) so
    that the post has a part to render."""
    monkeypatch.setattr(handlers, "_on_render_thread", lambda: True)
    walk_everywhere()
    _skin_thick()
    frames = {}
    for saved in (False, True):
        scene.render.filepath = str(tmp_path / f"saved_{saved}" / "f_")
        before = snapshot[0](scene)
        names = sorted(bpy.data.materials.keys()), sorted(bpy.data.node_groups.keys())
        assert bpy.ops.render.render(animation=True) == {"FINISHED"}
        assert "flash Marble Top" in active_session().job.thin_record["objects"]
        if saved:
            handlers.on_save_pre()  # what Blender calls around Ctrl-S
            assert snapshot[1](before, snapshot[0](scene)) == []
            assert (sorted(bpy.data.materials.keys()), sorted(bpy.data.node_groups.keys())) == names
            handlers.on_save_post()
        handlers._poll()  # the UI's timer: finishes
        assert snapshot[1](before, snapshot[0](scene)) == [] and active_session() is None
        assert (sorted(bpy.data.materials.keys()), sorted(bpy.data.node_groups.keys())) == names
        frames[saved] = {f: _read(Path(scene.render.frame_path(frame=f))) for f in FRAMES}
    for frame in FRAMES:
        for key, pixels in frames[False][frame].items():
            np.testing.assert_array_equal(frames[True][frame][key], pixels, err_msg=key)


def test_ui_finishes_through_the_users_compositor(scene, tmp_path, snapshot, monkeypatch):
    """With the UI (the handlers on Blender's render thread, the frames finished after the
    render job) the compositor runs on the finished frames as in background mode."""
    monkeypatch.setattr(handlers, "_on_render_thread", lambda: True)
    expected = _reference(scene, tmp_path / "ref")
    _user_compositor(scene, tmp_path / "side")
    scene.render.filepath = str(tmp_path / "apply" / "f_")
    before = snapshot[0](scene)
    assert bpy.ops.render.render(animation=True) == {"FINISHED"}
    assert not (tmp_path / "apply").exists()  # nothing delivered yet: the job just ended
    handlers._poll()  # the UI's timer: finishes (no window here)
    assert snapshot[1](before, snapshot[0](scene)) == [] and active_session() is None
    for frame in FRAMES:
        got = _read(Path(scene.render.frame_path(frame=frame)))
        np.testing.assert_allclose(
            _stack(got, "", "RGB"), expected[frame] * GAIN, rtol=1e-6, atol=1e-7
        )

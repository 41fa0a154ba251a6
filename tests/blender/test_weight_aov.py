"""Subsurface Weight in the pass render: constants travel in the sidecar, linked weights per pixel."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_frame  # noqa: E402
from cvsss.core.methods import make_processor  # noqa: E402
from cvsss.sss_addon.blender import render  # noqa: E402

pytestmark = pytest.mark.bpy


def _principled(material):
    return material.node_tree.nodes["Principled BSDF"]


def test_constant_and_linked_weight_reach_the_core(demo, tmp_path, snapshot, capfd, thick_parts):
    thick_parts()
    scene_state, state_diff = snapshot
    skin = bpy.data.materials["cvsss Skin"]
    marble = bpy.data.materials["cvsss Marble"]
    _principled(marble).inputs["Subsurface Weight"].default_value = 0.4
    tree = skin.node_tree
    value = tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 0.25
    tree.links.new(value.outputs[0], _principled(skin).inputs["Subsurface Weight"])
    radius = tree.nodes.new("ShaderNodeRGB")
    tree.links.new(radius.outputs[0], _principled(skin).inputs["Subsurface Radius"])
    before = scene_state(demo)

    job = render.job_from_scene(demo, frames=(1, 1), out=tmp_path / "w", reference=False)
    for _ in render.iter_passes(job):
        pass
    assert not state_diff(before, scene_state(demo))
    err = capfd.readouterr().err
    assert "'cvsss Skin': Subsurface Radius is linked" in err

    frame = read_frame(tmp_path / "w" / "passes" / "0001.exr")
    by_name = {s.name: s for s in frame.materials.values()}
    assert by_name["cvsss Marble"].weight == pytest.approx(0.4)
    assert by_name["cvsss Skin"].options.get("weight_linked") is True
    skin_px = frame.material == by_name["cvsss Skin"].slot
    marble_px = frame.material == by_name["cvsss Marble"].slot
    assert frame.sss_weight is not None and skin_px.any()
    # Inside the skin (away from edges, where the AOV is filtered with the background).
    inner = _inner(skin_px)
    assert np.allclose(frame.sss_weight[inner], 0.25, atol=1e-3)
    assert np.isnan(frame.sss_weight[marble_px]).all()
    # The composite applies it: Combined − A·B + A·((1 − w)·B + w·L) with w = 0.25.
    full = make_processor("fixed").process(frame)
    none = make_processor("none").process(frame)
    change = frame.albedo * (full.sss - frame.lighting)
    np.testing.assert_allclose(
        full.composite[inner], (none.composite + 0.25 * change)[inner], rtol=1e-4, atol=1e-6
    )


def _inner(mask: np.ndarray) -> np.ndarray:
    """Pixels of ``mask`` whose four neighbours are in it too (away from filtered edges)."""
    inner = mask.copy()
    for axis in (0, 1):
        for shift in (-1, 1):
            inner &= np.roll(mask, shift, axis=axis)
    return inner


def _passes(scene, out):
    job = render.job_from_scene(scene, frames=(1, 1), out=out, reference=False)
    for _ in render.iter_passes(job):
        pass
    return read_frame(out / "passes" / "0001.exr")


def test_muted_weight_link_passes_nothing_and_stays_muted(demo, tmp_path, snapshot, thick_parts):
    """Blender ignores a muted link: the socket's own value is the weight, and the link
    comes back muted after the pass render."""
    thick_parts()
    scene_state, state_diff = snapshot
    skin = bpy.data.materials["cvsss Skin"]
    socket = _principled(skin).inputs["Subsurface Weight"]
    socket.default_value = 0.6
    value = skin.node_tree.nodes.new("ShaderNodeValue")
    value.outputs[0].default_value = 0.3
    skin.node_tree.links.new(value.outputs[0], socket).is_muted = True
    before = scene_state(demo)

    frame = _passes(demo, tmp_path / "w")

    assert not state_diff(before, scene_state(demo))  # the mute flag included
    assert [link.is_muted for link in socket.links] == [True]
    spec = {s.name: s for s in frame.materials.values()}["cvsss Skin"]
    assert spec.weight == pytest.approx(0.6)
    assert not spec.options.get("weight_linked")
    skin_px = frame.material == spec.slot
    assert skin_px.any()
    assert frame.sss_weight is None or np.isnan(frame.sss_weight[skin_px]).all()


def test_group_shared_by_two_materials_writes_its_weight_once(demo, tmp_path, snapshot):
    """Two materials whose Principled BSDF is in one node group, its weight linked from the
    group's input: each material's pixels carry their own weight, not the sum of two AOV
    outputs in the shared group."""
    scene_state, state_diff = snapshot
    group = bpy.data.node_groups.new("cvsss shared", "ShaderNodeTree")
    group.interface.new_socket("W", in_out="INPUT", socket_type="NodeSocketFloat")
    group.interface.new_socket("BSDF", in_out="OUTPUT", socket_type="NodeSocketShader")
    inputs = group.nodes.new("NodeGroupInput")
    outputs = group.nodes.new("NodeGroupOutput")
    bsdf = group.nodes.new("ShaderNodeBsdfPrincipled")
    group.links.new(inputs.outputs["W"], bsdf.inputs["Subsurface Weight"])
    group.links.new(bsdf.outputs["BSDF"], outputs.inputs["BSDF"])
    weights = {"cvsss Skin": 0.3, "cvsss Marble": 0.7}
    for name, weight in weights.items():
        tree = bpy.data.materials[name].node_tree
        tree.nodes.remove(tree.nodes["Principled BSDF"])
        node = tree.nodes.new("ShaderNodeGroup")
        node.node_tree = group
        node.inputs["W"].default_value = weight
        out = next(n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial")
        tree.links.new(node.outputs["BSDF"], out.inputs["Surface"])
    before = scene_state(demo)

    frame = _passes(demo, tmp_path / "w")

    assert not state_diff(before, scene_state(demo))
    assert not [n for n in group.nodes if n.bl_idname == "ShaderNodeOutputAOV"]
    by_name = {s.name: s for s in frame.materials.values()}
    for name, weight in weights.items():
        assert by_name[name].options.get("weight_linked") is True
        inner = _inner(frame.material == by_name[name].slot)
        assert inner.any(), name
        got = frame.sss_weight[inner]
        # Never the sum of two AOV outputs; a pixel that another object's edge covers
        # in part holds less (the AOV is filtered, the material index is not).
        assert got.max() <= weight + 1e-3, name
        assert np.mean(np.abs(got - weight) <= 1e-3) > 0.95, name

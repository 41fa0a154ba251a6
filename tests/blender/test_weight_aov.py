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


def test_constant_and_linked_weight_reach_the_core(demo, tmp_path, snapshot, capfd):
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
    inner = skin_px.copy()
    for axis in (0, 1):
        for shift in (-1, 1):
            inner &= np.roll(skin_px, shift, axis=axis)
    assert np.allclose(frame.sss_weight[inner], 0.25, atol=1e-3)
    assert np.isnan(frame.sss_weight[marble_px]).all()
    # The composite applies it: Combined − A·B + A·((1 − w)·B + w·L) with w = 0.25.
    full = make_processor("fixed").process(frame)
    none = make_processor("none").process(frame)
    change = frame.albedo * (full.sss - frame.lighting)
    np.testing.assert_allclose(
        full.composite[inner], (none.composite + 0.25 * change)[inner], rtol=1e-4, atol=1e-6
    )

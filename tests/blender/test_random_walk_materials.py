"""A material's subsurface method travels from its Principled BSDF to the post.

The pass render's sidecar records each material's Subsurface Method and, for the
random walks, the inputs the core's fitted model needs, read from the node —
also the sockets Blender hides for the method (Subsurface IOR under Random Walk).
"""

import dataclasses

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core import SSSParams, make_processor  # noqa: E402
from cvsss.core.io.exr import read_frame  # noqa: E402
from cvsss.core.profiles import random_walk  # noqa: E402
from cvsss.sss_addon.blender import materials, render  # noqa: E402

pytestmark = pytest.mark.bpy


def _node(name):
    return bpy.data.materials[name].node_tree.nodes["Principled BSDF"]


def _set_hidden(node, identifier, value):
    for socket in node.inputs:
        if socket.identifier == identifier:
            socket.default_value = value
            return
    raise AssertionError(identifier)


def test_a_random_walk_materials_spec_carries_its_method_and_inputs(demo):
    skin = _node("cvsss Skin")
    skin.subsurface_method = "RANDOM_WALK"
    skin.inputs["Base Color"].default_value = (0.7, 0.4, 0.3, 1.0)
    skin.inputs["Subsurface Radius"].default_value = (1.0, 0.5, 0.25)
    skin.inputs["Subsurface Scale"].default_value = 0.02
    skin.inputs["Subsurface Anisotropy"].default_value = 0.3
    with pytest.raises(KeyError):  # hidden under Random Walk: not found by name
        skin.inputs["Subsurface IOR"]
    _set_hidden(skin, "Subsurface IOR", 1.33)
    marble = _node("cvsss Marble")
    marble.subsurface_method = "RANDOM_WALK_SKIN"
    marble.inputs["Subsurface IOR"].default_value = 1.5
    mats = materials.participating(demo)
    specs = {s.name: s for s in materials.material_specs(mats, demo)}

    spec = specs["cvsss Skin"]
    assert spec.method == "RANDOM_WALK"
    o = spec.options
    np.testing.assert_allclose(o["base_color"], (0.7, 0.4, 0.3), rtol=1e-6)
    np.testing.assert_allclose(o["subsurface_radius"], (1.0, 0.5, 0.25), rtol=1e-6)
    assert o["subsurface_scale"] == pytest.approx(0.02)
    assert o["subsurface_ior"] == pytest.approx(1.33)
    assert o["subsurface_anisotropy"] == pytest.approx(0.3)
    assert o["base_color_linked"] is False
    np.testing.assert_allclose(spec.d, np.array([1.0, 0.5, 0.25]) * 0.02 / (4 * np.pi), 1e-6)
    assert specs["cvsss Marble"].method == "RANDOM_WALK_SKIN"
    assert specs["cvsss Marble"].options["subsurface_ior"] == pytest.approx(1.5)
    assert specs["cvsss Apple"].method == "BURLEY" and specs["cvsss Apple"].options == {}

    # The panel's summary: the model's d and energy for those inputs.
    summary = materials.model_summary(bpy.data.materials["cvsss Skin"])
    d, e = random_walk.shape((1.0, 0.5, 0.25), 0.02, (0.7, 0.4, 0.3), "RANDOM_WALK", 1.33, 0.3)
    assert summary["label"] == "Random Walk"
    np.testing.assert_allclose(summary["d"], d, rtol=1e-6)
    np.testing.assert_allclose(summary["energy"], e, rtol=1e-6)

    # A textured Base Color is flagged; an override replaces the model (BURLEY).
    tree = bpy.data.materials["cvsss Skin"].node_tree
    rgb = tree.nodes.new("ShaderNodeRGB")
    tree.links.new(rgb.outputs[0], skin.inputs["Base Color"])
    assert materials.subsurface_model(bpy.data.materials["cvsss Skin"])[1]["base_color_linked"]
    settings = bpy.data.materials["cvsss Skin"].sss_material
    settings.use_override = True
    (over,) = (s for s in materials.material_specs(mats, demo) if s.name == "cvsss Skin")
    assert over.method == "BURLEY" and over.options == {}


def test_the_passes_carry_the_method_and_the_post_models_it(demo, tmp_path):
    """Render one frame's passes: the sidecar read back gives the Random Walk slot the
    model's d (its light differs from Burley's at the node's d)."""
    skin = _node("cvsss Skin")
    skin.subsurface_method = "RANDOM_WALK_SKIN"
    # The post renders every point here (Random Walk (Skin)'s mean free path makes the
    # whole Suzanne thin, which Cycles would render otherwise: test_thin_parts.py).
    job = render.job_from_scene(
        demo, frames=(1, 1), out=tmp_path, methods=["reference"], thin_walks="POST"
    )
    (step,) = render.iter_passes(job)
    frame = read_frame(step.path)
    (spec,) = (s for s in frame.materials.values() if s.name == "cvsss Skin")
    assert spec.method == "RANDOM_WALK_SKIN"
    color = tuple(skin.inputs["Base Color"].default_value)[:3]
    np.testing.assert_allclose(spec.options["base_color"], color, rtol=1e-6)
    params = SSSParams(reference_spp=16)
    got = make_processor("reference", params).process(frame)
    as_burley = dataclasses.replace(
        frame,
        materials={k: dataclasses.replace(v, method="BURLEY") for k, v in frame.materials.items()},
    )
    plain = make_processor("reference", params).process(as_burley)
    skin_pixels = got.mask & (frame.material == spec.slot)
    assert skin_pixels.sum() > 20
    assert not np.allclose(got.sss[skin_pixels], plain.sss[skin_pixels])
    others = got.mask & (frame.material != spec.slot)
    assert np.array_equal(got.sss[others], plain.sss[others])

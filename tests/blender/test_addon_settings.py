"""Settings, material panel data, registration and the demo builder in real Blender."""

import json
import math

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.methods import METHODS  # noqa: E402
from cvsss.core.params import (  # noqa: E402
    SSSParams,
    flag_of,
    specs,
)
from cvsss.core.profiles import presets, random_walk  # noqa: E402
from cvsss.core.profiles.burley import blender_shape  # noqa: E402
from cvsss.demo_blend import scenes  # noqa: E402
from cvsss.sss_addon.blender import materials  # noqa: E402
from cvsss.sss_addon.blender.properties import (  # noqa: E402
    PRESET_NAMES,
    param_properties,
    settings_to_params,
)
from cvsss.sss_addon.cli import params as cli_params  # noqa: E402

pytestmark = pytest.mark.bpy

PARAM_PROPS = (
    "eta",
    "target_variance",
    "eps_u",
    "eps_alpha",
    "kappa",
    "beta_min",
    "beta_max",
    "eta_cv",
    "fixed_spp",
    "reference_spp",
    "seed",
    "history_precision",
    "exposure",
)


def test_defaults_are_the_papers(fresh):
    s = fresh.sss_settings
    assert settings_to_params(s) == SSSParams()
    for name in PARAM_PROPS:
        default = s.bl_rna.properties[name].default
        assert (
            default == pytest.approx(getattr(SSSParams(), name))
            if isinstance(default, float)
            else default == getattr(SSSParams(), name)
        ), name
    assert [i.identifier for i in s.bl_rna.properties["method"].enum_items] == list(METHODS)
    assert s.engine == "CYCLES" and s.history_precision == "float32"
    assert not s.use_frame_range and not s.has_stats


def test_hard_limits_make_invalid_params_impossible(fresh):
    s = fresh.sss_settings
    for name in PARAM_PROPS:
        prop = s.bl_rna.properties[name]
        if prop.type not in ("FLOAT", "INT"):
            continue
        assert prop.description, name
        for bound in (prop.hard_min, prop.hard_max):
            setattr(s, name, bound)
            settings_to_params(s)  # never raises
        setattr(s, name, prop.default)
    # Crossing beta_min over beta_max drags the other along.
    s.beta_min = 100
    assert s.beta_max == 100
    s.beta_max = 5
    assert s.beta_min == 5
    s.eta = 0.0  # clamped to the open bound
    assert s.eta > 0
    settings_to_params(s)


def test_quality_picks_the_calibrated_parameters(fresh, monkeypatch):
    from cvsss.core.eval import quality
    from cvsss.core.params import ParameterError

    s = fresh.sss_settings
    s.method = "as_ccv"
    s.target_variance = 0.5  # ignored once a quality target is set
    s.quality = "PSNR"
    s.quality_psnr = 45.0
    # Expected from the shipped calibration itself: σ0² where as_ccv's measured PSNR curve
    # (log-linear between its points) reaches 45 dB, in the family of the largest β_min
    # that reaches it.
    data = json.loads(quality.CALIBRATION_PATH.read_text())
    families = sorted(
        data["methods"]["as_ccv"]["families"], key=lambda f: -f.get("fixed", {}).get("beta_min", 0)
    )
    family = next(f for f in families if min(f["psnr_db"]) <= 45.0 <= max(f["psnr_db"]))
    order = np.argsort(family["psnr_db"])
    log_sigma = np.interp(
        45.0, np.asarray(family["psnr_db"])[order], np.log10(family["values"])[order]
    )
    got = settings_to_params(s)
    assert got.target_variance == pytest.approx(10**log_sigma, rel=1e-3)
    assert got.beta_min == family.get("fixed", {}).get("beta_min", SSSParams().beta_min)
    s.quality = "SPP"
    s.quality_spp = 12.0
    low = settings_to_params(s)
    s.quality_spp = 48.0
    high = settings_to_params(s)
    assert high.target_variance < low.target_variance  # more samples: smaller σ0²
    # The job's method, not the panel's, is calibrated; methods without σ0² ignore it.
    assert settings_to_params(s, "as") == quality.apply(SSSParams(), "48spp", "as")[0]
    s.method = "separable"
    assert settings_to_params(s).target_variance == pytest.approx(0.5)
    assert s.bl_rna.properties["quality_spp"].hard_min == 1.0  # the core's smallest budget
    s.method = "as_ccv"

    def missing(*args, **kwargs):
        raise FileNotFoundError("no such file: quality_calibration.json")

    monkeypatch.setattr(quality, "load_calibration", missing)
    with pytest.raises(ParameterError, match="quality: no such file"):
        settings_to_params(s)
    monkeypatch.undo()
    s.quality = "MANUAL"
    assert settings_to_params(s).target_variance == pytest.approx(0.5)


def test_cv_mode_follows_the_method_table(fresh):
    s = fresh.sss_settings
    for method in METHODS.values():
        s.method = method.name
        assert s.cv_mode == (method.cv if method.adaptive else "none")
    s.cv_mode = "online"
    assert s.method == "as_ocv"
    s.cv_mode = "constant"
    assert s.method == "as_ccv"
    s.cv_mode = "none"
    assert s.method == "as"


def test_material_participation_shape_override_preset(fresh):
    mat = bpy.data.materials.new("m")
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    m = mat.sss_material
    assert m.mode == "AUTO" and not m.participates and not materials.participates(mat)
    bsdf.inputs["Subsurface Weight"].default_value = 0.5
    bsdf.inputs["Subsurface Radius"].default_value = (2.0, 1.0, 0.5)
    bsdf.inputs["Subsurface Scale"].default_value = 0.1
    assert m.participates
    np.testing.assert_allclose(materials.material_shape(mat), blender_shape((2.0, 1.0, 0.5), 0.1))
    np.testing.assert_allclose(materials.material_shape(mat)[0], 2.0 * 0.1 * 0.25 / math.pi)
    m.mode = "OFF"
    assert not m.participates
    m.mode = "ON"
    bsdf.inputs["Subsurface Weight"].default_value = 0.0
    assert m.participates
    m.use_override = True
    m.d_override = (0.1, 0.2, 0.3)
    np.testing.assert_allclose(materials.material_shape(mat), (0.1, 0.2, 0.3))
    items = [i.identifier for i in m.bl_rna.properties["preset"].enum_items]
    assert items == ["NONE", *[p.upper() for p in PRESET_NAMES]]
    m.preset = "SKIN1"
    m.preset_scale = 10.0
    (spec,) = materials.material_specs([mat], fresh)
    assert spec.options == {"preset": "skin1", "preset_scale": 10.0, "mm_per_unit": 1000.0}
    assert spec.slot == 1 and spec.d == pytest.approx((0.1, 0.2, 0.3))  # override wins
    m.use_override = False
    expected = presets.get("skin1").burley_d_mm() * 10.0 / 1000.0
    np.testing.assert_allclose(materials.material_shape(mat, fresh), expected)
    fresh.unit_settings.scale_length = 0.01  # centimetres: 10 mm per unit
    np.testing.assert_allclose(materials.material_shape(mat, fresh), expected * 100.0)


def test_material_inside_node_group(fresh):
    mat = bpy.data.materials.new("grouped")
    group = bpy.data.node_groups.new("G", "ShaderNodeTree")
    inner = group.nodes.new("ShaderNodeBsdfPrincipled")
    inner.inputs["Subsurface Weight"].default_value = 1.0
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    node = tree.nodes.new("ShaderNodeGroup")
    node.node_tree = group
    assert materials.participates(mat)
    with materials.SSSDisabled([mat]):
        assert inner.inputs["Subsurface Weight"].default_value == 0.0
    assert inner.inputs["Subsurface Weight"].default_value == 1.0


def test_animated_weight_takes_part_and_instanced_materials_are_seen(fresh):
    """The slots read without evaluating the scene include an instanced collection's
    objects, which the scene's objects do not. A Subsurface Weight of 0 keyframed to 1
    at a later frame takes part (the render reaches that frame); muted, it does not."""
    mat = bpy.data.materials.new("m")
    socket = mat.node_tree.nodes["Principled BSDF"].inputs["Subsurface Weight"]
    hidden = bpy.data.collections.new("hidden")  # not linked to the scene
    mesh = bpy.data.meshes.new("mesh")
    mesh.materials.append(mat)
    hidden.objects.link(bpy.data.objects.new("inside", mesh))
    assert list(materials.slot_materials(fresh)) == []
    empty = bpy.data.objects.new("instancer", None)
    empty.instance_type, empty.instance_collection = "COLLECTION", hidden
    fresh.collection.objects.link(empty)
    assert [m.name for m in materials.slot_materials(fresh)] == ["m"]
    socket.default_value = 0.0
    assert not materials.participates(mat)
    socket.keyframe_insert("default_value", frame=1)
    socket.default_value = 1.0
    socket.keyframe_insert("default_value", frame=10)
    fresh.frame_set(2)
    fresh.frame_set(1)
    assert socket.default_value == 0.0 and materials.participates(mat)
    for fcurve in materials._fcurves(mat.node_tree.animation_data):
        fcurve.mute = True
    assert not materials.participates(mat)


def _addon_classes():
    from cvsss.operators import demo, sequence
    from cvsss.sss_addon.blender import panels, properties

    return [c for m in (properties, sequence, demo, panels) for c in m.classes]


def test_unregister_leaves_nothing(addon):
    classes = _addon_classes()
    assert len(classes) == 9 and all(c.is_registered for c in classes)
    addon.unregister()
    try:
        assert not [c for c in classes if c.is_registered]
        assert not [name for name in dir(bpy.types) if name.startswith("SSS_")]
        assert not hasattr(bpy.types.Scene, "sss_settings")
        assert not hasattr(bpy.types.Material, "sss_material")
        assert not [op for op in dir(bpy.ops.sss) if not op.startswith("_")]
    finally:
        addon.register()
    assert all(c.is_registered for c in classes)
    assert bpy.ops.sss.render_sequence.idname() == "SSS_OT_render_sequence"


def test_build_demo_is_deterministic(fresh):
    scene = fresh
    assert bpy.ops.sss.build_demo(scene_name="flash") == {"FINISHED"}

    def geometry():
        out = {}
        for obj in bpy.data.collections["cvsss demo flash"].objects:
            if obj.type == "MESH":
                co = np.empty(len(obj.data.vertices) * 3)
                obj.data.vertices.foreach_get("co", co)
                out[obj.name] = (co.tobytes(), tuple(obj.matrix_world.col[3]))
            else:
                out[obj.name] = tuple(tuple(r) for r in obj.matrix_world)
        return out

    first = geometry()
    assert bpy.ops.sss.build_demo(scene_name="flash") == {"FINISHED"}
    assert geometry() == first
    assert len([o for o in bpy.data.objects if o.name.startswith("flash")]) == len(first)
    assert scene.render.fps == 60 and scene.camera.name == "flash Camera"
    light = bpy.data.lights["flash Sun"]
    for frame in (1, 2, 4, 7, 13):
        scene.frame_set(frame)
        t = (frame - 1) / 60
        peak = scenes.FLASH_PEAK
        assert light.energy == pytest.approx(
            peak / 2 * (math.sin(2 * math.pi * 5 * t) + 1), abs=1e-5
        )
    assert {m.name for m in materials.participating(scene)} == {
        "cvsss Skin",
        "cvsss Marble",
        "cvsss Apple",
    }
    assert scenes.names()[0] == "flash"
    with pytest.raises(ValueError, match="demo must be one of"):
        scenes.build("nope", scene)


class _Layout:
    """Records what a panel draws and checks every property and operator exists."""

    def __init__(self, log):
        self.log = log
        self.use_property_split = self.use_property_decorate = False
        self.active = self.enabled = True

    def _child(self, *args, **kwargs):
        return _Layout(self.log)

    row = column = box = _child

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, name
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        module, name = idname.split(".")
        assert name in dir(getattr(bpy.ops, module)), idname
        self.log.append(("operator", idname))

    def operator_menu_enum(self, idname, prop, **kwargs):
        self.operator(idname)

    def label(self, text="", **kwargs):
        self.log.append(("label", text))


def test_panel_says_when_the_files_python_does_not_run(fresh, tmp_path):
    """One line before a render when Blender skipped a registered script or a Python
    driver of the file (its own render skips them too)."""
    from types import SimpleNamespace

    from cvsss.sss_addon.blender import panels

    note = ("label", "Auto Run off: this file's Python drivers/scripts do not run")

    def drawn() -> list:
        log = []
        context = SimpleNamespace(scene=bpy.context.scene)
        panels.SSS_PT_render.draw(SimpleNamespace(layout=_Layout(log)), context)
        return log

    assert note not in drawn()
    rig = bpy.data.texts.new("rig.py")
    rig.write("registered = True\n")
    rig.use_module = True
    path = tmp_path / "rig.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    try:
        bpy.ops.wm.open_mainfile(filepath=str(path))  # as Blender's preference says: off
        assert note in drawn()
        bpy.ops.wm.open_mainfile(filepath=str(path), use_scripts=True)  # trusted
        assert note not in drawn()
    finally:
        bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)  # untrusted again


def test_panels_draw(fresh):
    from types import SimpleNamespace

    import numba

    from cvsss.sss_addon.blender import panels

    log = []
    context = SimpleNamespace(scene=fresh)
    panels.SSS_PT_render.draw(SimpleNamespace(layout=_Layout(log)), context)
    drawn = {name for kind, name in log if kind == "prop"}
    assert set(PARAM_PROPS) | {"method", "cv_mode", "engine", "output_dir"} <= drawn
    assert {name for kind, name in log if kind == "operator"} == {
        "sss.render_passes",
        "sss.apply_frame",
        "sss.render_sequence",
        "sss.build_demo",
    }
    assert ("label", "No frame processed yet") in log
    # Main panel + Advanced sub-panel: every parameter the command line takes.
    panels.SSS_PT_render_advanced.draw(SimpleNamespace(layout=_Layout(log)), context)
    drawn = {name for kind, name in log if kind == "prop"}
    generated = param_properties()
    assert set(generated) <= drawn
    flags = {
        (cls.__name__, f.name)
        for _, cls, _ in cli_params.GROUPS
        for f, spec in specs(cls)
        if flag_of(f, spec)
    }
    shown = {(cls.__name__, f.name) for cls, f, _ in generated.values()}
    # Measured materials and their scale are per material in Blender (Material panel:
    # preset, preset_scale; millimetres per unit from the scene's unit scale).
    assert flags - shown == {("ProfileChoice", "mm_per_unit"), ("ProfileChoice", "scale")}
    s = fresh.sss_settings
    s.has_stats, s.last_spp, s.last_sampling_ms, s.last_psnr = True, 12.5, 3.25, 48.0
    log.clear()
    panels.SSS_PT_render.draw(SimpleNamespace(layout=_Layout(log)), context)
    assert ("label", "Mean spp: 12.50") in log and ("label", "PSNR: 48.00 dB") in log
    # Which sampling backend runs: numba is pinned in this environment.
    assert (
        "label",
        f"Backend: numba ({numba.__version__}, {numba.get_num_threads()} threads)",
    ) in log
    log.clear()
    panels.SSS_PT_render_advanced.draw(SimpleNamespace(layout=_Layout(log)), context)
    assert ("prop", "backend") in log and (
        "label",
        "Runs: numba (" + numba.__version__ + ", " f"{numba.get_num_threads()} threads)",
    ) in log
    s.backend = "numpy"
    log.clear()
    panels.SSS_PT_render_advanced.draw(SimpleNamespace(layout=_Layout(log)), context)
    assert ("label", "Runs: NumPy") in log

    material = bpy.data.materials.new("m")
    material.node_tree.nodes["Principled BSDF"].inputs["Subsurface Weight"].default_value = 1
    assert material.node_tree.nodes["Principled BSDF"].subsurface_method == "RANDOM_WALK"
    material.node_tree.nodes["Principled BSDF"].subsurface_method = "BURLEY"
    log.clear()
    panels.SSS_PT_material.draw(
        SimpleNamespace(layout=_Layout(log)), SimpleNamespace(material=material)
    )
    assert {"mode", "participates", "use_override", "d_override", "preset"} <= {
        name for kind, name in log if kind == "prop"
    }
    d = blender_shape((1.0, 0.2, 0.1), 0.05)
    assert ("label", "R {:.5g}  G {:.5g}  B {:.5g}".format(*d)) in log
    assert ("label", "Model: Christensen-Burley (the node's Subsurface Method)") in log

    # A random walk: the panel names it and shows the fitted model's d and energy.
    material.node_tree.nodes["Principled BSDF"].subsurface_method = "RANDOM_WALK_SKIN"
    log.clear()
    panels.SSS_PT_material.draw(
        SimpleNamespace(layout=_Layout(log)), SimpleNamespace(material=material)
    )
    assert ("label", "Model: Random Walk (Skin) (the node's Subsurface Method)") in log
    d, e = random_walk.shape((1.0, 0.2, 0.1), 0.05, (0.8, 0.8, 0.8), "RANDOM_WALK_SKIN")
    assert ("label", "R {:.5g}  G {:.5g}  B {:.5g}".format(*d)) in log
    assert ("label", "Energy: R {:.3f}  G {:.3f}  B {:.3f}".format(*e)) in log

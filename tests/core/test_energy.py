"""A material's random-walk subsurface in the post: its fitted shape and its energy per pixel.

core.profiles.factory gives a RANDOM_WALK / RANDOM_WALK_SKIN slot the fitted
model's Burley d (core.profiles.random_walk.shape), and core.energy scales the
scattered light of its pixels by e·V(A, μ)·C(A, ℓ·H) before the composite. The
expected factors here come from the model's functions at the analytic view
cosine and curvature of the synthetic surfaces, not from core.energy; the
unscaled light comes from the same frame with the slot made BURLEY at the
model's d.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest
from tiling_helpers import FAST, differences, moving_frame, run_tiled, run_whole, same_state

from cvsss.core import synthetic
from cvsss.core.energy import REACH, scale_shaded
from cvsss.core.frame import Frame, MaterialSpec
from cvsss.core.io.sidecar import make_sidecar, read_sidecar, write_sidecar
from cvsss.core.method import MethodOptions
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.profiles import random_walk as rw
from cvsss.core.profiles.factory import ProfileError, build_profile, frame_profile
from cvsss.core.tiling import halo_px

PALE = [0.8, 0.55, 0.45]
RADIUS, SCALE = [1.0, 0.4, 0.2], 0.1
OPTIONS = {
    "base_color": PALE,
    "subsurface_radius": RADIUS,
    "subsurface_scale": SCALE,
    "subsurface_ior": 1.4,
    "subsurface_anisotropy": 0.0,
}
PARAMS = dataclasses.replace(FAST, reference_spp=32)


def _walk(spec: MaterialSpec, method="RANDOM_WALK", **options) -> MaterialSpec:
    return dataclasses.replace(spec, method=method, options={**OPTIONS, **options})


def _with(frame: Frame, **specs) -> Frame:
    materials = dict(frame.materials)
    for key, spec in specs.items():
        materials[int(key[1:])] = spec
    return dataclasses.replace(frame, materials=materials)


def _as_burley(frame: Frame, slot: int) -> Frame:
    """The frame with ``slot`` a BURLEY material at the model's d (the unscaled light)."""
    spec = frame.materials[slot]
    o = spec.options
    d, _ = rw.shape(
        o["subsurface_radius"],
        o["subsurface_scale"],
        o["base_color"],
        spec.method,
        o["subsurface_ior"],
        o["subsurface_anisotropy"],
    )
    burley = MaterialSpec(slot, spec.name, tuple(d), weight=spec.weight)
    return _with(frame, **{f"s{slot}": burley})


# -- the profile ---------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["RANDOM_WALK", "RANDOM_WALK_SKIN"])
def test_a_random_walk_slot_gets_the_models_shape_and_energy(method):
    burley = MaterialSpec(1, "wax", (0.01, 0.004, 0.002))
    walk = _walk(MaterialSpec(2, "skin", (0.03, 0.03, 0.03)), method, subsurface_ior=1.33)
    prof = build_profile({1: burley, 2: walk}, 3)
    d, e = rw.shape(RADIUS, SCALE, PALE, method, 1.33, 0.0)
    np.testing.assert_array_equal(prof.d[2], d)  # the spec's own d is not used
    np.testing.assert_array_equal(prof.d[1], burley.d)
    assert prof.energy.methods == ("BURLEY", "BURLEY", method)
    np.testing.assert_array_equal(prof.energy.energy[2], e)
    np.testing.assert_array_equal(prof.energy.energy[:2], 1.0)
    ell = rw.mean_free_path(RADIUS, SCALE, PALE, method, 1.33)
    np.testing.assert_array_equal(prof.energy.ell[2], ell)
    assert not np.allclose(d, walk.d) and np.all(e < 1)


def test_without_radius_and_scale_the_model_takes_them_from_d():
    """A hand-written sidecar: d is Blender's radius·scale/(4π)."""
    d_blender = tuple(np.array(RADIUS) * SCALE / (4 * math.pi))
    spec = MaterialSpec(1, "skin", d_blender, method="RANDOM_WALK", options={"base_color": PALE})
    d, _ = rw.shape(RADIUS, SCALE, PALE, "RANDOM_WALK")
    np.testing.assert_allclose(build_profile({1: spec}, 2).d[1], d, rtol=1e-12)


def test_burley_materials_build_the_same_profile_and_no_energy():
    spec = MaterialSpec(1, "wax", (0.01, 0.004, 0.002))
    prof = build_profile({1: spec}, 2)
    assert prof.energy is None
    np.testing.assert_array_equal(prof.d[1], spec.d)


def test_a_random_walk_material_without_base_color_is_refused():
    spec = MaterialSpec(3, "skin", (0.01,) * 3, method="RANDOM_WALK")
    with pytest.raises(ProfileError, match=r"'skin' \(slot 3\).*'base_color'"):
        build_profile({3: spec}, 4)


def test_a_preset_defines_the_profile_not_the_model():
    spec = _walk(MaterialSpec(1, "skin", (0.01,) * 3), preset="skin1")
    prof = build_profile({1: spec}, 2)
    assert prof.energy is None


# -- the sidecar ---------------------------------------------------------------------------
def test_old_sidecars_mean_burley_and_new_ones_keep_the_method(tmp_path):
    cam = synthetic.flat_plane().camera
    old = make_sidecar(cam, [MaterialSpec(1, "wax", (0.01, 0.004, 0.002))])
    assert "method" not in old["materials"][0]  # a BURLEY entry is written as before
    write_sidecar(tmp_path / "old.json", old)
    assert read_sidecar(tmp_path / "old.json").materials[1].method == "BURLEY"
    walk = _walk(MaterialSpec(2, "skin", (0.01,) * 3), "RANDOM_WALK_SKIN", base_color_linked=True)
    write_sidecar(tmp_path / "new.json", make_sidecar(cam, [walk]))
    raw = json.loads((tmp_path / "new.json").read_text())
    assert raw["materials"][0]["method"] == "RANDOM_WALK_SKIN"
    back = read_sidecar(tmp_path / "new.json").materials[2]
    assert back.method == "RANDOM_WALK_SKIN" and back.options == walk.options
    with pytest.raises(ValueError, match="subsurface method must be one of"):
        MaterialSpec(1, "x", (0.01,) * 3, method="CHRISTENSEN")


def test_a_linked_base_color_is_the_mean_of_the_diffuse_color_pass():
    frame = synthetic.flat_plane(32, 16)
    albedo = frame.albedo.copy()
    albedo[:, :16] = (0.2, 0.4, 0.6)
    albedo[:, 16:] = (0.6, 0.2, 0.3)
    spec = _walk(frame.materials[1], base_color_linked=True)
    made = dataclasses.replace(frame, albedo=albedo, materials={1: spec})
    assert made.materials[1].options["base_color"] == [0.4, 0.3, 0.45]
    unlinked = dataclasses.replace(frame, albedo=albedo, materials={1: _walk(frame.materials[1])})
    assert unlinked.materials[1].options["base_color"] == PALE


# -- the light of the pixels ---------------------------------------------------------------
def _pixels(frame, result):
    return result.mask & (frame.material == 1)


@pytest.mark.parametrize("name", ["reference", "separable"])
def test_a_tilted_plane_is_scaled_by_energy_and_view(name):
    """A plane turned 60° about the vertical: flat (C = 1), μ from the analytic normal."""
    tilt = math.radians(60.0)
    plane = synthetic.tilted_plane(48, 32, tilt=60.0)
    frame = _with(plane, s1=_walk(plane.materials[1]))
    base = make_processor(name, PARAMS).process(_as_burley(frame, 1))
    got = make_processor(name, PARAMS).process(frame)
    cam = frame.camera
    wu, hu = cam.unit_footprint()
    yy, xx = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    ray = np.stack(
        [(xx - cam.principal_point[0]) * wu, (yy - cam.principal_point[1]) * hu, np.ones_like(xx)],
        axis=-1,
    )
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    normal = np.array([math.sin(tilt), 0.0, -math.cos(tilt)])  # the plane z·cos = x·sin + ...
    mu = np.abs(ray @ normal)
    sel = _pixels(frame, got)
    sel[:, [0, -1]] = sel[[0, -1], :] = False  # one-sided normals on the image border
    _, e = rw.shape(RADIUS, SCALE, PALE, "RANDOM_WALK")
    want = e * rw.view_factor(PALE, mu[sel], "RANDOM_WALK")
    ratio = got.sss[sel].astype(np.float64) / base.sss[sel]
    np.testing.assert_allclose(ratio, want, rtol=2e-4)
    assert np.ptp(want[:, 0]) > 0.01  # the view angle changes across the plane
    # The composite follows: F = Combined − A·B + A·L (weight 1).
    f = frame.combined - frame.albedo * frame.lighting + frame.albedo * got.sss
    np.testing.assert_allclose(got.composite[sel], f[sel], rtol=1e-5, atol=1e-6)


def test_a_sphere_is_scaled_by_energy_view_and_curvature():
    """A sphere of radius R: normal (P − C)/R and mean curvature 1/R at every pixel."""
    radius, depth = 0.4, 2.0
    ball = synthetic.sphere(64, 48, radius=radius, depth=depth)
    spec = _walk(ball.materials[1], subsurface_radius=[1.0, 0.5, 0.25], subsurface_scale=0.12)
    frame = _with(ball, s1=spec)
    base = make_processor("reference", PARAMS).process(_as_burley(frame, 1))
    got = make_processor("reference", PARAMS).process(frame)
    cam = frame.camera
    wu, hu = cam.unit_footprint()
    yy, xx = np.mgrid[0 : cam.height, 0 : cam.width].astype(np.float64)
    z = frame.depth.astype(np.float64)
    p = np.stack(
        [(xx - cam.principal_point[0]) * wu * z, (yy - cam.principal_point[1]) * hu * z, z], axis=-1
    )
    n = (p - np.array([0.0, 0.0, depth])) / radius
    with np.errstate(invalid="ignore"):  # the background's inf depth
        mu = np.abs(np.sum(n * p, axis=-1)) / np.linalg.norm(p, axis=-1)
    sel = _pixels(frame, got) & (mu > 0.5)
    o = spec.options
    _, e = rw.shape(o["subsurface_radius"], o["subsurface_scale"], PALE, "RANDOM_WALK")
    ell = rw.mean_free_path(o["subsurface_radius"], o["subsurface_scale"], PALE, "RANDOM_WALK")
    assert 0.01 < ell[0] / radius < rw.MAX_ELL_CURVATURE  # below the cap: C varies by channel
    want = (
        e
        * rw.view_factor(PALE, mu[sel], "RANDOM_WALK")
        * rw.curvature_factor(PALE, np.full((sel.sum(), 1), 1.0 / radius) * ell, "RANDOM_WALK")
    )
    ratio = got.sss[sel].astype(np.float64) / base.sss[sel]
    # The depth buffer's normals and curvature are finite differences of the sphere's
    # depth: close to the analytic ones on most pixels, off by up to half the curvature
    # on rows and columns where a neighbour's depth step is not continued (the apex).
    error = np.abs(ratio / want - 1.0)
    assert np.median(error) < 2e-3  # the curvature term alone is > 1.5 % (below)
    assert np.mean(error < 5e-3) > 0.85
    flat = e * rw.view_factor(PALE, mu[sel], "RANDOM_WALK")
    assert np.all(want[:, 0] / flat[:, 0] > 1.015)  # the curvature term is felt


def test_planar_distance_applies_the_energy_only():
    ball = synthetic.sphere(48, 32)
    frame = _with(ball, s1=_walk(ball.materials[1]))
    params = dataclasses.replace(PARAMS, distance="planar")
    base = make_processor("reference", params).process(_as_burley(frame, 1))
    got = make_processor("reference", params).process(frame)
    sel = _pixels(frame, got)
    _, e = rw.shape(RADIUS, SCALE, PALE, "RANDOM_WALK")
    np.testing.assert_allclose(
        got.sss[sel].astype(np.float64) / base.sss[sel], np.tile(e, (sel.sum(), 1)), rtol=2e-7
    )


def test_burley_slots_are_unchanged_bit_for_bit():
    two = synthetic.scene_frame("flash", 3, 96, 64)
    mixed = _with(two, s1=_walk(two.materials[1]))
    for name in ("reference", "separable"):
        plain = make_processor(name, PARAMS).process(two)
        got = make_processor(name, PARAMS).process(mixed)
        marble = two.material == 2
        assert np.array_equal(got.sss[marble], plain.sss[marble])
        assert np.array_equal(got.composite[marble], plain.composite[marble])
        assert not np.array_equal(got.sss[two.material == 1], plain.sss[two.material == 1])
    geom_frame = synthetic.flat_plane(16, 8)
    proc = make_processor("reference", PARAMS)
    shaded = np.ones((16 * 8, 3))
    geom = proc._geometry.get(geom_frame, frame_profile(geom_frame, PARAMS))
    assert scale_shaded(geom_frame, geom, frame_profile(geom_frame, PARAMS), shaded) is shaded


def test_none_stays_the_frame_without_scattering():
    ball = synthetic.sphere(32, 24)
    frame = _with(ball, s1=_walk(ball.materials[1]))
    res = make_processor("none", PARAMS).process(frame)
    assert np.array_equal(res.composite, frame.combined)


# -- tiles ---------------------------------------------------------------------------------
def _walking(frame: Frame) -> Frame:
    return _with(frame, s1=_walk(frame.materials[1], "RANDOM_WALK_SKIN"))


@pytest.mark.parametrize("name", ["fixed", "as_ccv_t", "separable"])
def test_tiles_equal_the_whole_image(name):
    frames = [_walking(moving_frame(n)) for n in (1, 2)]
    whole, whole_state = run_whole(name, FAST, MethodOptions(), frames)
    tiled, tiled_state, session = run_tiled(name, FAST, MethodOptions(), frames)
    assert len(session.cores) == 12
    for a, b in zip(whole, tiled):
        assert differences(a, b) == []
    assert same_state(whole_state, tiled_state)
    plain, _ = run_whole(name, FAST, MethodOptions(), [moving_frame(n) for n in (1, 2)])
    assert not np.array_equal(plain[-1].sss, whole[-1].sss)


def test_the_halo_covers_the_curvatures_neighbours():
    """The energy reads the depth REACH pixels away: a material scattering less than a
    pixel still has a halo of ceil(radius) + 1 = REACH (core.tiling)."""
    still = dataclasses.replace(moving_frame(1), motion=None)
    tiny = _with(still, s1=_walk(still.materials[1], subsurface_scale=1e-4))
    tiny = _with(tiny, s2=dataclasses.replace(tiny.materials[2], d=(1e-5,) * 3))
    assert halo_px(tiny, frame_profile(tiny, SSSParams())) == REACH == 2


# -- hidden surface ------------------------------------------------------------------------
def test_random_walk_slots_do_not_read_the_mirror_image():
    """Mirror Hidden Light stands in for the light Cycles' disk probes read on the hidden
    side; a walk leaves through that side instead (accuracy §2.1). So a Random Walk
    slot's hidden-surface samples take the centre's light with the mirror on as off,
    while a Christensen-Burley slot's read the mirror image there."""
    from cvsss.core.geometry import geometry_of
    from cvsss.core.mc.estimator import estimate_distant, mirror_slots

    flash = synthetic.scene_frame("flash", 2, 160, 90)
    walked = _with(flash, s1=_walk(flash.materials[1]))
    runs = {}
    for name, frame in (("burley", flash), ("walk", walked)):
        profile = frame_profile(frame, SSSParams())
        geom = geometry_of(frame, profile, surface_distance=True)
        counts = np.full(geom.size, 16, np.int64)
        for mirror in (False, True):
            est = estimate_distant(
                geom, frame.lighting, frame.depth, profile, counts, frame=2, seed=0,
                depth_slope=2.0, disk=True, hidden_mirror=mirror,
            )  # fmt: skip
            runs[name, mirror] = geom.mat.copy(), est.distant
    assert mirror_slots(frame_profile(walked, SSSParams()), True).tolist() == [True, False, True]
    assert mirror_slots(frame_profile(walked, SSSParams()), False) is None
    for name, slot_changes in (("burley", {1: True, 2: True}), ("walk", {1: False, 2: True})):
        mat, off = runs[name, False]
        _, on = runs[name, True]
        for slot, changes in slot_changes.items():
            rows = mat == slot
            assert (not np.array_equal(on[rows], off[rows])) == changes, (name, slot)

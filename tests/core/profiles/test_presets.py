"""Measured presets, their Burley shapes and units, and the profile factory (all Table 2 rows)."""

import numpy as np
import pytest

from cvsss.core import SSSParams
from cvsss.core.frame import MaterialSpec
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.method import MethodOptions
from cvsss.core.methods import make_processor
from cvsss.core.profiles import (
    ArtistProfile,
    BurleyProfile,
    DipoleProfile,
    MixedProfile,
    ProfileChoice,
    presets,
)
from cvsss.core.profiles.factory import ProfileError, build_profile
from cvsss.core.synthetic import flat_plane, scene_frame

NAMES = (
    "apple",
    "chicken1",
    "chicken2",
    "cream",
    "ketchup",
    "marble",
    "potato",
    "skimmilk",
    "skin1",
    "skin2",
    "wholemilk",
)


def test_every_measured_material_is_a_preset():
    assert presets.names() == NAMES
    skin1 = presets.get("Skin1")
    assert skin1.sigma_a == (0.032, 0.17, 0.48) and skin1.sigma_s == (0.74, 0.88, 1.01)
    assert presets.get("marble").eta == 1.5
    with pytest.raises(ValueError, match="valid presets: apple, chicken1, .*wholemilk"):
        presets.get("jelly")


@pytest.mark.parametrize("name", NAMES)
def test_derived_burley_shape(name):
    m = presets.get(name)
    a = m.total_reflectance()
    assert np.all((a > 0) & (a < 1))
    ell = 1.0 / (np.array(m.sigma_a) + np.array(m.sigma_s))
    s = 1.9 - a + 3.5 * (a - 0.8) ** 2
    assert np.allclose(m.burley_d_mm(), ell / s)
    # Units: metres (1000 mm per unit) and an artist scale.
    assert np.allclose(m.burley_d(), m.burley_d_mm() / 1000)
    assert np.allclose(m.burley_d(mm_per_unit=10.0, scale=3.0), m.burley_d_mm() * 0.3)
    assert np.allclose(m.mean_free_path, ell)


def test_unit_factor_validation():
    assert presets.unit_factor() == pytest.approx(1e-3)
    for bad in (0.0, -1.0, float("nan"), float("inf"), True):
        with pytest.raises(ValueError, match="mm_per_unit must be"):
            presets.unit_factor(mm_per_unit=bad)
        with pytest.raises(ValueError, match="scale must be"):
            presets.unit_factor(scale=bad)


def test_parse_material_and_choice():
    assert ProfileChoice.parse_material("SKIN1") == ("skin1", ())
    assert ProfileChoice.parse_material("1=skin1, 2=marble") == (
        None,
        ((1, "skin1"), (2, "marble")),
    )
    for bad in ("", "1=", "x=skin1", "1=jelly", "skin1,marble"):
        with pytest.raises(ValueError):
            ProfileChoice.parse_material(bad)
    with pytest.raises(ValueError, match="profile must be one of burley, dipole, artist"):
        ProfileChoice(profile="gaussian")
    choice = ProfileChoice(
        profile="dipole", material="skin2", slot_materials=((2, "marble"),), scale=5.0
    )
    specs = choice.apply(
        {1: MaterialSpec(1, "a", (0.01,) * 3), 2: MaterialSpec(2, "b", (0.01,) * 3)}
    )
    assert specs[1].profile == specs[2].profile == "dipole"
    assert specs[1].options == {"preset": "skin2", "mm_per_unit": 1000.0, "scale": 5.0}
    assert specs[2].options["preset"] == "marble"
    assert (
        choice.to_dict()
        == ProfileChoice(**{**choice.to_dict(), "slot_materials": ((2, "marble"),)}).to_dict()
    )


def _specs(**kinds):
    return {
        i: MaterialSpec(i, f"m{i}", (0.01, 0.005, 0.002), profile=kind, options=opts)
        for i, (kind, opts) in enumerate(kinds.values(), 1)
    }


def test_factory_builds_each_profile_and_mixtures():
    burley = build_profile(_specs(a=("burley", {})), 2)
    assert isinstance(burley, BurleyProfile) and np.allclose(burley.d[1], (0.01, 0.005, 0.002))
    preset_burley = build_profile(_specs(a=("burley", {"preset": "skin1"})), 2)
    assert np.allclose(preset_burley.d[1], presets.get("skin1").burley_d())
    dip = build_profile(_specs(a=("dipole", {"preset": "skin1", "scale": 10.0})), 2)
    assert isinstance(dip, DipoleProfile) and np.allclose(dip.unit[1], 0.01)
    addon = {"preset": "skin1", "preset_scale": 4.0, "mm_per_unit": 10.0}  # sss_addon.materials
    assert np.allclose(build_profile(_specs(a=("dipole", addon)), 2).unit[1], 0.4)
    explicit = build_profile(
        _specs(a=("dipole", {"sigma_a": [0.03, 0.2, 0.5], "sigma_s": 1.0, "eta": 1.4})), 2
    )
    assert np.allclose(explicit.sigma_s[1], 1.0) and explicit.eta[1] == 1.4
    art = build_profile(
        _specs(a=("artist", {"strength": [0.5] * 3, "near": 0.01, "far": 0.05, "weight": 0.4})), 2
    )
    assert isinstance(art, ArtistProfile) and np.allclose(art.strength[1], 0.5)
    derived = build_profile(_specs(a=("artist", {"preset": "skin1", "strength": 0.7})), 2)
    assert np.allclose(derived.strength[1], 0.7) and np.all(derived.far[1] > derived.near[1])
    from_d = build_profile(_specs(a=("artist", {})), 2)
    assert np.all(from_d.far[1] > from_d.near[1]) and np.all(from_d.strength[1] > 0)
    mixed = build_profile(
        _specs(
            a=("burley", {}), b=("dipole", {"preset": "marble"}), c=("artist", {"preset": "skin1"})
        ),
        4,
    )
    assert isinstance(mixed, MixedProfile) and mixed.pixel_weight_scale
    kinds = [type(mixed.profiles[mixed.owner[s]]) for s in (1, 2, 3)]
    assert kinds == [BurleyProfile, DipoleProfile, ArtistProfile]
    assert mixed.scatters().tolist() == [False, True, True, True]


@pytest.mark.parametrize(
    ("opts", "kind", "fragment"),
    [
        ({}, "dipole", "needs a measured preset"),
        ({"preset": "jelly"}, "dipole", "unknown material preset"),
        ({"sigma_a": [1, 2], "sigma_s": 1}, "dipole", "3 finite numbers"),
        ({"preset": "skin1", "scale": -1}, "burley", "scale must be"),
        ({}, "voronoi", "profile must be one of"),
    ],
)
def test_factory_errors_name_the_material(opts, kind, fragment):
    with pytest.raises(ProfileError, match=fragment) as info:
        build_profile(_specs(a=(kind, opts)), 2)
    assert "'m1' (slot 1)" in str(info.value)


@pytest.mark.parametrize("m", [0, 3, 32])
def test_mixed_profile_constant_lighting_is_exact(m):
    frame = flat_plane(lighting=np.full((48, 64, 3), [0.4, 1.1, 2.5], np.float32))
    frame.material[:, 20:40] = 2
    frame.material[:, 40:] = 3
    specs = _specs(
        a=("burley", {}),
        b=("dipole", {"preset": "skin1", "scale": 20.0}),
        c=(
            "artist",
            {
                "strength": [0.6] * 3,
                "near": [0.05, 0.03, 0.02],
                "far": [0.2, 0.1, 0.05],
                "weight": 0.5,
            },
        ),
    )
    prof = build_profile(specs, 4)
    geom = geometry_of(frame, prof)
    counts = np.full(geom.size, m)
    est = estimate_distant(
        geom,
        frame.lighting,
        frame.depth,
        prof,
        counts,
        frame=1,
        seed=3,
        depth_slope=2.0,
    )
    b = frame.lighting.reshape(-1, 3)[geom.index]
    shaded = (1 - geom.gamma) * b + est.distant
    assert np.max(np.abs(shaded - b)) <= 1e-12 * 2.5
    assert est.samples == m * geom.size and geom.gamma.max() > 0.3


@pytest.mark.parametrize("profile", ["burley", "dipole", "artist"])
def test_sequence_processor_runs_every_profile(profile):
    choice = ProfileChoice(profile=profile, material="skin1", scale=20.0)
    proc = make_processor("as_ccv", SSSParams(), MethodOptions(profile=choice))
    frame = scene_frame("flash", 2, 64, 36)
    res = proc.process(frame)
    assert np.all(np.isfinite(res.composite)) and res.samples > 0
    assert res.gamma[res.mask].max() > 0.1

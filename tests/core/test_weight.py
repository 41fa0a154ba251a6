"""Subsurface Weight: the composite mixes (1 − w)·B + w·L as Cycles mixes diffuse and subsurface."""

import dataclasses

import numpy as np
import pytest

from cvsss.core import SSSParams, make_processor
from cvsss.core.frame import MaterialSpec
from cvsss.core.synthetic import scene_frame


def with_weight(frame, weights: dict, sss_weight=None):
    materials = {
        s: dataclasses.replace(m, weight=weights.get(s, 1.0)) for s, m in frame.materials.items()
    }
    return dataclasses.replace(frame, materials=materials, sss_weight=sss_weight)


def test_constant_weight_mixes_diffuse_and_subsurface():
    frame = scene_frame("flash", 3, 64, 36)
    full = make_processor("fixed", SSSParams(fixed_spp=16)).process(frame)
    half = make_processor("fixed", SSSParams(fixed_spp=16)).process(with_weight(frame, {1: 0.5}))
    none = make_processor("none").process(frame)
    np.testing.assert_array_equal(half.sss, full.sss)  # L itself does not change
    skin = frame.material == 1
    expected = 0.5 * (none.composite + full.composite)
    np.testing.assert_allclose(half.composite[skin], expected[skin], rtol=2e-6, atol=1e-7)
    other = frame.material == 2
    np.testing.assert_array_equal(half.composite[other], full.composite[other])
    zero = make_processor("fixed", SSSParams(fixed_spp=16)).process(with_weight(frame, {1: 0.0}))
    np.testing.assert_array_equal(zero.composite[skin], none.composite[skin])


def test_per_pixel_weight_overrides_the_constant_where_given():
    frame = scene_frame("flash", 3, 64, 36)
    sw = np.full(frame.shape, np.nan, np.float32)
    sw[:, :32] = 0.25
    full = make_processor("fixed", SSSParams(fixed_spp=16)).process(frame)
    none = make_processor("none").process(frame)
    res = make_processor("fixed", SSSParams(fixed_spp=16)).process(
        with_weight(frame, {1: 0.5, 2: 0.5}, sss_weight=sw)
    )
    sss = frame.material > 0
    left = sss.copy()
    left[:, 32:] = False
    right = sss & ~left
    np.testing.assert_allclose(
        res.composite[left],
        (0.75 * none.composite + 0.25 * full.composite)[left],
        rtol=2e-6,
        atol=1e-7,
    )
    np.testing.assert_allclose(
        res.composite[right],
        (0.5 * none.composite + 0.5 * full.composite)[right],
        rtol=2e-6,
        atol=1e-7,
    )


def test_weight_scales_what_the_adaptive_sampler_tracks():
    """Half the weight shows half the noise: the tracked variance drops 4x, counts follow."""
    frames = [scene_frame("flash", n, 64, 36) for n in range(1, 9)]
    p = SSSParams(target_variance=1e-5)
    full, half = make_processor("as", p), make_processor("as", p)
    for f in frames:
        a = full.process(f)
        b = half.process(with_weight(f, {1: 0.5, 2: 0.5}))
    m = a.mask & (a.counts > 0)
    np.testing.assert_allclose(b.variance[m].mean(), a.variance[m].mean() / 4, rtol=0.35)
    assert b.spp < a.spp


@pytest.mark.parametrize("bad", [-0.1, 1.5, float("nan"), True])
def test_weight_out_of_range_is_refused(bad):
    with pytest.raises(ValueError, match="subsurface weight must be in"):
        MaterialSpec(1, "m", (0.01,) * 3, weight=bad)


def test_weight_round_trips_through_the_sidecar():
    spec = MaterialSpec(1, "m", (0.01,) * 3, weight=0.3)
    assert MaterialSpec.from_dict(spec.to_dict()) == spec
    assert MaterialSpec.from_dict({"slot": 1, "d": [0.01] * 3}).weight == 1.0

"""core.result.relit: a method's composite with another lighting image put in."""

import dataclasses

import numpy as np

from cvsss.core import SSSParams, make_processor
from cvsss.core.result import relit
from cvsss.core.synthetic import scene_frame


def weighted_frame():
    """The flash scene with material 1 at Subsurface Weight 0.5 and a per-pixel 0.25 on
    the left half."""
    frame = scene_frame("flash", 3, 64, 36)
    materials = dict(frame.materials)
    materials[1] = dataclasses.replace(materials[1], weight=0.5)
    per_pixel = np.full(frame.shape, np.nan, np.float32)
    per_pixel[:, :20] = 0.25
    return dataclasses.replace(frame, materials=materials, sss_weight=per_pixel)


def test_relit_with_the_methods_own_lighting_is_its_composite():
    frame = weighted_frame()
    result = make_processor("fixed", SSSParams(fixed_spp=16)).process(frame)
    np.testing.assert_allclose(
        relit(frame, result.mask, result.sss), result.composite, rtol=2e-6, atol=1e-7
    )


def test_relit_adds_albedo_times_weight_times_the_lighting_change():
    frame = weighted_frame()
    mask = frame.material > 0
    out = relit(frame, mask, frame.lighting + 1.0)
    weight = np.where(frame.material == 1, 0.5, 1.0)
    weight[:, :20] = 0.25
    expected = frame.combined + np.where(mask, weight, 0.0)[..., None] * frame.albedo
    np.testing.assert_allclose(out, expected, rtol=2e-6, atol=1e-6)
    # The passes' own lighting changes nothing.
    np.testing.assert_allclose(relit(frame, mask, frame.lighting), frame.combined, atol=1e-6)

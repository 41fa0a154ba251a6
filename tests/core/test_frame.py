"""Frame: what its passes become (dtypes, repairs) and what it never changes."""

from __future__ import annotations

import numpy as np
import pytest

from cvsss.core import Camera, Frame
from cvsss.core.frame import MAX_OBJECTS

BAD = (np.nan, np.inf, -np.inf, -1.0)


def _frame(dtype, **passes) -> Frame:
    h, w = 2, 4
    base = {
        "lighting": np.full((h, w, 3), 0.5),
        "albedo": np.full((h, w, 3), 0.25),
        "combined": np.full((h, w, 3), 2.0),
        "depth": np.full((h, w), 3.0),
        "material": np.ones((h, w)),
    }
    base = {k: np.asarray(v).astype(dtype) for k, v in base.items()}
    base.update(passes)  # as given: the caller's own arrays
    return Frame(number=1, camera=Camera(width=w, height=h), materials={}, **base)


@pytest.mark.parametrize("dtype", [np.float16, np.float32, np.float64])
def test_each_bad_colour_becomes_zero_and_counts(dtype):
    light = np.full((2, 4, 3), 0.5)
    light[0, :, 0] = BAD  # NaN, +inf, -inf, a negative
    light[1, 0, 2] = -0.0  # not bad: a zero
    comb = np.full((2, 4, 3), 2.0)
    comb[1, 3, 1] = np.nan
    frame = _frame(dtype, lighting=light.astype(dtype), combined=comb.astype(dtype))
    want = np.full((2, 4, 3), 0.5, np.float32)
    want[0, :, 0] = 0.0
    want[1, 0, 2] = 0.0
    np.testing.assert_array_equal(frame.lighting, want)
    assert frame.lighting.dtype == np.float32
    assert frame.combined[1, 3, 1] == 0.0 and np.count_nonzero(frame.combined == 0.0) == 1
    assert frame.repaired == 4 + 1


def test_material_and_objects_round_clip_and_repair():
    material = np.array([[0.4, 0.6, 2.5, -3.0], [np.nan, np.inf, -np.inf, 3e9]])
    objects = np.array([[1.5, 2**20, -0.2, 7.0], [np.nan, 1.0, np.inf, 2.49]])
    frame = _frame(np.float64, material=material, objects=objects)
    np.testing.assert_array_equal(frame.material, [[0, 1, 2, 0], [0, 0, 0, 2**31 - 1]])
    np.testing.assert_array_equal(frame.objects, [[2, MAX_OBJECTS, 0, 7], [0, 1, 0, 2]])
    assert frame.material.dtype == np.int32 and frame.objects.dtype == np.int32
    assert frame.repaired == 3 + 2


def test_the_callers_arrays_are_left_as_they_were():
    light = np.full((2, 4, 3), 0.5, np.float32)
    light[0, 0, 0] = np.nan
    material = np.array([[1.0, np.nan, 2.0, 1.0]] * 2)
    kept = light.copy(), material.copy()
    frame = _frame(np.float32, lighting=light, material=material)
    assert frame.repaired == 3  # the NaN light and the two NaN slots
    np.testing.assert_array_equal(light, kept[0])
    np.testing.assert_array_equal(material, kept[1])
    assert not np.shares_memory(frame.lighting, light)

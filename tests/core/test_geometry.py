"""core.geometry: what the sampling step's inputs are made of."""

from __future__ import annotations

import numpy as np
import pytest

from cvsss.core.geometry import compact_slots


@pytest.mark.parametrize(
    "keys",
    [[1], [3, 7], [1, 2, 5, 65535], [2, 65536], [7, 2**31 - 1], [0, 4]],
)
@pytest.mark.parametrize("dtype", [np.int32, np.int64, np.uint32, np.uint64, np.uint8])
def test_compact_slots_maps_keys_to_their_rank_and_anything_else_to_zero(keys, dtype):
    """The lookup table (keys 1…65535, index types) and the binary search (other keys,
    uint64) give the same slots: ``keys[i]`` → i + 1, every other value → 0, including
    values above the largest key, negative ones and the Material Index pass's largest,
    2³¹ − 1."""
    keys = np.array(keys, dtype=np.int64)
    rng = np.random.default_rng(0)
    values = np.concatenate(
        [keys, keys + 1, keys - 1, [0, 1, 2, 65535, 65536, 2**31 - 1], rng.integers(0, 70000, 500)]
    )
    if np.dtype(dtype).kind == "i":
        values = np.concatenate([values, [-1, -70000]])
    values = values[(values >= np.iinfo(dtype).min) & (values <= np.iinfo(dtype).max)]
    material = values.astype(dtype).reshape(-1, 2 if values.size % 2 == 0 else 1)
    slots = compact_slots(material, keys)
    assert slots.dtype == np.int32 and slots.shape == material.shape
    rank = {int(k): i + 1 for i, k in enumerate(keys)}
    expected = np.array([rank.get(int(v), 0) for v in material.reshape(-1)]).reshape(slots.shape)
    assert np.array_equal(slots, expected)


def test_compact_slots_without_subsurface_materials_is_all_zero():
    assert not compact_slots(np.arange(10, dtype=np.int32), np.zeros(0, np.int64)).any()

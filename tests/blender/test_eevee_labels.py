"""EEVEE's labels: the filtered label AOVs of an EEVEE pass file become Cycles' index passes."""

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.errors import OutputError  # noqa: E402
from cvsss.sss_addon.blender import eevee_labels  # noqa: E402

pytestmark = pytest.mark.bpy


def _eevee_file(path, layer_aovs: dict, depth) -> None:
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    parts = [OpenEXR.Part(dict(header), {"ViewLayer.Depth.Z": depth}, "ViewLayer.Depth")]
    for name, values in layer_aovs.items():
        if isinstance(values, tuple):  # a colour AOV
            channels = {f"ViewLayer.{name}.{c}": v for c, v in zip("RGB", values)}
        else:
            channels = {f"ViewLayer.{name}.X": values}
        parts.append(OpenEXR.Part(dict(header), channels, f"ViewLayer.{name}"))
    OpenEXR.File(parts).write(str(path))


def test_aov_to_material_index_rewrites_an_eevee_file(tmp_path):
    """EEVEE filters the AOVs: edge pixels hold weighted means of the labels of the
    surfaces they cover. A pixel gets the slot of a surface holding over half of its
    weight, read through the cover or from a mix of two surfaces found nearby; any
    other mixed pixel gets no slot and a labelled neighbour's object (the largest)."""
    import OpenEXR

    # Row 0, left to right: slot 2 of object 5, whole; the same at 0.6 of the weight
    # beside a surface of another material; slot 3 of object 5 at a third; slot 1 of
    # object 4 (0.3, a label no whole pixel has) mixed with slot 2 of object 5 (0.7);
    # slot 3 of object 6, whole. Row 1: object 5 twice, nothing participating, slot 3
    # of object 6 (0.9) mixed with slot 1 of object 1 (0.1), slot 1 of object 1.
    # Row 2: the background.
    cover = np.array([[1, 0.6, 1 / 3, 1, 1], [1, 1, 0, 1, 1], [0, 0, 0, 0, 0]], np.float32)
    aov = np.array([[2, 1.2, 1.0, 1.7, 3], [2, 2, 0, 2.8, 1], [0, 0, 0, 0, 0]], np.float32)
    objects = np.array([[5, 3.0, 5 / 3, 4.7, 6], [5, 5, 0, 5.5, 1], [0, 0, 0, 0, 0]], np.float32)
    # The weighted sums of the squared slots and object numbers, likewise.
    aov_sq = np.array([[4, 2.4, 3, 3.1, 9], [4, 4, 0, 8.2, 1], [0, 0, 0, 0, 0]], np.float32)
    objects_sq = np.array(
        [[25, 15, 25 / 3, 22.3, 36], [25, 25, 0, 32.5, 1], [0, 0, 0, 0, 0]], np.float32
    )
    depth = np.full(cover.shape, 5.0, np.float32)
    depth[2] = 100.0025  # EEVEE background: the clip end
    path = tmp_path / "eevee.exr"
    aovs = {
        eevee_labels.AOV_NAME: aov,
        eevee_labels.OBJECT_AOV: objects,
        eevee_labels.COVER_AOV: (cover, aov_sq, objects_sq),
    }
    _eevee_file(path, aovs, depth)
    eevee_labels.aov_to_material_index(path, "ViewLayer", clip_end=100.0)
    f = OpenEXR.File(str(path), separate_channels=True)
    channels = {k: np.asarray(c.pixels) for p in f.parts for k, c in p.channels.items()}
    assert sorted(channels) == [
        "ViewLayer.Depth.Z",
        "ViewLayer.Material Index.X",
        "ViewLayer.Object Index.X",
    ]
    np.testing.assert_array_equal(
        channels["ViewLayer.Material Index.X"],
        [[2, 2, 0, 0, 3], [2, 2, 0, 3, 1], [0, 0, 0, 0, 0]],
    )
    np.testing.assert_array_equal(
        channels["ViewLayer.Object Index.X"],
        [[5, 5, 6, 6, 6], [5, 5, 0, 6, 1], [0, 0, 0, 0, 0]],
    )
    assert (channels["ViewLayer.Depth.Z"][2] == 1e10).all()
    assert (channels["ViewLayer.Depth.Z"][:2] == 5.0).all()


def test_eevee_labels_tell_two_objects_of_a_material_from_the_one_between():
    """Objects 3 and 1 of slot 2, half and half, average to object 2: the squares
    (5, not 4) show the mix. Dominant surface below half of the weight: no slot."""
    cover = np.array([[1, 0.8, 1, 0]])
    material = np.array([[2, 1.6, 2, 0]])
    objects = np.array([[3, 0.8 * 2, 1, 0]])
    material_sq = np.array([[4, 0.8 * 4, 4, 0]])
    objects_sq = np.array([[9, 0.8 * 5, 1, 0]])
    slots, numbers = eevee_labels.eevee_labels(material, objects, cover, material_sq, objects_sq)
    np.testing.assert_array_equal(slots, [[2, 0, 2, 0]])
    np.testing.assert_array_equal(numbers, [[3, 3, 1, 0]])


def test_aov_to_material_index_names_a_missing_aov(tmp_path):
    path = tmp_path / "eevee.exr"
    ones = np.ones((2, 2), np.float32)
    _eevee_file(path, {eevee_labels.AOV_NAME: ones, eevee_labels.OBJECT_AOV: ones}, ones)
    before = path.read_bytes()
    with pytest.raises(OutputError, match="no 'cvsss_cover' AOV"):
        eevee_labels.aov_to_material_index(path, "ViewLayer", clip_end=100.0)
    assert path.read_bytes() == before

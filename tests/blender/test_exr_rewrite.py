"""Rewriting a pass EXR in place: the edit lands, and a write that fails loses nothing."""

import numpy as np
import pytest

OpenEXR = pytest.importorskip("OpenEXR")
pytest.importorskip("bpy")

from cvsss.core.io import atomic  # noqa: E402
from cvsss.core.io.errors import OutputError  # noqa: E402
from cvsss.sss_addon.blender.exr_rewrite import rewrite_exr  # noqa: E402

pytestmark = pytest.mark.bpy

HEADER = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}


def _two_parts(path) -> None:
    parts = [
        OpenEXR.Part(dict(HEADER), {"V": np.full((3, 4), 0.25, np.float32)}, "layer.Index"),
        OpenEXR.Part(dict(HEADER), {"V": np.full((3, 4), 1.0, np.float32)}, "layer.extra"),
    ]
    OpenEXR.File(parts).write(str(path))


def _read(path) -> dict:
    exr = OpenEXR.File(str(path), separate_channels=True)
    return {p.name(): np.array(p.channels["V"].pixels) for p in exr.parts}


def _halve_and_drop(name, channels):
    if name == "layer.extra":
        return None
    return name, {k: v / 2 for k, v in channels.items()}


def test_the_edit_lands_and_nothing_is_left_beside(tmp_path):
    path = tmp_path / "pass.exr"
    _two_parts(path)
    rewrite_exr(path, _halve_and_drop)
    assert list(_read(path)) == ["layer.Index"]
    np.testing.assert_array_equal(_read(path)["layer.Index"], np.full((3, 4), 0.125))
    assert [p.name for p in tmp_path.iterdir()] == ["pass.exr"]


def test_a_write_that_fails_leaves_the_file_as_it_was(tmp_path, monkeypatch):
    """The disk fills while the new file is written (its sync fails): the pass file
    still holds both parts, unedited, and no temporary file stays beside it."""
    path = tmp_path / "pass.exr"
    _two_parts(path)
    before = path.read_bytes()

    def disk_full(self):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(atomic._Staged, "finish", disk_full)
    with pytest.raises(OutputError, match="No space left"):
        rewrite_exr(path, _halve_and_drop)
    assert path.read_bytes() == before
    assert [p.name for p in tmp_path.iterdir()] == ["pass.exr"]

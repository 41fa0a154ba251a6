"""Tests of core.exr: pass EXRs + sidecars in, result EXRs out, atomic writes."""

from __future__ import annotations

import dataclasses
import errno
import importlib.util
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from cvsss.core import Camera, Frame, FrameResult, MaterialSpec
from cvsss.core.io import atomic
from cvsss.core.io.errors import OutputError, PassError
from cvsss.core.io.exr import (
    list_frames,
    motion_from_vector,
    read_frame,
    read_pass,
    read_result,
    read_rgb,
    use_threads,
    vector_from_motion,
    write_passes,
    write_result,
)
from cvsss.core.io.sidecar import make_sidecar, write_sidecar

SKIN = MaterialSpec(slot=1, name="Skin", d=(0.01, 0.004, 0.002))
MARBLE = MaterialSpec(slot=2, name="Marble", d=(0.02, 0.02, 0.015), options={"preset": "x"})


# -- helpers ------------------------------------------------------------------------------
def make_frame(
    height: int = 6, width: int = 8, *, motion: bool = True, seed: int = 0, number: int = 7
) -> Frame:
    """A small frame with every pass filled, some background and two materials."""
    rng = np.random.default_rng(seed)
    depth = rng.uniform(1.0, 5.0, (height, width)).astype(np.float32)
    depth[0, :3] = np.inf
    material = rng.integers(0, 3, (height, width))
    material[0, :3] = 0
    return Frame(
        number=number,
        lighting=rng.uniform(0, 4, (height, width, 3)),
        albedo=rng.uniform(0, 1, (height, width, 3)),
        combined=rng.uniform(0, 4, (height, width, 3)),
        depth=depth,
        material=material,
        camera=Camera(width=width, height=height, lens=35.0, sensor_fit="HORIZONTAL"),
        materials={1: SKIN, 2: MARBLE},
        motion=rng.uniform(-3, 3, (height, width, 2)) if motion else None,
    )


def write_raw(
    path: Path,
    passes: dict[str, dict[str, np.ndarray]],
    *,
    layer: str = "ViewLayer",
    multipart: bool = True,
    camera: Camera | None = None,
    **sidecar,
) -> None:
    """Write an EXR with the given passes (pass -> channel -> (H, W)) and a sidecar."""
    head = f"{layer}." if layer else ""
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    if multipart:
        # Parts share the display window; a smaller pass gets a smaller data window.
        first = next(iter(next(iter(passes.values())).values()))
        parts = []
        for p, comps in passes.items():
            h, w = next(iter(comps.values())).shape
            windows = {
                "displayWindow": (np.zeros(2, np.int32), np.array(first.shape[::-1], np.int32) - 1),
                "dataWindow": (np.zeros(2, np.int32), np.array([w - 1, h - 1], np.int32)),
            }
            channels = {f"{head}{p}.{c}": a for c, a in comps.items()}
            parts.append(OpenEXR.Part({**header, **windows}, channels, f"{head}{p}"))
        exr_file = OpenEXR.File(parts)
    else:
        channels = {f"{head}{p}.{c}": a for p, comps in passes.items() for c, a in comps.items()}
        exr_file = OpenEXR.File(header, channels)
    exr_file.write(str(path))
    if camera is None:
        any_pass = next(iter(next(iter(passes.values())).values()))
        camera = Camera(width=any_pass.shape[1], height=any_pass.shape[0])
    data = make_sidecar(camera, [SKIN], view_layer=sidecar.pop("view_layer", layer), **sidecar)
    path.with_suffix(".json").write_text(json.dumps(data))


def blender_passes(
    height: int = 4, width: int = 5, names: dict[str, str] | None = None, value: float = 0.5
) -> dict[str, dict[str, np.ndarray]]:
    """Blender-style passes filled with constants; ``names`` renames passes."""

    def rgb(v: float) -> dict[str, np.ndarray]:
        return {c: np.full((height, width), v, np.float32) for c in "RGB"}

    passes = {
        "Combined": {**rgb(value), "A": np.ones((height, width), np.float32)},
        "Depth": {"Z": np.full((height, width), 2.0, np.float32)},
        "Material Index": {"X": np.ones((height, width), np.float32)},
        "Diffuse Direct": rgb(value),
        "Diffuse Indirect": rgb(0.25),
        "Diffuse Color": rgb(0.8),
    }
    names = names or {}
    return {names.get(p, p): comps for p, comps in passes.items()}


def temp_leftovers(directory: Path) -> list[str]:
    return sorted(p.name for p in directory.iterdir() if ".tmp" in p.name)


def make_result(height: int = 5, width: int = 4, seed: int = 1) -> FrameResult:
    rng = np.random.default_rng(seed)
    return FrameResult(
        number=12,
        method="adaptive_cv",
        sss=rng.uniform(0, 2, (height, width, 3)).astype(np.float32),
        composite=rng.uniform(0, 2, (height, width, 3)).astype(np.float32),
        counts=rng.integers(0, 64, (height, width)).astype(np.int32),
        alpha=rng.uniform(0, 1, (height, width)).astype(np.float32),
        gamma=rng.uniform(0, 1, (height, width, 3)).astype(np.float32),
        variance=rng.uniform(0, 0.1, (height, width)).astype(np.float32),
        valid_history=rng.uniform(size=(height, width)) < 0.5,
        mask=rng.uniform(size=(height, width)) < 0.7,
        spp=np.float64(3.25),
        samples=1234,
        sampling_ms=1.5,
        update_ms=0.25,
        total_ms=2.0,
        distant_share=0.5,
        fallback_share=0.0,
    )


# -- motion ---------------------------------------------------------------------------------
def test_motion_from_vector_convention_and_inverse():
    vector = np.zeros((2, 3, 4), np.float32)
    vector[..., 0], vector[..., 1], vector[..., 2] = 3.0, -2.0, 9.0
    motion = motion_from_vector(vector)
    assert motion.shape == (2, 3, 2) and motion.dtype == np.float32
    # Blender 5.0: X, Y = previous minus current position, y up; a Frame's
    # motion points to the previous position with y down (EXR rows).
    np.testing.assert_array_equal(motion[..., 0], 3.0)
    np.testing.assert_array_equal(motion[..., 1], 2.0)
    rng = np.random.default_rng(3)
    m = rng.normal(size=(4, 5, 2)).astype(np.float32)
    np.testing.assert_array_equal(motion_from_vector(vector_from_motion(m)), m)


@pytest.mark.parametrize("shape", [(4, 5), (4, 5, 2), (4, 5, 3)])
def test_motion_from_vector_rejects_bad_shape(shape):
    with pytest.raises(ValueError, match=r"\(H, W, 4\)"):
        motion_from_vector(np.zeros(shape))


# -- pass files: round trip -------------------------------------------------------------------
@pytest.mark.parametrize("motion", [True, False])
def test_write_read_round_trip(tmp_path, motion):
    frame = make_frame(motion=motion)
    path = tmp_path / "0007.exr"
    write_passes(path, frame)
    assert path.is_file() and path.with_suffix(".json").is_file()
    back = read_frame(path)
    assert back.number == 7
    assert back.source == str(path)
    assert back.lighting_passes == ("Diffuse Direct", "Diffuse Indirect")
    for name in ("lighting", "albedo", "combined"):
        got = getattr(back, name)
        assert got.dtype == np.float32 and got.shape == (6, 8, 3)
        np.testing.assert_array_equal(got, getattr(frame, name))
    np.testing.assert_array_equal(back.depth, frame.depth)
    assert np.isinf(back.depth[0, :3]).all() and np.isfinite(back.depth[1:]).all()
    np.testing.assert_array_equal(back.material, frame.material)
    assert back.material.dtype == np.int32
    if motion:
        np.testing.assert_array_equal(back.motion, frame.motion)
    else:
        assert back.motion is None
    assert back.camera == frame.camera
    assert back.materials == frame.materials
    assert back.materials[2].options == {"preset": "x"}


def test_written_file_looks_like_blender_5(tmp_path):
    path = tmp_path / "0001.exr"
    write_passes(path, make_frame(number=1))
    f = OpenEXR.File(str(path), separate_channels=True)
    names = {p.name(): sorted(p.channels) for p in f.parts}
    assert names["ViewLayer.Combined"] == [f"ViewLayer.Combined.{c}" for c in "ABGR"]
    assert names["ViewLayer.Depth"] == ["ViewLayer.Depth.Z"]
    assert names["ViewLayer.Material Index"] == ["ViewLayer.Material Index.X"]
    assert names["ViewLayer.Vector"] == [f"ViewLayer.Vector.{c}" for c in "WXYZ"]
    for p in ("Diffuse Direct", "Diffuse Indirect", "Diffuse Color"):
        assert names[f"ViewLayer.{p}"] == [f"ViewLayer.{p}.{c}" for c in "BGR"]
    depth = f.parts[[p.name() for p in f.parts].index("ViewLayer.Depth")].channels
    assert depth["ViewLayer.Depth.Z"].pixels[0, 0] == pytest.approx(1e10)
    sidecar = json.loads(path.with_suffix(".json").read_text())
    assert sidecar["format"] == "cvsss-passes/1" and sidecar["frame"] == 1
    assert sidecar["view_layer"] == "ViewLayer"
    assert Camera.from_dict(sidecar["camera"]) == Camera(
        width=8, height=6, lens=35.0, sensor_fit="HORIZONTAL"
    )


def test_float16_input(tmp_path):
    frame = make_frame()
    path = tmp_path / "0007.exr"
    write_passes(path, frame, half=True)
    f = OpenEXR.File(str(path), separate_channels=True)
    assert all(c.pixels.dtype == np.float16 for p in f.parts for c in p.channels.values())
    back = read_frame(path)
    for name in ("lighting", "albedo", "combined"):
        got = getattr(back, name)
        assert got.dtype == np.float32
        np.testing.assert_allclose(got, getattr(frame, name), rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(back.depth, frame.depth, rtol=1e-3)
    assert np.isinf(back.depth[0, :3]).all()
    np.testing.assert_array_equal(back.material, frame.material)
    np.testing.assert_allclose(back.motion, frame.motion, atol=2e-3)


def test_frame_number_precedence(tmp_path):
    write_passes(tmp_path / "0003.exr", make_frame(number=12))
    assert read_frame(tmp_path / "0003.exr").number == 12
    assert read_frame(tmp_path / "0003.exr", number=40).number == 40
    sidecar = tmp_path / "0003.json"
    data = json.loads(sidecar.read_text())
    del data["frame"]
    sidecar.write_text(json.dumps(data))
    assert read_frame(tmp_path / "0003.exr").number == 3
    os.replace(tmp_path / "0003.exr", tmp_path / "shot.exr")
    os.replace(sidecar, tmp_path / "shot.json")
    with pytest.raises(PassError, match=r"shot\.exr: no frame number"):
        read_frame(tmp_path / "shot.exr")
    assert read_frame(tmp_path / "shot.exr", number=5).number == 5


# -- pass discovery ---------------------------------------------------------------------------
def test_diffuse_indirect_is_optional(tmp_path):
    passes = blender_passes()
    del passes["Diffuse Indirect"]
    write_raw(tmp_path / "0001.exr", passes)
    frame = read_frame(tmp_path / "0001.exr")
    assert frame.lighting_passes == ("Diffuse Direct",)
    np.testing.assert_array_equal(frame.lighting, 0.5)
    assert frame.indirect is None


def test_indirect_round_trip_and_the_direct_part(tmp_path):
    """write_passes splits lighting by the frame's indirect pass; read_frame joins it
    again; the Geometry's direct part is lighting − indirect (0 where it would be < 0)."""
    from cvsss.core.geometry import geometry_of
    from cvsss.core.params import SSSParams
    from cvsss.core.profiles.factory import frame_profile
    from cvsss.core.synthetic import flat_plane

    frame = flat_plane(16, 12, d=(0.02, 0.01, 0.005))
    indirect = np.full_like(frame.lighting, 0.2)
    indirect[0, 0] = 5.0  # more than the lighting: clipped in the file, 0 direct
    frame = dataclasses.replace(frame, indirect=indirect)
    write_passes(tmp_path / "0001.exr", frame)
    back = read_frame(tmp_path / "0001.exr")
    np.testing.assert_allclose(back.lighting, frame.lighting, rtol=1e-6)
    np.testing.assert_allclose(back.indirect, np.minimum(indirect, frame.lighting), rtol=1e-6)
    geom = geometry_of(back, frame_profile(back, SSSParams()))
    expected = (back.lighting - back.indirect).reshape(-1, 3)[geom.index]
    np.testing.assert_allclose(geom.direct, np.maximum(expected, 0.0), atol=1e-7)


def test_object_index_is_optional_and_round_trips(tmp_path):
    """The Object Index pass (Blender 5 name or the old IndexOB) becomes frame.objects;
    without it frame.objects is None; write_passes writes it back; NaN reads as 0."""
    write_raw(tmp_path / "0001.exr", blender_passes())
    assert read_frame(tmp_path / "0001.exr").objects is None
    passes = blender_passes()
    ids = np.array([[1, 1, 2, 2, 0]] * 3 + [[3, 3, 3, np.nan, 0]], np.float32)
    passes["Object Index"] = {"X": ids}
    write_raw(tmp_path / "0002.exr", passes)
    frame = read_frame(tmp_path / "0002.exr")
    np.testing.assert_array_equal(frame.objects, np.nan_to_num(ids).astype(np.int32))
    assert frame.objects.dtype == np.int32 and frame.repaired == 1
    write_passes(tmp_path / "out" / "0002.exr", frame)
    np.testing.assert_array_equal(read_frame(tmp_path / "out" / "0002.exr").objects, frame.objects)
    old = blender_passes(names={"Material Index": "IndexMA"})
    old["IndexOB"] = {"X": ids}
    write_raw(tmp_path / "0003.exr", old, layer="RenderLayer", multipart=False)
    np.testing.assert_array_equal(read_frame(tmp_path / "0003.exr").objects, frame.objects)


def test_pixels_mostly_of_thin_points_take_no_part(tmp_path):
    """Where the pass render's thin-point AOV (cvsss_thin: the share of a pixel's samples
    whose subsurface Cycles rendered) is at least nine tenths, the Material Index reads
    as 0, so the post leaves the pixel as rendered; elsewhere (a half, the rule before)
    it reads as written."""
    passes = blender_passes()
    thin = np.array([[0.0, 0.5, 0.89, 0.9, 1.0]] * 4, np.float32)
    passes["cvsss_thin"] = {"X": thin}
    write_raw(tmp_path / "0001.exr", passes)
    expected = np.array([[1, 1, 1, 0, 0]] * 4)
    np.testing.assert_array_equal(read_frame(tmp_path / "0001.exr").material, expected)
    del passes["cvsss_thin"]
    write_raw(tmp_path / "0002.exr", passes)
    np.testing.assert_array_equal(read_frame(tmp_path / "0002.exr").material, 1)


def test_material_numbers_past_the_sidecars_slots_take_no_part(tmp_path):
    """The pass render numbers thin objects' material copies past the sidecar's table
    (one slot here, 1) so that the user's Material Index can be found again: such a
    number reads as 0, as a material that takes no part does."""
    passes = blender_passes()
    passes["Material Index"]["X"] = np.array([[0, 1, 2, 3, 7]] * 4, np.float32)
    write_raw(tmp_path / "0001.exr", passes)
    expected = np.array([[0, 1, 0, 0, 0]] * 4)
    np.testing.assert_array_equal(read_frame(tmp_path / "0001.exr").material, expected)


def test_lighting_sums_direct_and_indirect(tmp_path):
    write_raw(tmp_path / "0001.exr", blender_passes())
    frame = read_frame(tmp_path / "0001.exr")
    np.testing.assert_allclose(frame.lighting, 0.75)
    # The indirect part travels with the frame (the hidden-light fill scales the rest).
    np.testing.assert_allclose(frame.indirect, 0.25)
    np.testing.assert_allclose(frame.albedo, 0.8)
    np.testing.assert_array_equal(frame.material, 1)
    assert frame.motion is None


def test_old_blender_short_names_single_part(tmp_path):
    old = {
        "Diffuse Direct": "DiffDir",
        "Diffuse Indirect": "DiffInd",
        "Diffuse Color": "DiffCol",
        "Material Index": "IndexMA",
    }
    write_raw(
        tmp_path / "0002.exr", blender_passes(names=old), layer="RenderLayer", multipart=False
    )
    frame = read_frame(tmp_path / "0002.exr")
    np.testing.assert_allclose(frame.lighting, 0.75)
    np.testing.assert_array_equal(frame.material, 1)
    assert frame.lighting_passes == ("Diffuse Direct", "Diffuse Indirect")


@pytest.mark.parametrize("layer", ["View Layer.001", "Render Layer", ""])
def test_view_layer_prefix_is_detected(tmp_path, layer):
    write_raw(tmp_path / "0001.exr", blender_passes(), layer=layer)
    np.testing.assert_allclose(read_frame(tmp_path / "0001.exr").combined, 0.5)


def test_view_layer_named_by_sidecar(tmp_path):
    first = {
        f"A.{p}.{c}": a for p, comps in blender_passes(value=0.1).items() for c, a in comps.items()
    }
    second = {
        f"B.{p}.{c}": a for p, comps in blender_passes(value=0.9).items() for c, a in comps.items()
    }
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    path = tmp_path / "0001.exr"
    OpenEXR.File(header, {**first, **second}).write(str(path))
    sidecar = make_sidecar(Camera(width=5, height=4), view_layer="B")
    path.with_suffix(".json").write_text(json.dumps(sidecar))
    np.testing.assert_allclose(read_frame(path).combined, 0.9)
    sidecar["view_layer"] = "C"
    path.with_suffix(".json").write_text(json.dumps(sidecar))
    with pytest.raises(PassError, match=r"0001\.exr: several view layers \('A', 'B'\)"):
        read_frame(path)


def test_missing_pass_names_pass_file_and_found_passes(tmp_path):
    passes = blender_passes()
    del passes["Depth"]
    passes["Noisy Image"] = {"R": passes["Combined"]["R"]}
    write_raw(tmp_path / "0003.exr", passes)
    with pytest.raises(PassError) as info:
        read_frame(tmp_path / "0003.exr")
    message = str(info.value)
    assert "0003.exr: missing pass 'Depth'" in message
    assert (
        "(found: Combined, Diffuse Color, Diffuse Direct, Diffuse Indirect, "
        "Material Index, Noisy Image)"
    ) in message


def test_several_missing_passes_are_all_listed(tmp_path):
    passes = blender_passes()
    del passes["Material Index"], passes["Diffuse Color"]
    write_raw(tmp_path / "0003.exr", passes)
    with pytest.raises(PassError, match="missing passes 'Diffuse Color', 'Material Index'"):
        read_frame(tmp_path / "0003.exr")


def test_file_without_blender_passes(tmp_path):
    path = tmp_path / "0001.exr"
    rgb = {c: np.zeros((4, 5), np.float32) for c in "RGB"}
    OpenEXR.File({"type": OpenEXR.scanlineimage}, rgb).write(str(path))
    path.with_suffix(".json").write_text(json.dumps(make_sidecar(Camera(width=5, height=4))))
    with pytest.raises(PassError, match=r"0001\.exr: missing passes .*'Depth'.*\(found: B, G, R\)"):
        read_frame(path)


def test_pass_lacking_a_channel(tmp_path):
    passes = blender_passes()
    del passes["Diffuse Color"]["G"]
    write_raw(tmp_path / "0001.exr", passes)
    with pytest.raises(PassError, match=r"pass 'Diffuse Color' lacks channel\(s\) G"):
        read_frame(tmp_path / "0001.exr")


def test_passes_of_different_sizes(tmp_path):
    passes = blender_passes()
    passes["Depth"] = {"Z": np.full((2, 3), 2.0, np.float32)}
    write_raw(tmp_path / "0001.exr", passes)
    with pytest.raises(PassError, match=r"0001\.exr: passes differ in size .*Depth 3x2"):
        read_frame(tmp_path / "0001.exr")


def test_camera_resolution_must_match(tmp_path):
    write_raw(tmp_path / "0004.exr", blender_passes(), camera=Camera(width=16, height=12))
    with pytest.raises(PassError) as info:
        read_frame(tmp_path / "0004.exr")
    assert "0004.json: camera resolution 16x12 does not match" in str(info.value)
    assert "0004.exr (5x4)" in str(info.value)


# -- broken inputs ------------------------------------------------------------------------------
def test_truncated_file(tmp_path, capsys):
    path = tmp_path / "0003.exr"
    write_passes(path, make_frame(24, 32))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(PassError, match=r"0003\.exr: not a readable OpenEXR file \(truncated"):
        read_frame(path)
    assert capsys.readouterr().out == ""


def test_truncated_single_part_file(tmp_path, capsys):
    path = tmp_path / "r.exr"
    write_result(path, make_result(64, 48))
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 9 // 10])
    with pytest.raises(PassError, match=r"r\.exr: not a readable OpenEXR file"):
        read_result(path)
    assert capsys.readouterr().out == ""


@pytest.mark.parametrize("offset", [40, 60, 130])
def test_corrupt_pixel_data(tmp_path, capsys, offset):
    # Constant passes compress, so damaged bytes land in a zlib stream or a
    # chunk header (raw float noise is stored uncompressed and has no checksum).
    path = tmp_path / "0003.exr"
    write_raw(path, blender_passes(24, 32))
    data = bytearray(path.read_bytes())
    data[-offset : -offset + 8] = b"\xff" * 8
    path.write_bytes(bytes(data))
    with pytest.raises(PassError, match=r"0003\.exr: not a readable OpenEXR file \(.*part \d"):
        read_frame(path)
    assert capsys.readouterr().out == ""


def test_text_file_is_not_exr(tmp_path):
    path = tmp_path / "0003.exr"
    path.write_text("this is not an image\n")
    with pytest.raises(PassError, match=r"0003\.exr: not a readable OpenEXR file"):
        read_frame(path)


@pytest.mark.parametrize("content", [b"", b"v/1\x01"])
def test_empty_or_header_only_files(tmp_path, content):
    path = tmp_path / "0003.exr"
    path.write_bytes(content)
    with pytest.raises(PassError, match=r"0003\.exr: not a readable OpenEXR file"):
        read_frame(path)


def test_missing_file(tmp_path):
    with pytest.raises(PassError, match=r"0009\.exr: no such file"):
        read_frame(tmp_path / "0009.exr")


def test_missing_sidecar(tmp_path):
    path = tmp_path / "0003.exr"
    write_passes(path, make_frame())
    path.with_suffix(".json").unlink()
    with pytest.raises(PassError, match=r"0003\.json: missing camera sidecar next to .*0003\.exr"):
        read_frame(path)


@pytest.mark.parametrize(
    ("edit", "expected"),
    [
        (lambda d: "{not json", r"not valid JSON"),
        (lambda d: [1, 2], r"expected a JSON object"),
        (lambda d: {**d, "format": "other/2"}, r"unsupported format 'other/2'"),
        (lambda d: {k: v for k, v in d.items() if k != "camera"}, r"missing or invalid 'camera'"),
        (lambda d: {**d, "camera": {**d["camera"], "lens": -1}}, r"invalid camera \(.*lens"),
        (lambda d: {**d, "camera": {**d["camera"], "fov": 1}}, r"invalid camera \(.*fov"),
        (lambda d: {**d, "materials": [{"name": "x"}]}, r"invalid material #0 \(missing 'slot'\)"),
        (lambda d: {**d, "materials": [{"slot": 1, "d": [1, 2]}]}, r"invalid material #0"),
        (lambda d: {**d, "materials": d["materials"][:1] * 2}, r"material slot 1 is listed twice"),
        (lambda d: {**d, "frame": "12"}, r"'frame' must be an integer"),
        (lambda d: {**d, "scene_unit_scale": 0}, r"'scene_unit_scale' must be a positive"),
    ],
)
def test_invalid_sidecar(tmp_path, edit, expected):
    path = tmp_path / "0003.exr"
    write_passes(path, make_frame())
    sidecar = path.with_suffix(".json")
    edited = edit(json.loads(sidecar.read_text()))
    sidecar.write_text(edited if isinstance(edited, str) else json.dumps(edited))
    with pytest.raises(PassError, match=r"0003\.json: " + expected):
        read_frame(path)


# -- atomic writes --------------------------------------------------------------------------------
def test_existing_output_is_not_overwritten(tmp_path):
    path = tmp_path / "0001.exr"
    write_passes(path, make_frame(seed=1))
    before = path.read_bytes(), path.with_suffix(".json").read_bytes()
    with pytest.raises(FileExistsError, match=r"0001\.exr already exists.*--overwrite"):
        write_passes(path, make_frame(seed=2))
    assert (path.read_bytes(), path.with_suffix(".json").read_bytes()) == before
    write_passes(path, make_frame(seed=2, number=9), overwrite=True)
    back = read_frame(path)
    np.testing.assert_array_equal(back.lighting, make_frame(seed=2).lighting)
    assert back.number == 9
    assert temp_leftovers(tmp_path) == []


def test_existing_sidecar_blocks_write(tmp_path):
    path = tmp_path / "0001.exr"
    path.with_suffix(".json").write_text("{}")
    with pytest.raises(FileExistsError, match=r"0001\.json already exists"):
        write_passes(path, make_frame())
    assert not path.exists()
    assert path.with_suffix(".json").read_text() == "{}"


def test_no_temp_files_after_success(tmp_path):
    write_passes(tmp_path / "0001.exr", make_frame())
    write_result(tmp_path / "r.exr", make_result())
    write_sidecar(tmp_path / "x.json", make_sidecar(Camera(width=2, height=2)))
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "0001.exr",
        "0001.json",
        "r.exr",
        "x.json",
    ]


def _failing_write(self, target):
    target.write(b"v/1\x01 partial")
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_failed_write_leaves_nothing(tmp_path, monkeypatch):
    monkeypatch.setattr(OpenEXR.File, "write", _failing_write)
    path = tmp_path / "out" / "0001.exr"
    with pytest.raises(OutputError, match=r"cannot write .*0001\.exr: No space left on device"):
        write_passes(path, make_frame())
    assert list(path.parent.iterdir()) == []
    with pytest.raises(OutputError) as info:
        write_result(tmp_path / "out" / "r.exr", make_result())
    assert info.value.errno == errno.ENOSPC
    assert isinstance(info.value, OSError)
    assert list(path.parent.iterdir()) == []


def test_failed_overwrite_keeps_old_file(tmp_path, monkeypatch):
    path = tmp_path / "0001.exr"
    write_passes(path, make_frame(seed=1))
    before = path.read_bytes()
    monkeypatch.setattr(OpenEXR.File, "write", _failing_write)
    with pytest.raises(OutputError):
        write_passes(path, make_frame(seed=2), overwrite=True)
    assert path.read_bytes() == before
    assert temp_leftovers(tmp_path) == []


def test_failure_after_sync_leaves_nothing(tmp_path, monkeypatch):
    def no_space(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fsync", no_space)
    with pytest.raises(OutputError, match="No space left on device"):
        write_passes(tmp_path / "0001.exr", make_frame())
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_unwritable_folder(tmp_path):
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    with pytest.raises(OutputError, match=r"cannot write .*file\.txt: not a folder"):
        write_passes(blocker / "0001.exr", make_frame())


def test_permission_denied_names_file_and_cause(tmp_path, monkeypatch):
    real_open = os.open

    def deny(path, flags, *args):
        if flags & os.O_CREAT:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), str(path))
        return real_open(path, flags, *args)

    monkeypatch.setattr(atomic.os, "open", deny)
    with pytest.raises(OutputError, match=r"cannot write .*0001\.json: Permission denied"):
        write_passes(tmp_path / "0001.exr", make_frame())
    monkeypatch.undo()
    assert list(tmp_path.iterdir()) == []


def test_output_must_be_exr(tmp_path):
    with pytest.raises(ValueError, match=r"must end in \.exr"):
        write_passes(tmp_path / "0001.json", make_frame())


# -- results ------------------------------------------------------------------------------------
def test_write_read_result_round_trip(tmp_path):
    result = make_result()
    path = tmp_path / "result" / "0012.exr"
    write_result(path, result, metadata={"eta": 0.1, "cv_mode": "emcm"})
    back = read_result(path)
    for layer, field in [("Composite", "composite"), ("SSS", "sss"), ("Gamma", "gamma")]:
        assert back[layer].shape == (5, 4, 3) and back[layer].dtype == np.float32
        np.testing.assert_array_equal(back[layer], getattr(result, field))
    for layer, field in [
        ("SampleCount", "counts"),
        ("Alpha", "alpha"),
        ("Variance", "variance"),
        ("ValidHistory", "valid_history"),
        ("Mask", "mask"),
    ]:
        assert back[layer].shape == (5, 4) and back[layer].dtype == np.float32
        np.testing.assert_array_equal(back[layer], getattr(result, field).astype(np.float32))
    header = back["header"]
    assert header["cvsss.method"] == "adaptive_cv"
    assert header["cvsss.frame"] == "12"
    assert header["cvsss.eta"] == "0.1" and header["cvsss.cv_mode"] == "emcm"
    assert float(header["cvsss.spp"]) == 3.25 and header["cvsss.samples"] == "1234"
    channels = OpenEXR.File(str(path), separate_channels=True).parts[0].channels
    assert sorted(channels) == sorted(
        [f"{layer}.{c}" for layer in ("Composite", "SSS", "Gamma") for c in "RGB"]
        + [f"{layer}.V" for layer in ("SampleCount", "Alpha", "Variance", "ValidHistory", "Mask")]
    )


def test_write_result_refuses_existing_and_bad_metadata(tmp_path):
    path = tmp_path / "0012.exr"
    write_result(path, make_result())
    with pytest.raises(FileExistsError, match="--overwrite"):
        write_result(path, make_result())
    write_result(path, make_result(seed=5), overwrite=True)
    np.testing.assert_array_equal(read_result(path)["SSS"], make_result(seed=5).sss)
    with pytest.raises(ValueError, match="reserved"):
        write_result(tmp_path / "x.exr", make_result(), metadata={"method": "x"})
    with pytest.raises(ValueError, match="without spaces"):
        write_result(tmp_path / "x.exr", make_result(), metadata={"a b": 1})
    assert not (tmp_path / "x.exr").exists()


def test_write_result_checks_shapes(tmp_path):
    result = make_result()
    result.alpha = np.zeros((2, 2), np.float32)
    with pytest.raises(ValueError, match=r"result alpha has shape \(2, 2\), expected \(5, 4\)"):
        write_result(tmp_path / "x.exr", result)
    assert list(tmp_path.iterdir()) == []


# -- listing ----------------------------------------------------------------------------------------
def test_list_frames_orders_by_number(tmp_path):
    for name in (
        "0010.exr",
        "2.exr",
        "0001.exr",
        "notes.exr",
        "0003.json",
        "0004.EXR",
        ".0005.exr.tmp-1-ab",
    ):
        (tmp_path / name).write_bytes(b"")
    (tmp_path / "0006.exr").mkdir()
    assert list_frames(tmp_path) == [
        (1, tmp_path / "0001.exr"),
        (2, tmp_path / "2.exr"),
        (4, tmp_path / "0004.EXR"),
        (10, tmp_path / "0010.exr"),
    ]


def test_list_frames_errors(tmp_path):
    with pytest.raises(PassError, match=r"missing: no such folder"):
        list_frames(tmp_path / "missing")
    with pytest.raises(PassError, match=r"no frame files named <digits>\.exr"):
        list_frames(tmp_path)
    (tmp_path / "a.txt").write_text("")
    with pytest.raises(PassError, match="not a folder"):
        list_frames(tmp_path / "a.txt")
    (tmp_path / "1.exr").write_bytes(b"")
    (tmp_path / "0001.exr").write_bytes(b"")
    with pytest.raises(PassError, match=r"frame 1 appears twice \(0001\.exr, 1\.exr\)"):
        list_frames(tmp_path)


# -- a real Blender render ---------------------------------------------------------------------------
RENDER_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import bpy

    out = sys.argv[1]
    bpy.ops.wm.read_factory_settings(use_empty=False)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 1
    scene.render.resolution_x, scene.render.resolution_y = 16, 12
    scene.render.resolution_percentage = 100
    scene.render.use_motion_blur = False
    layer = scene.view_layers[0]
    layer.use_pass_diffuse_direct = True
    layer.use_pass_diffuse_indirect = True
    layer.use_pass_diffuse_color = True
    layer.use_pass_z = True
    layer.use_pass_material_index = True
    layer.use_pass_vector = True
    bpy.data.materials["Material"].pass_index = 1
    cam = scene.camera.data
    # Shift the view so the cube sits in the top-left: checks the row/column order.
    cam.shift_x, cam.shift_y = 0.2, -0.2
    settings = scene.render.image_settings
    settings.media_type = "MULTI_LAYER_IMAGE"
    settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True)
    r = scene.render
    camera = {
        "width": r.resolution_x * r.resolution_percentage // 100,
        "height": r.resolution_y * r.resolution_percentage // 100,
        "type": cam.type, "lens": cam.lens, "sensor_width": cam.sensor_width,
        "sensor_height": cam.sensor_height, "sensor_fit": cam.sensor_fit,
        "ortho_scale": cam.ortho_scale, "pixel_aspect_x": r.pixel_aspect_x,
        "pixel_aspect_y": r.pixel_aspect_y, "clip_start": cam.clip_start,
        "clip_end": cam.clip_end,
    }
    sidecar = {
        "format": "cvsss-passes/1", "frame": scene.frame_current, "camera": camera,
        "materials": [{"slot": 1, "name": "Material", "d": [0.1, 0.05, 0.02]}],
        "scene_unit_scale": scene.unit_settings.scale_length,
        "view_layer": layer.name, "engine": scene.render.engine,
    }
    with open(out[:-4] + ".json", "w") as f:
        json.dump(sidecar, f)
    """
)


@pytest.mark.bpy
@pytest.mark.skipif(importlib.util.find_spec("bpy") is None, reason="bpy is not installed")
def test_read_real_blender_render(tmp_path):
    script = tmp_path / "render.py"
    script.write_text(RENDER_SCRIPT)
    out = tmp_path / "0001.exr"
    run = subprocess.run(
        [sys.executable, str(script), str(out)],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-2000:]
    parts = [p.name() for p in OpenEXR.File(str(out), header_only=True).parts]
    assert "ViewLayer.Diffuse Direct" in parts  # Blender 5 writes one part per pass

    frame = read_frame(out)
    assert frame.number == 1
    assert frame.shape == (12, 16)
    assert frame.lighting.shape == frame.albedo.shape == frame.combined.shape == (12, 16, 3)
    assert frame.motion is not None and frame.motion.shape == (12, 16, 2)
    assert frame.lighting_passes == ("Diffuse Direct", "Diffuse Indirect")
    assert frame.camera.width == 16 and frame.camera.sensor_fit == "AUTO"
    assert frame.materials[1].name == "Material"
    cube = frame.material == 1
    assert 0 < cube.sum() < cube.size
    assert np.isfinite(frame.depth[cube]).all() and (frame.depth[cube] > 1).all()
    assert np.isinf(frame.depth[~cube]).all()
    assert (frame.albedo[cube] > 0).all()
    # The cube was shifted into the top-left quadrant (EXR row 0 is the top).
    rows, cols = np.nonzero(cube)
    assert rows.mean() < 12 / 2 and cols.mean() < 16 / 2
    assert not cube[-1].any() and not cube[:, -1].any()


# -- threads ----------------------------------------------------------------------------------
@pytest.fixture
def exr_threads():
    """Restore OpenEXR's global thread count after the test (it is process-wide)."""
    before = OpenEXR.global_thread_count()
    yield
    OpenEXR.set_global_thread_count(before)


def test_threads_do_not_change_the_bytes(tmp_path, exr_threads):
    # A result large enough for many 16-line ZIP blocks, written and read on one
    # thread (a count already set is kept) and then on every core.
    result = make_result(240, 320, seed=3)
    frame = make_frame(240, 320, seed=3)
    OpenEXR.set_global_thread_count(1)
    write_result(tmp_path / "one" / "r.exr", result)
    write_passes(tmp_path / "one" / "0001.exr", frame)
    one = read_frame(tmp_path / "one" / "0001.exr")
    assert OpenEXR.global_thread_count() == 1
    OpenEXR.set_global_thread_count(0)
    cores = len(os.sched_getaffinity(0))
    assert use_threads() == (cores if cores > 1 else 0)
    write_result(tmp_path / "all" / "r.exr", result)
    write_passes(tmp_path / "all" / "0001.exr", frame)
    for name in ("r.exr", "0001.exr"):
        assert (tmp_path / "all" / name).read_bytes() == (tmp_path / "one" / name).read_bytes()
    np.testing.assert_array_equal(
        read_result(tmp_path / "all" / "r.exr")["Composite"], result.composite
    )
    np.testing.assert_array_equal(read_frame(tmp_path / "all" / "0001.exr").lighting, one.lighting)


def test_a_thread_count_already_set_is_kept(exr_threads):
    OpenEXR.set_global_thread_count(3)
    assert use_threads() == 3
    assert OpenEXR.global_thread_count() == 3


def test_read_rgb_of_a_single_layer_and_a_multilayer_render(tmp_path):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    rgb = np.arange(4 * 5 * 3, dtype=np.float32).reshape(4, 5, 3) / 7.0
    single = {c: np.ascontiguousarray(rgb[..., i]) for i, c in enumerate("RGB")}
    single["A"] = np.ones((4, 5), np.float32)
    OpenEXR.File(header, single).write(str(tmp_path / "single.exr"))
    np.testing.assert_array_equal(read_rgb(tmp_path / "single.exr"), rgb)
    layered = {f"View Layer.Combined.{c}": a for c, a in single.items()}
    OpenEXR.File(header, layered).write(str(tmp_path / "layered.exr"))
    np.testing.assert_array_equal(read_rgb(tmp_path / "layered.exr"), rgb)
    OpenEXR.File(header, {"Y": single["R"]}).write(str(tmp_path / "grey.exr"))
    with pytest.raises(PassError, match="no Combined pass"):
        read_rgb(tmp_path / "grey.exr")


def test_read_pass_by_either_name_and_its_errors(tmp_path):
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    index = np.array([[0, 1, 2], [3, 0, 7]], np.float32)
    depth = np.full((2, 3), 4.5, np.float32)
    channels = {"ViewLayer.IndexOB.X": index, "ViewLayer.Depth.Z": depth}
    OpenEXR.File(header, channels).write(str(tmp_path / "old.exr"))
    for name in ("Object Index", "IndexOB"):
        np.testing.assert_array_equal(read_pass(tmp_path / "old.exr", name), index)
    np.testing.assert_array_equal(read_pass(tmp_path / "old.exr", "Depth"), depth)
    with pytest.raises(PassError, match="no Material Index pass"):
        read_pass(tmp_path / "old.exr", "Material Index")
    two = {"A.Object Index.X": index, "B.Object Index.X": index}
    OpenEXR.File(header, two).write(str(tmp_path / "two.exr"))
    with pytest.raises(PassError, match="Object Index pass in several view layers"):
        read_pass(tmp_path / "two.exr", "Object Index")
    with pytest.raises(KeyError):
        read_pass(tmp_path / "old.exr", "Cryptomatte")

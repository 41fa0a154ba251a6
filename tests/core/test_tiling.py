"""Tiles with a halo reproduce the whole-image post bit for bit (core.tiling; docs/explanation/design.md §12).

Every method runs over a short sequence whose content moves across tile
borders (motion vectors of a few pixels, sub-pixel jitter), once on the whole
image and once as tiles (run inline), and every image of every result, every
frame-level figure but the timings, and the carried state must be equal.
A halo without its radius or its motion term must break that equality.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from tiling_helpers import (
    FAST,
    FRAMES,
    H,
    W,
    differences,
    moving_frame,
    run_tiled,
    run_whole,
    same_state,
)

from cvsss.core import synthetic
from cvsss.core.frame import Crop
from cvsss.core.method import MethodOptions
from cvsss.core.methods import METHODS, make_processor
from cvsss.core.params import SeparableParams, SSSParams
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.synthetic import flat_plane
from cvsss.core.tiling import (
    InlineExecutor,
    StatePiece,
    TiledProcessor,
    TileSession,
    crop_frame,
    crop_piece,
    halo_px,
    join_pieces,
    motion_px,
    neighbours,
    scatter_radius_px,
    split_state,
    tile_cores,
    window,
)

CASES = [(name, FAST, MethodOptions()) for name in METHODS] + [
    ("as", dataclasses.replace(FAST, distance="planar"), MethodOptions()),
    ("as_ccv", dataclasses.replace(FAST, distance="cycles"), MethodOptions()),
    ("as_ocv", dataclasses.replace(FAST, history_precision="float16"), MethodOptions()),
    (
        "separable",
        FAST,
        MethodOptions(separable=SeparableParams(filter="linear", follow="exponential")),
    ),
]


@pytest.mark.parametrize(
    ("name", "params", "options"), CASES, ids=[f"{c[0]}-{i}" for i, c in enumerate(CASES)]
)
def test_tiles_equal_whole_image(name, params, options):
    whole, whole_state = run_whole(name, params, options, FRAMES)
    tiled, tiled_state, session = run_tiled(name, params, options, FRAMES)
    # The tiles are smaller than the image and the halo crosses several tile borders.
    assert len(session.cores) == 12
    assert all(h > 5 for h in session.halos.values())
    for a, b in zip(whole, tiled):
        assert differences(a, b) == []
    assert same_state(whole_state, tiled_state)


def test_tiles_equal_whole_image_with_touching_objects():
    """The Object Index pass is cropped with the other passes: the slab cut into two
    objects that touch (SSSParams.contact) gives the same bits tiled and whole."""

    def cut(frame):
        objects = frame.objects.copy()
        objects[(frame.material == 2) & (np.arange(W)[None, :] % 7 < 3)] = 9
        return dataclasses.replace(frame, objects=objects)

    frames = [cut(f) for f in FRAMES]
    whole, whole_state = run_whole("as_ccv", FAST, MethodOptions(), frames)
    tiled, tiled_state, _ = run_tiled("as_ccv", FAST, MethodOptions(), frames)
    for a, b in zip(whole, tiled):
        assert differences(a, b) == []
    assert same_state(whole_state, tiled_state)
    plain, _ = run_whole("as_ccv", FAST, MethodOptions(), FRAMES)
    assert not np.array_equal(plain[-1].composite, whole[-1].composite)


@pytest.mark.parametrize("name", ["as_ccv", "separable"])
def test_tiles_of_a_still_scene_reuse_their_geometry(name):
    """The pooled tile processors keep one Geometry per crop (core.geometry.GeometryCache):
    the tiles of a still scene's later frames reuse theirs, and the result is still the
    whole image's, bit for bit."""
    from cvsss.core import tiling

    frames = [synthetic.scene_frame("flash", n, W, H) for n in (1, 2, 3)]
    tiling._POOL.clear()
    whole, whole_state = run_whole(name, FAST, MethodOptions(), frames)
    tiled, tiled_state, session = run_tiled(name, FAST, MethodOptions(), frames)
    for a, b in zip(whole, tiled):
        assert differences(a, b) == []
    assert same_state(whole_state, tiled_state)
    hits = sum(p._geometry.hits for pool in tiling._POOL.values() for p in pool)
    assert hits == 2 * len(session.cores)  # every tile of frames 2 and 3


def test_odd_tile_sizes_and_a_tile_larger_than_the_image():
    whole, state = run_whole("as_ccv", FAST, MethodOptions(), FRAMES[:2])
    for tile in (7, 31, 200):
        tiled, tiled_state, _ = run_tiled("as_ccv", FAST, MethodOptions(), FRAMES[:2], tile=tile)
        assert all(differences(a, b) == [] for a, b in zip(whole, tiled))
        assert same_state(state, tiled_state)


@pytest.mark.parametrize("name", ["fixed", "separable"])
def test_halo_short_of_the_radius_breaks_identity(name):
    """Samples (taps) of core pixels land beyond a halo of half the scattering radius."""
    still = dataclasses.replace(FRAMES[0], motion=None)
    radius = scatter_radius_px(still, frame_profile(still, FAST))
    assert radius > 3
    assert halo_px(still, frame_profile(still, FAST)) == math.ceil(radius) + 1
    whole, _ = run_whole(name, FAST, MethodOptions(), [still])
    tiled, _, _ = run_tiled(name, FAST, MethodOptions(), [still], halo=math.ceil(radius) // 2)
    assert "composite" in differences(whole[0], tiled[0])


def test_halo_without_the_motion_breaks_identity():
    """The history a core pixel reprojects from lies beyond a halo without the motion term."""
    frames = [moving_frame(n, step=(11, -4)) for n in (1, 2, 3)]
    profile = frame_profile(frames[0], FAST)
    short = max(math.ceil(scatter_radius_px(f, profile)) for f in frames) + 1
    assert min(motion_px(f) for f in frames) > short + 2
    whole, state = run_whole("as", FAST, MethodOptions(), frames)
    full, full_state, _ = run_tiled("as", FAST, MethodOptions(), frames)
    assert all(differences(a, b) == [] for a, b in zip(whole, full))
    assert same_state(state, full_state)
    tiled, tiled_state, _ = run_tiled("as", FAST, MethodOptions(), frames, halo=short)
    assert differences(whole[0], tiled[0]) == []  # no history yet: the radius suffices
    assert "counts" in differences(whole[-1], tiled[-1])
    assert not same_state(state, tiled_state)


# -- the pieces ------------------------------------------------------------------------------
def test_tile_cores_partition_the_image():
    cores = tile_cores((50, 70), 16)
    cover = np.zeros((50, 70), int)
    for y0, y1, x0, x1 in cores:
        cover[y0:y1, x0:x1] += 1
    assert (cover == 1).all()
    assert window((16, 32, 0, 16), 5, (50, 70)) == (11, 37, 0, 21)
    assert neighbours(cores, window(cores[0], 3, (50, 70))) == [0, 1, 5, 6]
    with pytest.raises(ValueError, match="tile size"):
        tile_cores((4, 4), 0)


def test_halo_from_camera_materials_and_motion():
    # Flat plane at depth 2 (50 mm lens, 36 mm sensor, 64 px): footprint 2·0.72/64 = 0.0225;
    # d_max = 0.01, truncated at 16·d = 0.16 → 7.1 px.
    plane = flat_plane(64, 48, d=(0.01, 0.004, 0.002), depth=2.0)
    profile = frame_profile(plane, SSSParams())
    assert scatter_radius_px(plane, profile) == pytest.approx(0.16 / 0.0225)
    assert motion_px(plane) == 0.0
    assert halo_px(plane, profile) == 8 + 0 + 1
    moved = dataclasses.replace(plane, motion=np.full((48, 64, 2), 2.5, np.float32))
    assert motion_px(moved) == pytest.approx(math.hypot(2.5, 2.5))
    # Vectors that leave the image need no halo: their history is dropped anyway.
    away = np.full((48, 64, 2), 1e6, np.float32)
    assert motion_px(dataclasses.replace(plane, motion=away)) == 0.0
    # No subsurface pixel: no radius.
    none = dataclasses.replace(plane, material=np.zeros((48, 64), np.int32))
    assert scatter_radius_px(none, profile) == 0.0


def test_crop_keeps_camera_and_image_coordinates():
    frame = FRAMES[1]
    crop = crop_frame(frame, (10, 40, 20, 60), (15, 35, 25, 55))
    assert crop.shape == (30, 40) and crop.origin == (10, 20)
    assert crop.camera == frame.camera and crop.image_shape == frame.shape
    assert np.array_equal(crop.lighting, frame.lighting[10:40, 20:60])
    with pytest.raises(ValueError, match="does not fit"):
        dataclasses.replace(crop, crop=Crop((H, W), (40, 20), (40, 50, 20, 30)))
    with pytest.raises(ValueError, match="core"):
        dataclasses.replace(crop, crop=Crop((H, W), (10, 20), (0, 5, 20, 30)))
    with pytest.raises(ValueError, match="whole frame"):
        crop_frame(crop, (0, 4, 0, 4), (0, 4, 0, 4))


def test_state_pieces_tile_any_per_pixel_buffer():
    """A per-pixel array added to a state later (e.g. a new history buffer) needs no change."""
    rng = np.random.default_rng(0)
    state = {
        "h_buf_mu": rng.random((20, 30)).astype(np.float32),
        "h_buf_new_accum": rng.random((20, 30, 3)).astype(np.float16),
        "h_valid": rng.random((20, 30)) > 0.5,
        "h_meta": np.array([7]),
        "h_precision": np.array("float32"),
    }
    whole = split_state(state, (0, 20, 0, 30))
    assert sorted(whole.pixels) == ["h_buf_mu", "h_buf_new_accum", "h_valid"]
    cores = tile_cores((20, 30), 8)
    pieces = [crop_piece(whole, c) for c in cores]
    assert same_state(join_pieces(pieces, (0, 20, 0, 30)), state)
    box = (3, 17, 5, 22)
    part = join_pieces(pieces, box)
    assert np.array_equal(part["h_buf_new_accum"], state["h_buf_new_accum"][3:17, 5:22])
    odd = [*pieces[:-1], StatePiece(pieces[-1].box, pieces[-1].pixels, {"h_meta": np.array([8])})]
    with pytest.raises(ValueError, match="different arrays|neither per-pixel"):
        join_pieces(odd, (0, 20, 0, 30))
    with pytest.raises(ValueError, match="uncovered"):
        join_pieces(pieces[1:], (0, 20, 0, 30))


def test_resume_from_a_whole_state_continues_bit_for_bit():
    whole, state = run_whole("as_ocv", FAST, MethodOptions(), FRAMES)
    proc = make_processor("as_ocv", FAST, MethodOptions())
    proc.process(FRAMES[0])
    session = TileSession(InlineExecutor(), 20, FAST, MethodOptions())
    tiled = TiledProcessor("as_ocv", FAST, MethodOptions(), session)
    tiled.restore(proc.state())
    results = [tiled.process(f) for f in FRAMES[1:]]
    assert all(differences(a, b) == [] for a, b in zip(whole[1:], results))
    assert same_state(state, tiled.state())


class Flaky(InlineExecutor):
    """Loses the work of one gather, as a worker dying mid-frame would."""

    class Lost(Exception):
        pass

    lost = (Lost,)

    def __init__(self, fail_at: int):
        self.calls = 0
        self.fail_at = fail_at

    def gather(self, handles):
        self.calls += 1
        if self.calls == self.fail_at:
            raise self.Lost("worker died")
        return list(handles)


def test_lost_work_is_submitted_again_with_identical_output():
    whole, state = run_whole("as_ccv", FAST, MethodOptions(), FRAMES)
    session = TileSession(Flaky(fail_at=2), 24, FAST, MethodOptions())
    tiled = TiledProcessor("as_ccv", FAST, MethodOptions(), session)
    results = [tiled.process(f) for f in FRAMES]
    assert tiled.resubmitted == 1
    assert all(differences(a, b) == [] for a, b in zip(whole, results))
    assert same_state(state, tiled.state())


# -- a folder of passes, written and resumed -------------------------------------------------
def test_tiled_post_of_a_folder_writes_the_same_files(tmp_path):
    from cvsss.core.eval.compare import output_differences
    from cvsss.core.io.exr import write_passes
    from cvsss.core.run import RunSpec, run_folder

    passes = tmp_path / "passes"
    for f in FRAMES:
        write_passes(passes / f"{f.number:04d}.exr", f)
    spec = RunSpec(("as_ccv", "separable"), FAST, reference=True, reference_every=2)

    def tiled(name, params, options):
        return TiledProcessor(
            name, params, options, TileSession(InlineExecutor(), 32, params, options)
        )

    run_folder(passes, tmp_path / "whole", spec)
    rows = run_folder(passes, tmp_path / "tiles", spec, processors=tiled)
    assert len(rows) == 3 * 2 + 2
    assert output_differences(tmp_path / "whole", tmp_path / "tiles") == []
    other = dataclasses.replace(spec, params=dataclasses.replace(FAST, seed=1))
    run_folder(passes, tmp_path / "seed1", other)
    found = output_differences(tmp_path / "whole", tmp_path / "seed1")
    assert any("psnr_db" in d for d in found) and any("Composite" in d for d in found)
    # A tiled run resumes a checkpoint of the run without tiles (and the converse).
    (passes / "0003.exr").unlink()
    (passes / "0003.json").unlink()
    run_folder(passes, tmp_path / "mixed", spec)
    for f in FRAMES[2:]:
        write_passes(passes / f"{f.number:04d}.exr", f)
    run_folder(
        passes, tmp_path / "mixed", spec, existing="resume", processors=tiled, lookahead=True
    )
    assert output_differences(tmp_path / "whole", tmp_path / "mixed") == []

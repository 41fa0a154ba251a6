"""The compiled sampling step's own rules (core.backends.numba.sampling): its result does
not depend on threads, task dealing, visiting order or build; its texel keys and tile
order; and starting rows itself."""

from __future__ import annotations

import numpy as np
import pytest

from cvsss.core.geometry import GeometryCache, geometry_of
from cvsss.core.mc import estimator
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.params import SSSParams
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.synthetic import scene_frame

numba = pytest.importorskip("numba")
sampling = pytest.importorskip("cvsss.core.backends.numba.sampling")


def test_thread_count_does_not_change_the_result(monkeypatch):
    """Pixels are independent: one thread and all threads give the same bits."""
    frame = scene_frame("flash", 3, 256, 144)
    profile = frame_profile(frame, SSSParams())
    geom = geometry_of(frame, profile, surface_distance=True)
    counts = np.full(geom.size, 16)
    kw = dict(frame=3, seed=1, depth_slope=2.0, variance=True, backend="numba")
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    finally:
        numba.set_num_threads(before)
    many = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    assert np.array_equal(one.distant, many.distant)
    assert np.array_equal(one.variance, many.variance)
    assert one.fallback == many.fallback
    # Small calls run the serial build of the same code: the same bits again.
    assert counts.sum() >= sampling.PARALLEL_MIN_SAMPLES
    original, chosen = sampling.build_for, []

    def spy(samples, pixels=0):
        chosen.append(original(samples, pixels))
        return chosen[-1]

    monkeypatch.setattr(sampling, "PARALLEL_MIN_SAMPLES", 1 << 62)
    monkeypatch.setattr(sampling, "build_for", spy)
    serial = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    assert chosen == [sampling.pixel_sums_serial]
    assert np.array_equal(serial.distant, many.distant)
    assert np.array_equal(serial.variance, many.variance)


def test_tasks_dealt_over_any_number_of_threads_give_the_same_bits(monkeypatch):
    """The parallel build deals its tasks out over ``threads`` (iteration t runs task
    (t % per)·threads + t // per): every task runs once, whatever the count, also where
    it does not divide the tasks or exceeds them. Every pixel active, so the pass
    writes each row of an uninitialised estimate: a task left out shows as garbage."""
    frame = scene_frame("flash", 3, 160, 90)
    profile = frame_profile(frame, SSSParams())
    geom = geometry_of(frame, profile, surface_distance=True)
    counts = np.random.default_rng(3).integers(1, 40, geom.size)
    tasks = -(-geom.size // sampling.PIXELS_PER_TASK)
    assert tasks % 3 and tasks % 7 and tasks < 1000, tasks
    kw = dict(frame=3, seed=1, depth_slope=2.0, variance=True, backend="numba")
    runs = {}
    for threads in (1, 2, 3, 7, 1000):
        monkeypatch.setattr(
            sampling,
            "build_for",
            lambda n, p=0, k=threads: lambda *a: sampling.pixel_sums(*a[:-1], k),
        )
        runs[threads] = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    for threads, run in runs.items():
        assert np.array_equal(run.distant, runs[1].distant), threads
        assert np.array_equal(run.variance, runs[1].variance), threads
        assert run.fallback == runs[1].fallback, threads


def test_the_build_follows_the_work_of_pixels_and_samples():
    """Threads for a call's work, counting each pixel as PIXEL_SAMPLES samples."""
    top = sampling.PARALLEL_MIN_SAMPLES
    assert sampling.build_for(top) is sampling.pixel_sums
    assert sampling.build_for(top - 1) is sampling.pixel_sums_serial
    # Many pixels at one sample each: the pixels' own cost makes it worth the threads.
    pixels = top // (sampling.PIXEL_SAMPLES + 1) + 1
    assert sampling.build_for(pixels, pixels) is sampling.pixel_sums
    assert sampling.build_for(pixels) is sampling.pixel_sums_serial
    # A 32x32 tile at 16 spp stays serial.
    assert sampling.build_for(16 * 1024, 1024) is sampling.pixel_sums_serial


def test_surface_keys_tell_every_slot_and_object_apart_in_float32():
    """The texel keys ``slot + K·object``: equal exactly for the same material of the
    same object, the object recovered by floor(key/K), exact in float32 even with many
    slots and the largest object numbers (renumbered by rank when they would not fit)."""
    rng = np.random.default_rng(1)
    slots = rng.integers(0, 700, 5000).astype(np.int32)  # K = 1024
    objects = rng.choice([0, 3, 17, 32767], 5000).astype(np.int32)  # 32768·1024 > 2**24
    keys, inv_k = sampling.surface_keys(slots, objects)
    k32 = keys.astype(np.float32)
    assert np.array_equal(k32.astype(np.int64), keys)  # exact in float32
    pairs = slots.astype(np.int64) * 100_000 + objects
    same_key = k32[:, None] == k32[None, :200]
    assert np.array_equal(same_key, pairs[:, None] == pairs[None, :200])
    obj = np.floor(k32 * inv_k)
    assert np.array_equal(obj[:, None] == obj[None, :200], objects[:, None] == objects[None, :200])
    plain, one = sampling.surface_keys(slots, None)
    assert np.array_equal(plain, slots) and one == 1.0


def test_tile_order_visits_every_pixel_once_tile_by_tile():
    """The visiting order (speed only): a permutation of the active pixels, tile after
    tile of TILE×TILE pixels, row-major inside a tile, at any image width (tile keys
    past 16 bits included)."""
    tile_side = sampling.TILE
    rng = np.random.default_rng(2)
    # 70 tiles (16-bit keys); 301 × 220 = 66220 tiles (wider keys), sparse pixels of it.
    for w, h, n in ((100, 70, None), (300 * tile_side + 5, 220 * tile_side, 50_000)):
        assert (-(-w // tile_side)) * (-(-h // tile_side)) > (1 << 16) or n is None
        if n is None:
            flat = np.flatnonzero(rng.random(w * h) < 0.3)
        else:
            flat = np.unique(rng.integers(0, w * h, n))
        y, x = np.divmod(flat, w)
        order = sampling.tile_order(x, y, w)
        assert np.array_equal(np.sort(order), np.arange(flat.size))
        tile = (y // tile_side) * (-(-w // tile_side)) + x // tile_side
        assert np.all(np.diff(tile[order]) >= 0)
        same = np.diff(tile[order]) == 0
        assert np.all(np.diff(flat[order])[same] > 0)


def _compiled_sums(geom, frame, profile, counts, active, *, start=False, variance=True):
    if start:
        distant = np.full((geom.size, 3), np.nan)
    else:
        distant = geom.gamma * geom.at(frame.lighting).astype(np.float64)
    var, fallback = estimator._distant_sums_compiled(
        geom, profile, counts, active, frame.lighting, frame.depth, frame=frame.number,
        seed=0, depth_slope=2.0, variance=variance, disk=True, hidden_light=0.75,
        hidden_mirror=estimator.mirror_slots(profile, True), contact=0.5, chunk_samples=1 << 16, distant=distant, start=start,
        samples=int(counts[active].sum()),
    )  # fmt: skip
    return distant, var, fallback


def test_results_do_not_depend_on_the_visiting_order(monkeypatch):
    """Each pixel's sums are its own: visiting the pixels in reverse gives the same bits."""
    frame = scene_frame("flash", 2, 48, 32)
    profile = frame_profile(frame, SSSParams())
    counts = np.random.default_rng(3).integers(1, 40, geometry_of(frame, profile).size)

    def run():
        # A Geometry of its own: a Geometry keeps the order of its pixels (its memos).
        fresh = geometry_of(frame, profile, surface_distance=True)
        return _compiled_sums(fresh, frame, profile, counts, np.flatnonzero(fresh.gamma_sum > 0))

    tiled = run()
    monkeypatch.setattr(sampling, "tile_order", lambda x, y, w, a: np.arange(a.size)[::-1].copy())
    reverse = run()
    assert np.array_equal(tiled[0], reverse[0])
    assert np.array_equal(tiled[1], reverse[1])
    assert tiled[2] == reverse[2]


def test_started_rows_equal_numpys_start_plus_the_means():
    """With ``start`` the pass sets each row to γ·B(p) plus the pixel's mean itself:
    from rows of NaN it gives the bits of NumPy's γ·B with the means added; a Geometry
    reused with other lighting (its texels relit in place) gives the bits of a fresh one.
    Only a reused Geometry keeps the texels (32 bytes per pixel) between calls."""
    frames = [scene_frame("flash", n, 48, 32) for n in (2, 3, 4)]
    assert not np.array_equal(frames[1].lighting, frames[2].lighting)
    profile = frame_profile(frames[0], SSSParams())
    cache = GeometryCache()
    size = geometry_of(frames[0], profile, surface_distance=True).size
    counts = np.random.default_rng(5).integers(1, 40, size)
    active = np.arange(size)
    for frame in frames:  # the third frame relights the second one's texels
        geom = cache.get(frame, profile, surface_distance=True)
        assert geom.reused == (frame is not frames[0])
        for variance in (False, True):
            fresh = geometry_of(frame, profile, surface_distance=True)
            want = _compiled_sums(fresh, frame, profile, counts, active, variance=variance)
            got = _compiled_sums(geom, frame, profile, counts, active, start=True,
                                 variance=variance)  # fmt: skip
            assert np.isfinite(want[0]).all()
            assert np.array_equal(got[0], want[0])
            assert got[2] == want[2]
            if variance:
                assert np.array_equal(got[1], want[1])
            else:
                assert got[1] is None and want[1] is None
        assert (estimator._TEXELS in geom.memos) == geom.reused
        assert estimator._TEXELS not in fresh.memos and not fresh.reused
    assert cache.hits == 2
    # Rows of pixels that take no samples would stay unset: refused.
    with pytest.raises(ValueError, match="every pixel"):
        _compiled_sums(fresh, frames[0], profile, counts, active[:-1], start=True)


def test_history_passes_are_compiled_for_writable_arrays():
    """The history's reads and writes run in the types the compile step compiles:
    writable arrays (a read-only one is another type, compiled again inside a frame)."""
    from cvsss.core.mc.history import History

    hist = History.empty((4, 5))
    index = np.arange(6, dtype=np.int64)
    hist.write_columns(("mu",), index, np.ones((6, 1)), "numba")
    hist.read_columns(("mu",), index, "numba")
    history = pytest.importorskip("cvsss.core.backends.numba.history")
    for compiled in (history.read_column, history.write_column):
        arrays = [t for s in compiled.signatures for t in s if isinstance(t, numba.types.Array)]
        assert arrays and all(t.mutable for t in arrays)

"""Sequence processing: CV acts on counts only, determinism, history storage."""

import numpy as np
import pytest

from cvsss.core import METHODS, SSSParams, make_processor
from cvsss.core.io import checkpoint
from cvsss.core.mc.history import History
from cvsss.core.synthetic import scene_frame, sequence


def test_same_counts_same_image_for_every_adaptive_method():
    """CV acts in the sample domain only (P Sec. 6): given the same counts, the adaptive
    methods shade the same image; left to choose, they choose different counts."""
    frames = list(sequence("flash", 4, 80, 45))
    rng = np.random.default_rng(3)
    forced = rng.integers(1, 40, frames[0].shape)  # any count map
    results, own = {}, {}
    for method in ("as", "as_ocv", "as_ccv"):
        proc = make_processor(method, SSSParams())
        free = make_processor(method, SSSParams())
        for f in frames:
            res = proc.process(f, counts=forced)
            own[method] = free.process(f).counts
        results[method] = res
    a, b, c = (results[m] for m in ("as", "as_ocv", "as_ccv"))
    assert np.array_equal(a.counts[a.mask], forced[a.mask])
    assert np.array_equal(a.sss, b.sss) and np.array_equal(a.sss, c.sss)
    assert np.array_equal(a.composite, c.composite)
    # ... while under flashing light the control variates lower their own counts.
    assert own["as_ccv"][a.mask].mean() < own["as"][a.mask].mean()
    assert own["as_ocv"][a.mask].mean() < own["as"][a.mask].mean()


def test_cv_lowers_counts_under_flashing_light():
    spp = {}
    for method in ("as", "as_ocv", "as_ccv"):
        proc = make_processor(method, SSSParams())
        spp[method] = np.mean([proc.process(f).spp for f in sequence("flash", 36, 96, 54)][12:])
    assert spp["as_ccv"] < 0.7 * spp["as"]
    assert spp["as_ocv"] < 0.7 * spp["as"]


def test_fixed_seed_bit_identical():
    def go():
        proc = make_processor("as_ocv", SSSParams(seed=9))
        return [proc.process(f) for f in sequence("regular", 5, 64, 36)][-1]

    a, b = go(), go()
    for name in ("sss", "composite", "counts", "alpha", "variance"):
        assert np.array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize("method", list(METHODS))
def test_every_method_runs(method):
    p = SSSParams(reference_spp=64)
    proc = make_processor(method, p)
    for f in sequence("flash", 2, 48, 27):
        res = proc.process(f)
    assert res.method == method
    assert np.all(np.isfinite(res.composite))
    if METHODS[method].monte_carlo:
        assert res.samples > 0
    elif METHODS[method].kind == "separable":  # tap reads, not samples
        assert res.samples > 0 and not np.array_equal(res.composite, f.combined)
    else:
        assert res.samples == 0 and np.array_equal(res.composite, f.combined)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("method", ["as_ccv", "as_ocv_t", "separable"])
def test_reused_geometry_gives_the_same_frames(method, backend):
    """The processors reuse a still scene's Geometry (core.geometry.GeometryCache): a
    sequence whose geometry is still, then moves, then is still again gives the same
    frames, bit for bit, as one that prepares every frame anew; the still frames hit.
    The compiled kernel keeps its texels in the reused Geometry and relights them
    (core.mc.estimator._TEXELS): the light flashes from frame to frame."""
    import dataclasses

    from cvsss.core import geometry

    frames = list(sequence("flash", 6, 64, 36))
    for k in (3, 4):  # geometry moves on frames 4 and 5, and stays from 5 to 6
        frames[k] = dataclasses.replace(frames[k], depth=frames[k].depth * (1.0 + 0.05 * (k - 2)))
    frames[5] = dataclasses.replace(frames[5], depth=frames[4].depth.copy())

    class Fresh(geometry.GeometryCache):
        def geometry_of(self, frame, profile, **options):
            return geometry.geometry_of(frame, profile, **options)

    params = SSSParams(backend=backend)
    cached, fresh = make_processor(method, params), make_processor(method, params)
    fresh._geometry = Fresh()
    for f in frames:
        a, b = cached.process(f), fresh.process(f)
        for name in ("composite", "sss", "counts", "alpha", "variance", "gamma", "mask"):
            x, y = getattr(a, name), getattr(b, name)
            assert np.array_equal(x, y, equal_nan=True), (f.number, name)
    assert cached._geometry.hits == 3  # frames 2, 3 and 6


def test_only_the_online_control_variate_keeps_its_history_j():
    """J (Σ, ζ) is the online control variate's: the other adaptive methods hold H (and
    the temporal buffers) only, and their frames equal those of a history that also
    carries a J it never reads."""
    from cvsss.core.mc.history import H_FIELDS, J_FIELDS, T_FIELDS, History

    frames = list(sequence("flash", 3, 48, 27))
    for method in ("as", "as_ccv", "as_ocv", "as_ccv_t", "as_ocv_t"):
        m = METHODS[method]
        proc = make_processor(method, SSSParams())
        results = [proc.process(f) for f in frames]
        want = {
            *H_FIELDS,
            *(J_FIELDS if m.cv == "online" else ()),
            *(T_FIELDS if m.temporal else ()),
        }
        assert set(proc.history.buffers) == want, method
        if m.cv != "online":
            full = make_processor(method, SSSParams())
            p = full.params
            full.history = History.empty(
                frames[0].shape, p.history_precision, p.eta_cv, p.target_variance,
                temporal=bool(m.temporal),
            )  # fmt: skip
            for f, r in zip(frames, results):
                assert np.array_equal(full.process(f).composite, r.composite), method


def test_float16_history_stays_close_to_float32():
    out = {}
    for prec in ("float32", "float16"):
        proc = make_processor("as_ocv", SSSParams(history_precision=prec))
        out[prec] = [proc.process(f) for f in sequence("flash", 30, 64, 36)]
        h = proc.history
        assert h.buffers["mu"].dtype == np.dtype(prec)
    s32 = np.mean([r.spp for r in out["float32"][10:]])
    s16 = np.mean([r.spp for r in out["float16"][10:]])
    assert abs(s16 - s32) / s32 < 0.1
    # Scaled storage keeps Σ from flushing to zero at η_cv = 1e-6.
    h16 = proc.history
    assert np.count_nonzero(h16.buffers["syy"]) > 0


@pytest.mark.parametrize("backend", ["numpy", "auto"])
def test_history_reprojection_follows_motion(backend):
    h = History.empty((4, 6))
    h.buffers["mu"][1, 2] = 5.0
    h.valid[1, 2] = True
    h.material[:] = 1
    h.depth[:] = 2.0
    motion = np.zeros((4, 6, 2), np.float32)
    motion[2, 4] = (-2.0, -1.0)  # surface now at (row 2, col 4) came from (1, 2)
    out = h.reproject(motion, np.full((4, 6), 2.0, np.float32), np.ones((4, 6), np.int32), backend)
    assert out.buffers["mu"][2, 4] == 5.0 and out.valid[2, 4]
    # Material change or a depth jump invalidates.
    mat = np.ones((4, 6), np.int32)
    mat[2, 4] = 2
    assert not h.reproject(motion, np.full((4, 6), 2.0, np.float32), mat, backend).valid[2, 4]
    depth = np.full((4, 6), 2.0, np.float32)
    depth[2, 4] = 3.0
    assert not h.reproject(motion, depth, np.ones((4, 6), np.int32), backend).valid[2, 4]


@pytest.mark.parametrize("backend", ["numpy", "auto"])
@pytest.mark.parametrize("still", ["none", "zero", "tiny"])
def test_still_camera_history_aligned_in_place(backend, still):
    def history():
        h = History.empty((4, 6), temporal=True)
        h.buffers["mu"][...] = 5.0
        h.buffers["acc_n"][...] = 3.0
        h.valid[...] = True
        h.material[...] = 1
        h.depth[...] = 2.0
        return h

    depth = np.full((4, 6), 2.0, np.float32)
    depth[0, 0] = 2.5  # a depth jump
    mat = np.ones((4, 6), np.int32)
    mat[1, 1] = 2  # another slot
    motion = None if still == "none" else np.zeros((4, 6, 2), np.float32)
    if still == "tiny":  # a still camera's motion pass holds such values
        motion[::2] = (8e-6, -0.49)
    copied = history().reproject(motion, depth, mat, backend)
    h = history()
    aligned = h.reproject(motion, depth, mat, backend, in_place=True)
    assert aligned is h
    changed = np.zeros((4, 6), bool)
    changed[0, 0] = changed[1, 1] = True
    assert np.array_equal(aligned.valid, ~changed)
    assert np.array_equal(aligned.buffers["acc_n"], np.where(changed, 0.0, 3.0))
    assert np.all(aligned.buffers["mu"] == 5.0)  # not a reset field
    assert np.array_equal(aligned.depth, depth) and np.array_equal(aligned.material, mat)
    for k, v in copied.buffers.items():
        assert np.array_equal(aligned.buffers[k], v), k
    assert np.array_equal(aligned.cv_valid, copied.cv_valid)
    # A moving camera's history is fetched anew, in place or not: the old one unchanged.
    motion = np.zeros((4, 6, 2), np.float32)
    motion[2, 4] = (-2.0, -1.0)
    moved = h.reproject(motion, depth, mat, backend, in_place=True)
    assert moved is not h and h.buffers["acc_n"][0, 0] == 0 and h.buffers["acc_n"][2, 4] == 3


def test_state_handed_out_is_not_written_by_the_next_frame():
    # A still scene's history is aligned in place, except after state() handed its
    # arrays out (a checkpoint may write them later; the bench restores them).
    proc = make_processor("as_ccv_t", SSSParams())
    frames = list(sequence("flash", 4, 32, 18))
    for f in frames[:2]:
        proc.process(f)
    state = proc.state()
    before = {k: v.copy() for k, v in state.items()}
    proc.process(frames[2])
    for k, v in state.items():
        assert np.array_equal(v, before[k], equal_nan=v.dtype.kind == "f"), k
    # ... and the frame after that one aligns in place again, with the same result.
    twin = make_processor("as_ccv_t", SSSParams())
    for f in frames[:3]:
        twin.process(f)
    assert np.array_equal(proc.process(frames[3]).sss, twin.process(frames[3]).sss)


def test_checkpoint_round_trip(tmp_path):
    proc = make_processor("as_ocv", SSSParams(history_precision="float16"))
    for f in sequence("flash", 3, 32, 18):
        proc.process(f)
    path = tmp_path / "h.npz"
    checkpoint.save(path, {"frames_done": [1, 2, 3]}, proc.state())
    # Written through a temporary file beside it, which is gone.
    assert [p.name for p in tmp_path.iterdir()] == ["h.npz"]
    state, arrays = checkpoint.load(path)
    assert sorted(arrays) == sorted(proc.state())
    resumed = make_processor("as_ocv", SSSParams(history_precision="float16"))
    resumed.restore(arrays)
    loaded = resumed.history
    assert state["frames_done"] == [1, 2, 3]
    assert loaded.frame == 3 and loaded.precision == "float16"
    for k, v in proc.history.buffers.items():
        assert np.array_equal(loaded.buffers[k], v)
    assert np.array_equal(loaded.valid, proc.history.valid)
    # The resumed processor continues exactly as the original.
    nxt = scene_frame("flash", 4, 32, 18)
    assert np.array_equal(resumed.process(nxt).sss, proc.process(nxt).sss)


def test_mismatched_frame_size_is_an_error():
    proc = make_processor("as", SSSParams())
    proc.process(scene_frame("static", 1, 32, 18))
    with pytest.raises(ValueError, match="sequence started at 32x18"):
        proc.process(scene_frame("static", 2, 48, 27))

"""Whole methods on both backends: the NumPy and the compiled passes give the same
results frame after frame (the twins one by one: backends/test_twins.py).

Tolerance: ``RTOL = 4e-6`` of the largest value of an image (~32 float32 ulps; the
runs below measure ≤ 1.6e-7). Everything discrete must be *equal*: sample counts
per pixel, samples taken, samples that fell back.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from tiling_helpers import FAST, FRAMES, differences, run_tiled, run_whole, same_state

from cvsss.core.camera import Camera
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.method import MethodOptions
from cvsss.core.methods import METHODS, make_processor
from cvsss.core.params import SSSParams
from cvsss.core.profiles.burley import BurleyProfile
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.synthetic import flat_plane

pytest.importorskip("numba")

RTOL = 4e-6
TIMINGS = ("sampling_ms", "update_ms", "total_ms")
EXACT = ("counts", "valid_history", "mask", "samples", "fallback", "draws", "spp")


def run(name: str, params: SSSParams, frames=FRAMES):
    proc = make_processor(name, params, MethodOptions())
    return [proc.process(f) for f in frames], proc.state()


def assert_same_result(a, b, rtol: float = RTOL) -> None:
    """Every field of two FrameResults: discrete ones equal, images within rtol·max."""
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name in TIMINGS:
            continue
        if f.name in EXACT or not isinstance(x, np.ndarray | float):
            assert np.array_equal(x, y), f.name
            continue
        x, y = np.asarray(x, np.float64), np.asarray(y, np.float64)
        scale = float(np.max(np.abs(x), initial=0.0))
        np.testing.assert_allclose(y, x, rtol=0, atol=rtol * scale + 1e-30, err_msg=f.name)


@pytest.mark.parametrize("distance", ["surface", "cycles", "planar"])
@pytest.mark.parametrize("name", list(METHODS))
def test_every_method_same_result(name, distance):
    """Three moving frames (history, reprojection, disocclusion band): same images and counts."""
    params = dataclasses.replace(FAST, distance=distance)
    a, state_a = run(name, params.replace(backend="numpy"))
    b, state_b = run(name, params.replace(backend="numba"))
    for x, y in zip(a, b):
        assert_same_result(x, y)
    assert state_a.keys() == state_b.keys()
    for k in state_a:
        if state_a[k].dtype.kind == "f":
            scale = float(np.max(np.abs(state_a[k]), initial=0.0))
            np.testing.assert_allclose(state_b[k], state_a[k], rtol=0, atol=RTOL * scale + 1e-30)
        else:
            assert np.array_equal(state_a[k], state_b[k]), k


def test_tiles_equal_whole_image_on_numba_and_match_numpy():
    """core.tiling's bit-identity holds per backend (global pixel coordinates seed the hash)."""
    params = FAST.replace(backend="numba")
    whole, whole_state = run_whole("as_ocv_t", params, MethodOptions(), FRAMES)
    tiled, tiled_state, session = run_tiled("as_ocv_t", params, MethodOptions(), FRAMES)
    assert len(session.cores) == 12
    assert all(differences(a, b) == [] for a, b in zip(whole, tiled))
    assert same_state(whole_state, tiled_state)
    numpy_tiled, _, _ = run_tiled(
        "as_ocv_t", FAST.replace(backend="numpy"), MethodOptions(), FRAMES
    )
    for a, b in zip(numpy_tiled, tiled):
        assert_same_result(a, b)


def test_total_ms_covers_the_composite(monkeypatch):
    """``total_ms`` is the whole ``process()`` call: the composite and the maps built
    after the sampling included (a composite slowed by 50 ms shows in it)."""
    import time

    from cvsss.core.backends.twins import TWINS

    row = TWINS["composite"]
    slow = row.compiled

    def composite(*args, **kwargs):
        time.sleep(0.05)
        return slow(*args, **kwargs)

    monkeypatch.setattr(row, "compiled", composite)
    for name in ("as_ccv", "separable"):
        res = make_processor(name, SSSParams(backend="numba")).process(FRAMES[0])
        assert res.total_ms >= 50.0 + res.sampling_ms + res.update_ms, name


def test_other_profiles_run_on_numpy_with_the_numba_backend():
    """The compiled sampling covers Burley; another profile is computed by NumPy, not refused."""
    frame = flat_plane(32, 24)
    burley = frame_profile(frame, SSSParams())
    assert isinstance(burley, BurleyProfile)
    geom = geometry_of(frame, burley)
    counts = np.full(geom.size, 8)
    kw = dict(frame=1, seed=0, depth_slope=2.0)

    class Other(BurleyProfile):  # not the Burley class itself: same numbers, NumPy path
        pass

    other = Other(burley.d)
    a = estimate_distant(geom, frame.lighting, frame.depth, other, counts, backend="numba", **kw)
    b = estimate_distant(geom, frame.lighting, frame.depth, burley, counts, backend="numpy", **kw)
    assert np.array_equal(a.distant, b.distant)  # bit-identical: it is the NumPy path


@pytest.mark.parametrize("distance", ["surface", "cycles", "planar"])
@pytest.mark.parametrize("d", [(0.02, 0.01, 0.005), (0.01, 0.01, 0.01)], ids=["rgb", "grey"])
def test_orthographic_camera_and_constant_lighting_on_numba(d, distance):
    """Ortho camera, one profile for all channels (w_c = γ_c) or three; constant B gives
    L = B exactly on the compiled backend (the centre control), any m (Cycles' kernel:
    to float rounding)."""
    plane = flat_plane(48, 32, d=d, depth=2.0)
    ortho = Camera(**{**dataclasses.asdict(plane.camera), "type": "ORTHO", "ortho_scale": 1.5})
    plane = dataclasses.replace(plane, camera=ortho)
    profile = frame_profile(plane, SSSParams())
    assert bool(profile.chromatic()[1]) == (d[0] != d[2])
    geom = geometry_of(plane, profile, surface_distance=distance != "planar")
    assert (geom.surface is not None and geom.surface.ortho) == (distance != "planar")
    counts = np.full(geom.size, 24)
    kw = dict(frame=1, seed=3, depth_slope=2.0, disk=distance == "cycles")
    const = np.full_like(plane.lighting, 0.37)
    c = estimate_distant(geom, const, plane.depth, profile, counts, backend="numba", **kw)
    b_ = const.reshape(-1, 3)[geom.index].astype(np.float64)
    shaded = (1 - geom.gamma) * b_ + c.distant
    if distance == "cycles":
        # Cycles' kernel gains energy on curved surfaces only: on a plane G = 1 up to the
        # rounding of the offset's component along the normal.
        np.testing.assert_allclose(shaded, b_, rtol=1e-6)
    else:
        assert np.array_equal(shaded, (1 - geom.gamma) * b_ + geom.gamma * b_)

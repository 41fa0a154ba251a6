"""The numba and NumPy backends of the sampling step take the same samples (core.mc.backend).

Both implement :func:`core.mc.estimator.estimate_distant` operation by
operation in float32; only log/exp/sin/cos come from different libraries, so
the estimates agree to float32 rounding. The tolerance used throughout is
``RTOL = 4e-6`` of the largest value of the image (~32 float32 ulps; the
runs below measure ≤ 1.6e-7 on these frames). Everything discrete must be
*equal*: sample counts per pixel, samples taken, samples that fell back. (A
sample within an ulp of a pixel boundary could in principle round to the
neighbouring pixel in one backend; with these fixed seeds and frames none
does, and the equalities would catch one that did.)
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from test_tiling import FAST, FRAMES, differences, run_tiled, run_whole, same_state

from cvsss.core.camera import Camera
from cvsss.core.geometry import prepare, surface
from cvsss.core.mc import backend
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.methods import METHODS, MethodOptions, make_processor
from cvsss.core.params import ParameterError, SSSParams
from cvsss.core.profiles.burley import BurleyProfile
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.synthetic import flat_plane, scene_frame
from cvsss.core.tiling import crop_frame

numba = pytest.importorskip("numba")

RTOL = 4e-6
TIMINGS = ("pass_ms", "update_ms", "total_ms")
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


def test_numba_runs_here():
    """The pinned environment has numba: this lane measures the compiled kernel, not a fallback."""
    assert backend.resolve("auto") == "numba"
    assert backend.resolve("numpy") == "numpy"
    assert "numba" in backend.describe("auto")


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
        scale = (
            float(np.max(np.abs(state_a[k]), initial=0.0)) if state_a[k].dtype.kind == "f" else 0
        )
        if state_a[k].dtype.kind == "f":
            np.testing.assert_allclose(state_b[k], state_a[k], rtol=0, atol=RTOL * scale + 1e-30)
        else:
            assert np.array_equal(state_a[k], state_b[k]), k


def _surface_frames():
    frame = scene_frame("flash", 2, 96, 54)  # perspective, background (inf depth), steep rims
    plane = flat_plane(48, 32, d=(0.02, 0.01, 0.005), depth=2.0)
    yy, xx = np.mgrid[0:32, 0:48]
    tilted = (2.0 + 0.05 * xx + 0.002 * yy * yy).astype(np.float32)
    tilted[10:14, 20:30] = np.inf  # a hole: one-sided steps around it
    ortho = Camera(**{**dataclasses.asdict(plane.camera), "type": "ORTHO", "ortho_scale": 1.5})
    return {
        "perspective": frame,
        "crop": crop_frame(frame, (10, 40, 20, 70), (14, 36, 24, 66)),
        "ortho": dataclasses.replace(plane, camera=ortho, depth=tilted),
        "perspective-hole": dataclasses.replace(plane, depth=tilted),
    }


@pytest.mark.parametrize("case", ["perspective", "crop", "ortho", "perspective-hole"])
def test_compiled_surface_is_bit_identical(case):
    """The compiled depth-buffer surface (areas and normals) equals the NumPy one bit for
    bit: perspective and orthographic cameras, a crop (tile origin), holes in the depth."""
    frame = _surface_frames()[case]
    a, b = surface(frame, "numpy"), surface(frame, "numba")
    assert b.ortho == a.ortho == (case == "ortho")
    assert b.area.dtype == a.area.dtype == np.float32
    assert b.normal.dtype == a.normal.dtype == np.float32
    assert np.array_equal(a.area, b.area)
    assert np.array_equal(a.normal, b.normal)
    assert np.isfinite(a.normal).all() and (a.area > 0).any()


def _two_materials():
    """The tilted plane with a hole, a stripe without subsurface (finite depth) and a
    second subsurface material: reads that land on another material must get no weight."""
    plane = _surface_frames()["perspective-hole"]
    mat = plane.material.copy()
    mat[:, 30:33] = 0
    mat[20:, :20] = 2
    spec = plane.materials[1]
    other = dataclasses.replace(spec, slot=2, name="other", d=(0.03, 0.02, 0.01))
    return dataclasses.replace(plane, material=mat, materials={1: spec, 2: other})


@pytest.mark.parametrize("case", ["perspective", "crop", "materials"])
@pytest.mark.parametrize(
    "options",
    [
        {},
        {"filter": "linear"},
        {"jitter": True, "jitter_threshold": 1.0},
        {"kernel": "svd2", "taps": 11, "filter": "linear", "jitter": True},
        {"follow": "exponential"},
    ],
    ids=["nearest", "linear", "jitter", "svd2-linear-jitter", "exponential"],
)
def test_compiled_separable_passes_equal_numpy(options, case):
    """The compiled separable passes (the ``separable`` method and the temporal proxy)
    give NumPy's result bit for bit: nearest and linear reads, jittered taps, two terms
    (the vertical pass reads each term's group), a crop (tile origin, core pixels) and
    the same fall-back count. The exponential follow calls exp, which differs by an ulp
    between the libraries: within 1e-6 of the largest value there."""
    from cvsss.core.mc import estimator_numba
    from cvsss.core.params import SeparableParams
    from cvsss.core.separable.apply import apply

    frame = _two_materials() if case == "materials" else _surface_frames()[case]
    profile = frame_profile(frame, SSSParams())
    params = SeparableParams(**options)
    out = {}
    for name in ("numpy", "numba"):
        geom = prepare(frame, profile)
        out[name] = apply(frame, profile, params, seed=5, geom=geom, backend=name)
    (ga, a, sa), (gb, b, sb) = out["numpy"], out["numba"]
    assert np.array_equal(ga.index, gb.index) and a.shape == b.shape == (ga.size, 3)
    assert (a > 0).any() and sa["fallback"] > 0
    if case == "crop":
        assert ga.core is not None and not ga.core.all()
    for k in ("fallback", "tap_reads", "reads_per_pixel"):
        assert sa[k] == sb[k], k
    if params.follow == "exponential":
        np.testing.assert_allclose(b, a, rtol=0, atol=1e-6 * a.max())
    else:
        assert np.array_equal(a, b)
    # The compiled pass of the follow rule ran.
    assert estimator_numba.separable_pass(params.follow == "exponential").signatures


@pytest.mark.parametrize("case", ["perspective", "crop", "materials"])
def test_compiled_neighbourhood_equals_numpy(case):
    """The temporal reuse's 3×3 statistics, compiled, equal NumPy's bit for bit: inactive
    pixels, NaN values, several materials, the image and crop borders."""
    from cvsss.core.mc import estimator_numba
    from cvsss.core.mc.temporal import neighbourhood

    frame = _two_materials() if case == "materials" else _surface_frames()[case]
    geom = prepare(frame, frame_profile(frame, SSSParams()))
    rng = np.random.default_rng(4)
    values = rng.lognormal(0, 2, (geom.size, 3))
    values[rng.random(geom.size) < 0.05, 0] = np.nan
    active = rng.random(geom.size) < 0.8
    if case != "materials":  # speckled slots
        geom = dataclasses.replace(geom, mat=rng.integers(1, 3, geom.size).astype(np.int32))
    assert len(np.unique(geom.mat)) == 2
    a = neighbourhood(geom, values, active, "numpy")
    b = neighbourhood(geom, values, active, "numba")
    for x, y in zip(a, b):
        assert x.shape == y.shape == (geom.size, 3)
        assert np.array_equal(x, y, equal_nan=True)
    assert np.isfinite(a[0]).all() and (a[1] > 0).any()
    assert estimator_numba.neighbourhood_pass.signatures


@pytest.mark.parametrize("noisy", [True, False], ids=["noise", "no-noise"])
@pytest.mark.parametrize("clamp", [2.0, np.inf], ids=["clamp", "no-clamp"])
@pytest.mark.parametrize("mode", ["plain", "subtractive", "multiplicative"])
def test_compiled_temporal_reuse_matches_numpy(mode, clamp, noisy):
    """The temporal reuse's compiled per-pixel passes give NumPy's estimate, frame
    counts and history within a few ulps (libm's log and exp against NumPy's, and the
    luminance summed in channel order against a matrix product): at most 1e-13 relative
    on finite values, and NaN and ±inf in the same places. Inactive pixels, NaN and
    infinite inputs and noise, a black control and a negative proxy included."""
    from cvsss.core.mc import estimator_numba, temporal
    from cvsss.core.mc.history import History

    frame = _surface_frames()["perspective"]
    geom = prepare(frame, frame_profile(frame, SSSParams()))
    p = geom.size
    out = {}
    with np.errstate(all="ignore"):
        for name in ("numpy", "numba"):
            rng = np.random.default_rng(1)
            hist = History.empty(frame.shape, "float32", 1e-3, 1e-4, temporal=True)
            for v in hist.buffers.values():
                v[...] = rng.lognormal(0, 1, frame.shape)
            distant, control = rng.lognormal(0, 1, (2, p, 3))
            proxy = rng.normal(1, 1, (p, 3))
            distant[::37, 1] = np.nan
            control[::41, 0] = 0.0
            proxy[::43, 2] = np.inf
            noise = rng.lognormal(-1, 1, p)
            noise[::29] = np.nan
            noise[::31] = np.inf
            est, frames = temporal.reuse(
                hist, geom, distant, control, rng.random(p), proxy, rng.random(p) < 0.85,
                mode=mode, min_weight=0.1, clamp=clamp, tolerance=0.3,
                noise=noise if noisy else None, scale=np.ones(3), backend=name,
            )  # fmt: skip
            out[name] = est, frames, {k: v.copy() for k, v in hist.buffers.items()}
    (a, na, ha), (b, nb, hb) = out["numpy"], out["numba"]
    for x, y in ((a, b), (na, nb)):
        assert np.array_equal(np.isnan(x), np.isnan(y))
        assert np.array_equal(np.isinf(x), np.isinf(y)) and np.array_equal(
            x[np.isinf(x)], y[np.isinf(y)]
        )
        ok = np.isfinite(x)
        np.testing.assert_allclose(y[ok], x[ok], rtol=1e-13, atol=1e-300)
    assert np.isfinite(a).mean() > 0.9 and (na > 1).any() and (na == 0).any()
    for k in ha:
        np.testing.assert_allclose(hb[k], ha[k], rtol=1e-6, equal_nan=True, err_msg=k)
    assert estimator_numba.reuse_start.signatures and estimator_numba.reuse_finish.signatures


def test_compiled_burley_region_matches_numpy():
    """The compiled Burley region (γ, weight scale, sampling bounds) equals the NumPy one:
    bit for bit where NumPy's float64 exp is libm's (no AVX-512), else within 1e-14
    relative: NumPy's AVX-512 exp differs from libm's by an ulp, and γ, a difference of
    exponentials, carries that ulp of its terms (measured up to 17 ulp of γ itself,
    2.0e-15 relative, on an AVX-512 host). Channels that do not scatter, r0 = 0 and r0
    beyond the truncation radius included."""
    from cvsss.core.geometry import distant_region

    rng = np.random.default_rng(3)
    d = np.array([[0, 0, 0], [0.01, 0.005, 0.002], [0.02, 0.0, 0.004], [1e-9, 5.0, 0.3]])
    profile = BurleyProfile(d)
    mat = rng.integers(1, 4, 5000)
    r0 = rng.random(5000) * 0.05
    r0[:4] = 0.0
    r0[4:8] = 1e300
    a = distant_region(profile, r0, mat, "numpy")
    b = distant_region(profile, r0, mat, "numba")
    features = np.core._multiarray_umath.__cpu_features__
    for name in ("gamma", "weight_scale", "lo", "hi"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype == np.float64 and x.shape == y.shape == (5000, 3), name
        if features.get("AVX512F"):
            np.testing.assert_allclose(y, x, rtol=1e-14, atol=0, err_msg=name)
        else:
            assert np.array_equal(x, y), name
    assert (a.gamma[:, 1][mat == 2] == 0).all()  # a channel without scattering: γ = 0
    assert (a.gamma > 0).any() and (a.gamma <= 1).all()


@pytest.mark.parametrize("case", ["whole", "crop"])
def test_compiled_composite_and_maps_equal_numpy(case):
    """The compiled composite and float maps (core.result.assemble) give NumPy's images
    bit for bit: NaN, ±inf, negative and above-float32 ``shaded``, a Subsurface Weight
    and none (also all ones, which NumPy skips), a crop, (P,) and (P, 3) maps with NaN
    and out-of-range values."""
    from cvsss.core.result import composite

    frame = scene_frame("flash", 3, 48, 32)
    if case == "crop":
        frame = crop_frame(frame, (4, 28, 6, 40), (8, 24, 10, 36))
    geom = prepare(frame, frame_profile(frame, SSSParams()))
    rng = np.random.default_rng(5)
    shaded = geom.at(frame.lighting).astype(np.float64) * rng.random((geom.size, 3)) * 2
    shaded[:5] = [[np.nan, np.inf, -np.inf], [-1.0, 1e300, 0.0], [-0.0, 3.5e38, np.nan]] + [
        [1.0, 2.0, 3.0]
    ] * 2
    for weight in (None, rng.random(geom.size), np.ones(geom.size)):
        a = composite(frame, geom.index, shaded, weight, "numpy")
        b = composite(frame, geom.index, shaded, weight, "numba")
        for x, y in zip(a, b):
            assert x.dtype == y.dtype == np.float32 and x.shape == y.shape == frame.lighting.shape
            assert np.array_equal(x, y)
        assert not np.array_equal(a[0], frame.combined)  # the SSS pixels changed
    values = rng.normal(0, 1e39, (geom.size, 3))
    values[:3] = [[np.nan, np.inf, -np.inf], [0.5, -0.5, 1e-50], [1, 2, 3]]
    for v, fill in (
        (values, 0.0),
        (values[:, 1], 0.0),
        ((values[:, 0] / 1e2).astype(np.float32), -1.0),
    ):
        x = geom.to_image(v, fill, backend="numpy")
        y = geom.to_image(v, fill, backend="numba")
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape == (
            *geom.shape,
            *v.shape[1:],
        )
        assert np.array_equal(x, y, equal_nan=True)
    from cvsss.core.mc import estimator_numba

    # The numba calls above ran the compiled passes (not a NumPy fall-back).
    assert estimator_numba._composite_pass.signatures
    assert estimator_numba._float_image_pass.signatures


@pytest.mark.parametrize("precision", ["float16", "float32"])
@pytest.mark.parametrize("moving", [True, False])
def test_compiled_reprojection_equals_numpy(precision, moving):
    """The compiled history reprojection gives NumPy's history bit for bit: every
    buffer (the temporal ones and the reset frame count included), both valid masks,
    depth and material. Motion with NaN, ±inf, huge values, half-pixel ties (rint),
    off-screen sources; inf (background) and jumping depths; changed slots."""
    from cvsss.core.mc.history import History

    rng = np.random.default_rng(11)
    shape = (23, 37)
    hist = History.empty(shape, precision, 1e-3, 1e-4, temporal=True)
    for v in hist.buffers.values():
        v[...] = rng.normal(0, 3, shape)
    hist.valid[...] = rng.random(shape) < 0.8
    hist.cv_valid[...] = rng.random(shape) < 0.6
    hist.material[...] = rng.integers(0, 3, shape)
    hist.depth[...] = rng.uniform(1, 2, shape)
    hist.depth[0] = np.inf
    depth = (hist.depth * rng.choice([1.0, 1.05, 1.2], shape)).astype(np.float32)
    depth[:, 0] = np.inf
    material = np.where(rng.random(shape) < 0.9, hist.material, 2).astype(np.int32)
    motion = None
    if moving:
        motion = rng.normal(0, 4, (*shape, 2)).astype(np.float32)
        motion[::5] = np.round(motion[::5] * 2) / 2  # ties: x.5
        motion[1, :4] = [[np.nan, 0], [np.inf, 1], [-np.inf, 1], [1e30, -1e30]]
    a = hist.reproject(motion, depth, material, "numpy")
    b = hist.reproject(motion, depth, material, "numba")
    for name in ("valid", "cv_valid", "material", "depth"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and np.array_equal(x, y), name
    assert a.buffers.keys() == b.buffers.keys()
    for k in a.buffers:
        x, y = a.buffers[k], b.buffers[k]
        assert x.dtype == y.dtype == hist.dtype, k
        assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), k
    assert a.valid.any() and not a.valid.all()
    assert (a.buffers["acc_n"] == 0).sum() > (a.buffers["mu"] == 0).sum()  # reset: not same
    from cvsss.core.mc import estimator_numba

    assert estimator_numba._reproject_pass.signatures  # the compiled pass ran


@pytest.mark.parametrize("scaled", [False, True])
def test_compiled_history_columns_equal_numpy(scaled):
    """History.read_columns / write_columns on the compiled backend store and return
    what History.read / write do, bit for bit: NaN (stored 0), ±inf and values past
    float32 (stored ±max), values that round, negative zero; with a stored scale
    (the float16 scales, forced here on float32 buffers) and without."""
    from cvsss.core.mc import estimator_numba
    from cvsss.core.mc.history import History

    rng = np.random.default_rng(5)
    shape = (19, 29)
    names = ("acc_r", "var", "sxy")
    hist = History.empty(shape, "float32", 1e-3, 1e-4, temporal=True)
    if scaled:
        hist.cov_scale, hist.var_scale = 1e3, 1e4
    assert (hist.scale("var") != 1.0) == scaled
    index = rng.choice(shape[0] * shape[1], 300, replace=False).astype(np.int64)
    values = rng.normal(0, 1e3, (300, 3)) * rng.choice([1e-40, 1.0, 1e36], (300, 3))
    values[:6, 0] = [np.nan, np.inf, -np.inf, 4e38, -4e38, -0.0]
    values[6:9, 1] = [np.nan, 1e35, -1e35]  # past float32 once scaled
    a, b = (dataclasses.replace(hist, buffers={k: v.copy() for k, v in hist.buffers.items()})
            for _ in range(2))  # fmt: skip
    for c, name in enumerate(names):
        a.write(name, index, values[:, c])
    b.write_columns(names, index, values, "numba")
    for name in names:
        assert np.array_equal(a.buffers[name].view(np.uint32), b.buffers[name].view(np.uint32))
    assert not np.isfinite(values).all() and np.isfinite(b.buffers["acc_r"]).all()
    # A scalar broadcasts to every pixel, as in NumPy's assignment.
    a.write("sxx", index[:7], 2.5)
    b.write("sxx", index[:7], 2.5, "numba")
    assert np.array_equal(a.buffers["sxx"], b.buffers["sxx"])
    back = np.stack([a.read(n, index) for n in names], axis=-1)
    got = b.read_columns(names, index, "numba")
    assert got.dtype == np.float64 and np.array_equal(back.view(np.uint64), got.view(np.uint64))
    # The compiled passes ran (not the NumPy fall-back), and float16 buffers fall back.
    assert estimator_numba.read_column.signatures and estimator_numba.write_column.signatures
    # ... in the types warm_up compiles: writable arrays (a read-only one is another type,
    # compiled again at its first use, inside a frame).
    for kernel in (estimator_numba.read_column, estimator_numba.write_column):
        arrays = [t for sig in kernel.signatures for t in sig if isinstance(t, numba.types.Array)]
        assert arrays and all(t.mutable for t in arrays)
    half = History.empty(shape, "float16", 1e-3, 1e-4, temporal=True)
    assert not half.compiled_io("numba", index, names)
    assert hist.compiled_io("numba", index, names)


@pytest.mark.parametrize("method", ["as_ccv", "as", "as_ocv"])
@pytest.mark.parametrize("weighted", [True, False])
def test_compiled_history_step_equals_numpy(method, weighted, monkeypatch):
    """The compiled history step (tracked luminance, the online control variate's α
    and EMCM step, Eq. 5–7, float32 stores in place) leaves NumPy's history bit for
    bit: μ, σ², m̄, J and the valid masks, and the α and σ² maps. Estimates with NaN,
    ±inf and values beyond float32 (stored as ±max), huge B (the tracked value's
    bound), weights 0…1 or all 1 (NumPy then skips the product), invalid history and
    J, pixels without samples, and covariances that put α on either bound of D or
    leave its ratio undefined (Σ_yy + ε_α <= 0: α = 1)."""
    import types

    from cvsss.core.mc import estimator_numba
    from cvsss.core.mc.history import H_FIELDS, J_FIELDS, History

    rng = np.random.default_rng(5)
    shape, n = (19, 31), 400
    index = np.sort(rng.choice(shape[0] * shape[1], n, replace=False)).astype(np.int64)
    distant = rng.normal(0, 2, (n, 3))
    distant[:6, 0] = [np.nan, np.inf, -np.inf, 1e39, -1e200, 1e300]
    b = rng.uniform(0, 4, (n, 3))
    b[6:9] = [1e160, 1e308, 0.0]
    weight = rng.uniform(0, 1, n) if weighted else np.ones(n)
    weight[:3] = [0.0, 1.0, 0.5] if weighted else 1.0
    geom = types.SimpleNamespace(
        index=index, gamma=rng.uniform(0, 1, (n, 3)), weight=weight, size=n
    )
    m = rng.integers(0, 5, n).astype(np.int32)
    valid = rng.random(n) < 0.7
    hist = History.empty(shape, "float32", 1e-3, 1e-4)
    for k in H_FIELDS:
        hist.buffers[k][...] = rng.uniform(0, 3, shape)
    hist.buffers["var"].reshape(-1)[index[:4]] = [3e38, 0.0, 1e-30, 7.0]
    for k in J_FIELDS:
        hist.buffers[k][...] = rng.normal(0, 2, shape)
    hist.buffers["syy"][...] = np.abs(hist.buffers["syy"])
    # Σ_yy + ε_α tiny, 0 or negative (α = 1), Σ_xy huge or negative (α past D).
    for k, v in (("syy", [1e-30, 0.0, 3e38, -1e-3]), ("sxy", [3e38, -3e38, 1e-3, -1e-4])):
        hist.buffers[k].reshape(-1)[index[10:14]] = v
    hist.cv_valid = rng.random(shape) < 0.8
    calls = []
    step = estimator_numba.history_step
    monkeypatch.setattr(estimator_numba, "history_step", lambda *a: calls.append(1) or step(*a))
    out = {}
    for name in ("numpy", "numba"):
        params = SSSParams(backend=name, exposure=2.5, eps_alpha=0.0)
        proc = make_processor(method, params)
        h = History.from_arrays(hist.to_arrays())
        with np.errstate(all="ignore"):
            alpha, var = proc._update(h, geom, m, valid, distant, b)
        out[name] = (h, alpha, var)
    assert calls == [1]  # the numba run took the compiled step, the NumPy one did not
    (a, alpha_a, var_a), (c, alpha_c, var_c) = out["numpy"], out["numba"]
    for k in (*H_FIELDS, *J_FIELDS):
        assert c.buffers[k].dtype == np.float32
        assert np.array_equal(a.buffers[k].view(np.uint32), c.buffers[k].view(np.uint32)), k
    assert np.array_equal(a.valid, c.valid) and a.valid.any() and not a.valid.all()
    assert np.array_equal(a.cv_valid, c.cv_valid)
    if method == "as_ocv":  # J moved, and α took values inside D and on its bounds
        assert not np.array_equal(a.buffers["sxx"], hist.buffers["sxx"])
        taken = alpha_a[m > 0]
        assert (taken == 0).any() and ((taken > 0) & (taken < 1)).any() and (taken > 1).any()
    assert np.array_equal(alpha_a.view(np.uint64), alpha_c.view(np.uint64))
    assert np.array_equal(var_a.view(np.uint64), var_c.view(np.uint64))
    assert np.isfinite(a.buffers["mu"]).all() and (a.buffers["var"] >= 0).all()


def test_total_ms_covers_the_composite(monkeypatch):
    """``total_ms`` is the whole ``process()`` call: the composite and the maps built
    after the sampling included (a composite slowed by 50 ms shows in it)."""
    import time

    from cvsss.core import result

    slow = result.composite

    def composite(*args, **kwargs):
        time.sleep(0.05)
        return slow(*args, **kwargs)

    monkeypatch.setattr(result, "composite", composite)
    for name in ("as_ccv", "separable"):
        res = make_processor(name, SSSParams(backend="numba")).process(FRAMES[0])
        assert res.total_ms >= 50.0 + res.pass_ms + res.update_ms, name


@pytest.mark.parametrize("hidden", [1.0, 0.5])
@pytest.mark.parametrize("inverse", ["exact", "fast"])
@pytest.mark.parametrize("distance", ["surface", "cycles", "planar"])
def test_estimate_with_variance_fast_inverse_and_a_chromatic_profile(inverse, distance, hidden):
    """The variance path (temporal methods), both Burley samplers, per-channel profiles,
    the hidden-light fill of samples that land off the surface."""
    frame = scene_frame("flash", 2, 160, 90)
    profile = frame_profile(frame, SSSParams(burley_inverse=inverse))
    assert profile.chromatic()[1:].any()  # per-channel weights are exercised
    geom = prepare(frame, profile, surface_distance=distance != "planar")
    counts = (np.arange(geom.size) % 37).astype(np.int32)  # includes m = 0 and m = 1
    kw = dict(
        frame=2,
        seed=7,
        depth_slope=2.0,
        variance=True,
        disk=distance == "cycles",
        hidden_light=hidden,
    )
    a = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    b = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, backend="numba", **kw)
    assert (a.samples, a.fallback) == (b.samples, b.fallback)
    assert 0 < a.fallback < a.samples
    scale = np.abs(a.distant).max()
    np.testing.assert_allclose(b.distant, a.distant, rtol=0, atol=RTOL * scale)
    # inf (one sample) and 0 (no sample) exactly where NumPy has them.
    assert np.array_equal(np.isinf(a.variance), np.isinf(b.variance))
    assert np.array_equal(a.variance == 0, b.variance == 0)
    fin = np.isfinite(a.variance)
    # Σy² − (Σy)²/m cancels: relative error ~1e-4 of the spread, not of the value.
    np.testing.assert_allclose(b.variance[fin], a.variance[fin], rtol=1e-3, atol=1e-12)


def _object_frames():
    """Frames whose objects share a material and touch: the synthetic scene with its slab
    cut into two objects, and a tilted plane seen by an ortho camera, cut in two."""
    frame = scene_frame("flash", 2, 160, 90)
    objects = frame.objects.copy()
    objects[(frame.material == 2) & (np.arange(160)[None, :] > 110)] = 9
    plane = flat_plane(48, 32, d=(0.02, 0.01, 0.005), depth=2.0)
    yy, xx = np.mgrid[0:32, 0:48]
    tilted = (2.0 + 0.05 * xx + 0.002 * yy * yy).astype(np.float32)
    ortho = Camera(**{**dataclasses.asdict(plane.camera), "type": "ORTHO", "ortho_scale": 1.5})
    light = (1.2 + np.sin(0.4 * xx + 0.3 * yy))[..., None] * np.array([1.0, 0.8, 0.6])
    return {
        "perspective": dataclasses.replace(frame, objects=objects),
        "ortho": dataclasses.replace(
            plane,
            camera=ortho,
            depth=tilted,
            lighting=light.astype(np.float32),
            objects=np.where(xx < 20, 4, 5).astype(np.int32),
        ),
    }


@pytest.mark.parametrize("hidden", [1.0, 0.5])
@pytest.mark.parametrize("distance", ["surface", "cycles", "planar"])
@pytest.mark.parametrize("case", ["perspective", "ortho"])
def test_objects_and_contacts_take_the_same_samples(case, distance, hidden):
    """The Object Index pass on both backends: samples on another object rejected, those
    touching the centre's tangent plane taken unlit (SSSParams.contact), with the
    hidden-light fill beside them."""
    frame = _object_frames()[case]
    profile = frame_profile(frame, SSSParams())
    geom = prepare(frame, profile, surface_distance=distance != "planar")
    counts = (np.arange(geom.size) % 29).astype(np.int32)
    kw = dict(frame=2, seed=5, depth_slope=2.0, disk=distance == "cycles", hidden_light=hidden)
    out = {}
    for contact in (0.0, 0.5):
        a = estimate_distant(
            geom, frame.lighting, frame.depth, profile, counts, contact=contact, **kw
        )
        b = estimate_distant(
            geom,
            frame.lighting,
            frame.depth,
            profile,
            counts,
            contact=contact,
            backend="numba",
            **kw,
        )
        assert (a.samples, a.fallback) == (b.samples, b.fallback)
        scale = np.abs(a.distant).max()
        np.testing.assert_allclose(b.distant, a.distant, rtol=0, atol=RTOL * scale)
        out[contact] = a
    # Some samples touched the other object (taken, not fallen back), changing the estimate.
    assert out[0.5].fallback < out[0.0].fallback
    assert not np.array_equal(out[0.5].distant, out[0.0].distant)


@pytest.mark.parametrize("distance", ["surface", "cycles", "planar"])
@pytest.mark.parametrize("d", [(0.02, 0.01, 0.005), (0.01, 0.01, 0.01)], ids=["rgb", "grey"])
def test_orthographic_camera_and_constant_lighting(d, distance):
    """Ortho camera, one profile for all channels (w_c = γ_c) or three; constant B gives
    L = B exactly (the centre control), any m (Cycles' kernel: to float rounding)."""
    plane = flat_plane(48, 32, d=d, depth=2.0)
    ortho = Camera(**{**dataclasses.asdict(plane.camera), "type": "ORTHO", "ortho_scale": 1.5})
    yy, xx = np.mgrid[0:32, 0:48]
    light = np.stack([np.sin(0.3 * xx), np.cos(0.2 * yy), 0.01 * xx * yy], -1) + 1.5
    plane = dataclasses.replace(plane, camera=ortho, lighting=light.astype(np.float32))
    profile = frame_profile(plane, SSSParams())
    assert bool(profile.chromatic()[1]) == (d[0] != d[2])
    geom = prepare(plane, profile, surface_distance=distance != "planar")
    assert (geom.surface is not None and geom.surface.ortho) == (distance != "planar")
    counts = np.full(geom.size, 24)
    kw = dict(frame=1, seed=3, depth_slope=2.0, disk=distance == "cycles")
    a = estimate_distant(geom, plane.lighting, plane.depth, profile, counts, **kw)
    b = estimate_distant(geom, plane.lighting, plane.depth, profile, counts, backend="numba", **kw)
    np.testing.assert_allclose(b.distant, a.distant, rtol=0, atol=RTOL * np.abs(a.distant).max())
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


def test_thread_count_does_not_change_the_result(monkeypatch):
    """Pixels are independent: one thread and all threads give the same bits."""
    frame = scene_frame("flash", 3, 256, 144)
    profile = frame_profile(frame, SSSParams())
    geom = prepare(frame, profile, surface_distance=True)
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
    from cvsss.core.mc import estimator_numba

    assert counts.sum() >= estimator_numba.PARALLEL_MIN_SAMPLES
    original, chosen = estimator_numba.kernel, []

    def spy(samples, pixels=0):
        chosen.append(original(samples, pixels))
        return chosen[-1]

    monkeypatch.setattr(estimator_numba, "PARALLEL_MIN_SAMPLES", 1 << 62)
    monkeypatch.setattr(estimator_numba, "kernel", spy)
    serial = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    assert chosen == [estimator_numba.pixel_sums_serial]
    assert np.array_equal(serial.distant, many.distant)
    assert np.array_equal(serial.variance, many.variance)


def test_tasks_dealt_over_any_number_of_threads_give_the_same_bits(monkeypatch):
    """The parallel build deals its tasks out over ``threads`` (iteration t runs task
    (t % per)·threads + t // per): every task runs once, whatever the count, also where
    it does not divide the tasks or exceeds them. Every pixel active, so the kernel
    writes each row of an uninitialised estimate: a task left out shows as garbage."""
    from cvsss.core.mc import estimator_numba as en

    frame = scene_frame("flash", 3, 160, 90)
    profile = frame_profile(frame, SSSParams())
    geom = prepare(frame, profile, surface_distance=True)
    counts = np.random.default_rng(3).integers(1, 40, geom.size)
    tasks = -(-geom.size // en.PIXELS_PER_TASK)
    assert tasks % 3 and tasks % 7 and tasks < 1000, tasks
    kw = dict(frame=3, seed=1, depth_slope=2.0, variance=True, backend="numba")
    runs = {}
    for threads in (1, 2, 3, 7, 1000):
        monkeypatch.setattr(
            en, "kernel", lambda n, p=0, k=threads: lambda *a: en.pixel_sums(*a[:-1], k)
        )
        runs[threads] = estimate_distant(geom, frame.lighting, frame.depth, profile, counts, **kw)
    for threads, run in runs.items():
        assert np.array_equal(run.distant, runs[1].distant), threads
        assert np.array_equal(run.variance, runs[1].variance), threads
        assert run.fallback == runs[1].fallback, threads


def test_the_kernel_build_follows_the_work_of_pixels_and_samples():
    """Threads for a call's work, counting each pixel as PIXEL_SAMPLES samples."""
    from cvsss.core.mc import estimator_numba as en

    top = en.PARALLEL_MIN_SAMPLES
    assert en.kernel(top) is en.pixel_sums
    assert en.kernel(top - 1) is en.pixel_sums_serial
    # Many pixels at one sample each: the pixels' own cost makes it worth the threads.
    pixels = top // (en.PIXEL_SAMPLES + 1) + 1
    assert en.kernel(pixels, pixels) is en.pixel_sums
    assert en.kernel(pixels) is en.pixel_sums_serial
    # A 32x32 tile at 16 spp stays serial.
    assert en.kernel(16 * 1024, 1024) is en.pixel_sums_serial


def test_other_profiles_run_on_numpy_with_the_numba_backend():
    """The kernel implements Burley; another profile is computed by the NumPy path, not refused."""
    frame = flat_plane(32, 24)
    burley = frame_profile(frame, SSSParams())
    assert isinstance(burley, BurleyProfile)
    geom = prepare(frame, burley)
    counts = np.full(geom.size, 8)
    kw = dict(frame=1, seed=0, depth_slope=2.0)

    class Other(BurleyProfile):  # not the Burley class itself: same numbers, NumPy path
        pass

    other = Other(burley.d)
    a = estimate_distant(geom, frame.lighting, frame.depth, other, counts, backend="numba", **kw)
    b = estimate_distant(geom, frame.lighting, frame.depth, burley, counts, backend="numpy", **kw)
    assert np.array_equal(a.distant, b.distant)  # bit-identical: it is the NumPy path


def test_backend_parameter_is_validated():
    assert SSSParams().backend == "auto"
    with pytest.raises(ParameterError, match="backend must be one of auto, numpy, numba"):
        SSSParams(backend="cuda")
    with pytest.raises(ValueError, match="backend must be one of"):
        backend.resolve("cuda")


_NO_NUMBA = textwrap.dedent(
    """
    import json, logging, sys

    class Refuse:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in ("numba", "llvmlite"):
                raise ImportError(f"{name} is not installed")
            return None

    sys.meta_path.insert(0, Refuse())
    records = []
    handler = logging.Handler()
    handler.emit = lambda r: records.append((r.levelname, r.getMessage()))
    logging.getLogger("cvsss").addHandler(handler)
    logging.getLogger("cvsss").setLevel(logging.INFO)

    import numpy as np
    from cvsss.core.methods import make_processor
    from cvsss.core.mc import backend
    from cvsss.core.params import SSSParams
    from cvsss.core.synthetic import scene_frame

    res = make_processor("as_ccv", SSSParams(backend="numba")).process(scene_frame("flash", 1, 64, 36))
    out = {
        "auto": backend.resolve("auto"),
        "describe": backend.describe("auto"),
        "numba_loaded": "numba" in sys.modules,
        "samples": int(res.samples),
        "finite": bool(np.isfinite(res.composite).all()),
        "log": records,
    }
    print(json.dumps(out))
    """
)


def test_clean_fallback_without_numba():
    """Where numba cannot be imported (no wheel for the platform) NumPy runs and the log says so."""
    env = {**os.environ, "PYTHONHASHSEED": "0"}
    proc = subprocess.run(
        [sys.executable, "-c", _NO_NUMBA], capture_output=True, text=True, env=env, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["auto"] == "numpy"
    assert out["numba_loaded"] is False
    assert out["samples"] > 0 and out["finite"]
    assert out["describe"].startswith("NumPy (numba unavailable (ImportError")
    # Asked for numba, got NumPy: a warning that says why; "auto" just informs.
    assert [
        lvl
        for lvl, msg in out["log"]
        if msg.startswith("cvsss: Monte Carlo backend numpy (asked numba")
    ] == ["WARNING"]
    assert any("NumPy fallback" in msg for _, msg in out["log"])
    assert any(
        lvl == "INFO" and msg.startswith("cvsss: Monte Carlo backend numpy (asked auto")
        for lvl, msg in out["log"]
    )


def test_cache_dir_is_per_user():
    path = backend.cache_dir()
    assert path.parts[-2:] == ("cvsss", "numba")
    if sys.platform.startswith("linux"):
        base = os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache")
        assert str(path).startswith(base)


def test_compiled_kernel_is_cached_on_disk():
    """After the first compile, a fresh process loads the kernel from numba's disk cache."""
    code = textwrap.dedent(
        """
        import json
        from cvsss.core.mc import backend, estimator_numba
        seconds = backend.warm_up()
        kernels = (estimator_numba.pixel_sums, estimator_numba.pixel_sums_serial)
        print(json.dumps({"s": seconds,
                          "hits": sum(sum(k.stats.cache_hits.values()) for k in kernels),
                          "misses": sum(sum(k.stats.cache_misses.values()) for k in kernels)}))
        """
    )
    backend.warm_up()  # compiles (and writes the cache) if nothing did yet
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["hits"] >= 2 and out["misses"] == 0


def test_a_full_warm_up_stamps_the_cache_for_this_source(tmp_path, monkeypatch):
    """``kernels_cached()``: the stamp a warm-up of every kernel leaves in the cache folder,
    held against the kernels' source file (as numba's own staleness test), Python and
    numba; anything else, or no stamp, is not cached."""
    backend.warm_up()
    assert backend.kernels_cached()
    stamp = json.loads((backend.cache_location() / backend.STAMP).read_text())
    source = (Path(backend.__file__).parent / "estimator_numba.py").stat()
    assert stamp == {
        "source": [source.st_mtime_ns, source.st_size],
        "python": sys.version,
        "numba": numba.__version__,
    }
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    assert not backend.kernels_cached()  # nothing there
    for other, cached in [
        (stamp, True),
        ({**stamp, "source": [source.st_mtime_ns + 1, source.st_size]}, False),
        ({**stamp, "numba": "0.0.1"}, False),
        ({**stamp, "python": "2.7"}, False),
    ]:
        (tmp_path / backend.STAMP).write_text(json.dumps(other))
        assert backend.kernels_cached() is cached
    (tmp_path / backend.STAMP).write_text("{")
    assert not backend.kernels_cached()


def test_kernels_cached_does_not_import_numba():
    code = (
        "import sys; from cvsss.core.mc import backend; backend.kernels_cached(); "
        "print('numba' in sys.modules)"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split() == ["False"]


@pytest.mark.parametrize(
    "pixels, build", [(1920 * 1080, "pixel_sums"), (48 * 32, "pixel_sums_serial")]
)
def test_warm_up_for_a_frame_size_prepares_the_build_it_takes(pixels, build):
    """``warm_up(pixels)`` (what a job prepares before its first frame) loads or
    compiles the sampling kernel's build that frames of that size take, not the other."""
    code = textwrap.dedent(
        f"""
        import json
        from cvsss.core.mc import backend, estimator_numba
        backend.warm_up({pixels})
        print(json.dumps({{name: len(getattr(estimator_numba, name).overloads)
                          for name in ("pixel_sums", "pixel_sums_serial")}}))
        """
    )
    backend.warm_up()  # both builds in the disk cache, so the fresh process only loads
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    loaded = json.loads(proc.stdout.strip().splitlines()[-1])
    assert loaded == {name: int(name == build) for name in loaded}
    from cvsss.core.mc import estimator_numba

    assert estimator_numba.kernel(0, pixels) is getattr(estimator_numba, build)


def test_surface_keys_tell_every_slot_and_object_apart_in_float32():
    """The kernel's texel keys ``slot + K·object``: equal exactly for the same material of
    the same object, the object recovered by floor(key/K), exact in float32 even with
    many slots and the largest object numbers (renumbered by rank when they would not
    fit)."""
    from cvsss.core.mc.estimator_numba import surface_keys

    rng = np.random.default_rng(1)
    slots = rng.integers(0, 700, 5000).astype(np.int32)  # K = 1024
    objects = rng.choice([0, 3, 17, 32767], 5000).astype(np.int32)  # 32768·1024 > 2**24
    keys, inv_k = surface_keys(slots, objects)
    k32 = keys.astype(np.float32)
    assert np.array_equal(k32.astype(np.int64), keys)  # exact in float32
    pairs = slots.astype(np.int64) * 100_000 + objects
    same_key = k32[:, None] == k32[None, :200]
    assert np.array_equal(same_key, pairs[:, None] == pairs[None, :200])
    obj = np.floor(k32 * inv_k)
    assert np.array_equal(obj[:, None] == obj[None, :200], objects[:, None] == objects[None, :200])
    plain, one = surface_keys(slots, None)
    assert np.array_equal(plain, slots) and one == 1.0


def test_tile_order_visits_every_pixel_once_tile_by_tile():
    """The kernel's visiting order (speed only): a permutation of the active pixels,
    tile after tile of TILE×TILE pixels, row-major inside a tile, at any image width
    (tile keys past 16 bits included)."""
    from cvsss.core.mc.estimator_numba import TILE, tile_order

    rng = np.random.default_rng(2)
    # 70 tiles (16-bit keys); 301 × 220 = 66220 tiles (wider keys), sparse pixels of it.
    for w, h, n in ((100, 70, None), (300 * TILE + 5, 220 * TILE, 50_000)):
        assert (-(-w // TILE)) * (-(-h // TILE)) > (1 << 16) or n is None
        if n is None:
            flat = np.flatnonzero(rng.random(w * h) < 0.3)
        else:
            flat = np.unique(rng.integers(0, w * h, n))
        y, x = np.divmod(flat, w)
        order = tile_order(x, y, w)
        assert np.array_equal(np.sort(order), np.arange(flat.size))
        tile = (y // TILE) * (-(-w // TILE)) + x // TILE
        assert np.all(np.diff(tile[order]) >= 0)
        same = np.diff(tile[order]) == 0
        assert np.all(np.diff(flat[order])[same] > 0)


def test_kernel_results_do_not_depend_on_the_visiting_order(monkeypatch):
    """Each pixel's sums are its own: visiting the pixels in reverse gives the same bits."""
    from cvsss.core.mc import estimator_numba as en

    frame = scene_frame("flash", 2, 48, 32)
    profile = frame_profile(frame, SSSParams())
    geom = prepare(frame, profile, surface_distance=True)
    counts = np.random.default_rng(3).integers(1, 40, geom.size)
    active = np.flatnonzero(geom.gamma_sum > 0)

    def run():
        args = (frame.lighting, frame.depth, 2, 0, 2.0, True, True, 0.75, 0.5)
        distant = np.zeros((geom.size, 3))
        # A Geometry of its own: a Geometry keeps the order of its pixels (its memos).
        fresh = prepare(frame, profile, surface_distance=True)
        var, fallback = en.run_kernel(fresh, profile, counts, active, *args, distant=distant)
        return distant, var, fallback

    tiled = run()
    monkeypatch.setattr(en, "tile_order", lambda x, y, w, a: np.arange(a.size)[::-1].copy())
    reverse = run()
    assert np.array_equal(tiled[0], reverse[0])
    # It added the pixels' means (a pixel whose samples were all rejected adds 0).
    assert np.count_nonzero(np.any(tiled[0][active] != 0.0, axis=1)) > active.size // 2
    assert np.array_equal(tiled[1], reverse[1])
    assert tiled[2] == reverse[2]


def test_kernel_started_rows_equal_numpys_start_plus_the_means():
    """With ``start`` the kernel sets each row to γ·B(p) plus the pixel's mean itself:
    from rows of NaN it gives the bits of NumPy's γ·B with the means added; a Geometry
    reused with other lighting (its texels relit in place) gives the bits of a fresh one.
    Only a reused Geometry keeps the texels (32 bytes per pixel) between calls."""
    from cvsss.core.geometry import GeometryCache
    from cvsss.core.mc import estimator_numba as en

    frames = [scene_frame("flash", n, 48, 32) for n in (2, 3, 4)]
    assert not np.array_equal(frames[1].lighting, frames[2].lighting)
    profile = frame_profile(frames[0], SSSParams())
    cache = GeometryCache()
    size = prepare(frames[0], profile, surface_distance=True).size
    counts = np.random.default_rng(5).integers(1, 40, size)
    active = np.arange(size)

    def run(g, frame, start, variance):
        args = (frame.lighting, frame.depth, frame.number, 0, 2.0, variance, True, 0.75, 0.5)
        if start:
            distant = np.full((g.size, 3), np.nan)
        else:
            distant = g.gamma * g.at(frame.lighting).astype(np.float64)
        var, fb = en.run_kernel(g, profile, counts, active, *args, distant=distant, start=start)
        return distant, var, fb

    for frame in frames:  # the third frame relights the second one's texels
        # The cache hands on the first frame's Geometry (with this frame's direct light).
        geom = cache.prepare(frame, profile, surface_distance=True)
        assert geom.reused == (frame is not frames[0])
        for variance in (False, True):
            fresh = prepare(frame, profile, surface_distance=True)
            want = run(fresh, frame, False, variance)
            got = run(geom, frame, True, variance)
            assert np.isfinite(want[0]).all()
            assert np.array_equal(got[0], want[0])
            assert got[2] == want[2]
            if variance:
                assert np.array_equal(got[1], want[1])
            else:
                assert got[1] is None and want[1] is None
        assert (en._TEXELS in geom.memos) == geom.reused
        assert en._TEXELS not in fresh.memos and not fresh.reused
    assert cache.hits == 2
    # Rows of pixels that take no samples would stay unset: refused.
    with pytest.raises(ValueError, match="every pixel"):
        args = (frames[0].lighting, frames[0].depth, 2, 0, 2.0, False, True, 0.75, 0.5)
        distant = np.empty((size, 3))
        en.run_kernel(geom, profile, counts, active[1:], *args, distant=distant, start=True)

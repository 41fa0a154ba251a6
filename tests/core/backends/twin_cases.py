"""Cases for the twin table's equivalence tests (test_twins.py): every twin of
:data:`cvsss.core.backends.twins.TWINS` has cases here, each built once per side.

A case is ``Case(id, build, check)``: ``build(backend)`` returns fresh ``(args,
kwargs)`` for a call of the twin whose backend is ``backend`` (a twin may write
into its arguments, so each side gets its own); ``check(a, b, args_a, args_b)``
compares what the NumPy side (a) and the compiled side (b) returned and wrote.

Expected agreement (the reason in each check): the same bits, except where a
library ``exp``/``log`` differs by an ulp (NumPy's against libm's) and, in the
sampling step, float32 rounding: ``RTOL`` of the image's largest value.
"""

from __future__ import annotations

import dataclasses
import types
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from cvsss.core.camera import Camera
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import mirror_slots as mirror_of
from cvsss.core.mc.history import H_FIELDS, J_FIELDS, T_FIELDS, History
from cvsss.core.params import SeparableParams, SSSParams
from cvsss.core.profiles.burley import BurleyProfile
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.separable.apply import _pixels, _stack
from cvsss.core.separable.kernels import build_kernels
from cvsss.core.synthetic import flat_plane, scene_frame
from cvsss.core.tiling import crop_frame

#: Tolerance of the sampling step: ~32 float32 ulps of the image's largest value (the
#: frames below measure ≤ 1.6e-7).
RTOL = 4e-6


@dataclass
class Case:
    id: str
    build: Callable[[str], tuple[tuple, dict]]
    check: Callable[[Any, Any, tuple, tuple], None]


def same_bits(x, y, what: str = "") -> None:
    x, y = np.asarray(x), np.asarray(y)
    assert x.dtype == y.dtype and x.shape == y.shape, what
    assert np.array_equal(x.view(np.uint8), y.view(np.uint8)), what


def avx512() -> bool:
    """NumPy has its own AVX-512 ``exp`` here (an ulp from libm's, which numba calls)."""
    return bool(np.core._multiarray_umath.__cpu_features__.get("AVX512F"))


# -- frames -------------------------------------------------------------------------
def surface_frames() -> dict:
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


def two_materials():
    """The tilted plane with a hole, a stripe without subsurface (finite depth) and a
    second subsurface material: reads that land on another material get no weight."""
    plane = surface_frames()["perspective-hole"]
    mat = plane.material.copy()
    mat[:, 30:33] = 0
    mat[20:, :20] = 2
    spec = plane.materials[1]
    other = dataclasses.replace(spec, slot=2, name="other", d=(0.03, 0.02, 0.01))
    return dataclasses.replace(plane, material=mat, materials={1: spec, 2: other})


def object_frames() -> dict:
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


# -- sampling -------------------------------------------------------------------------
def _sampling(frame, distance: str, params=None, *, variance=False, hidden=1.0,
              contact=0.0, period=37, start=False, mirror=False):  # fmt: skip
    profile = frame_profile(frame, params or SSSParams())
    geom = geometry_of(frame, profile, surface_distance=distance != "planar")
    counts = (np.arange(geom.size) % period).astype(np.int64)  # m = 0 and m = 1 included
    if start:
        counts = counts % (period - 1) + 1  # every pixel active
    active = np.flatnonzero((counts > 0) & (geom.gamma_sum > 0))
    assert not start or active.size == geom.size
    # True: every slot reads the mirror image; "some": every other slot (as where
    # Random Walk slots do not, core.mc.estimator.mirror_slots).
    mirror_slots = (
        np.arange(profile.n_slots) % 2 == 1 if mirror == "some" else mirror_of(profile, mirror)
    )

    def build(backend):
        distant = (
            np.full((geom.size, 3), np.nan)
            if start
            else geom.gamma * geom.at(frame.lighting).astype(np.float64)
        )
        kwargs = dict(
            frame=int(frame.number), seed=7, depth_slope=2.0, variance=variance,
            disk=distance == "cycles", hidden_light=hidden, contact=contact,
            hidden_mirror=mirror_slots, chunk_samples=1 << 16, distant=distant, start=start,
            samples=int(counts[active].sum()), backend=backend,
        )  # fmt: skip
        return (geom, profile, counts, active, frame.lighting, frame.depth), kwargs

    def check(a, b, args_a, args_b):
        (var_a, fb_a), (var_b, fb_b) = a, b
        assert fb_a == fb_b and fb_a > 0
        da, db = args_a[-1]["distant"], args_b[-1]["distant"]
        assert np.isfinite(da).all()
        np.testing.assert_allclose(db, da, rtol=0, atol=RTOL * np.abs(da).max())
        assert (var_a is None) == (var_b is None) == (not variance)
        if variance:
            # Σy² − (Σy)²/m cancels later: the sums themselves agree to float32 rounding.
            np.testing.assert_allclose(var_b, var_a, rtol=1e-4, atol=1e-9)

    return build, check


def sampling_cases() -> list[Case]:
    cases = []
    frame = scene_frame("flash", 2, 160, 90)
    for distance in ("surface", "cycles", "planar"):
        for inverse in ("exact", "fast"):
            params = SSSParams(burley_inverse=inverse)
            build, check = _sampling(frame, distance, params, variance=True, hidden=0.5)
            cases.append(Case(f"{distance}-{inverse}-variance-hidden", build, check))
    for distance in ("surface", "cycles", "planar"):
        for hidden in (1.0, 0.5):
            build, check = _sampling(frame, distance, variance=True, hidden=hidden, mirror=True)
            cases.append(Case(f"{distance}-mirror-hidden{hidden:g}", build, check))
        build, check = _sampling(frame, distance, variance=True, hidden=0.5, mirror="some")
        cases.append(Case(f"{distance}-mirror-some-slots", build, check))
        # A crop: the mirror image's pixel in the crop's coordinates.
        build, check = _sampling(surface_frames()["crop"], distance, mirror=True)
        cases.append(Case(f"{distance}-mirror-crop", build, check))
    for case, objframe in object_frames().items():
        for distance in ("surface", "cycles", "planar"):
            build, check = _sampling(objframe, distance, contact=0.5, hidden=0.5, period=29)
            cases.append(Case(f"objects-{case}-{distance}", build, check))
            build, check = _sampling(
                objframe, distance, contact=0.5, hidden=0.5, period=29, mirror=True
            )
            cases.append(Case(f"objects-{case}-{distance}-mirror", build, check))
    build, check = _sampling(frame, "surface", start=True, variance=True)
    cases.append(Case("start-rows", build, check))
    return cases


# -- the geometry ------------------------------------------------------------------------
def surface_cases() -> list[Case]:
    def make(name):
        def build(backend):
            return (surface_frames()[name],), {"backend": backend}

        def check(a, b, *_):
            assert a.ortho == b.ortho == (name == "ortho")
            same_bits(a.area, b.area, "area")
            same_bits(a.normal, b.normal, "normal")
            assert np.isfinite(a.normal).all() and (a.area > 0).any()

        return Case(name, build, check)

    return [make(n) for n in ("perspective", "crop", "ortho", "perspective-hole")]


def float_image_cases() -> list[Case]:
    frame = scene_frame("flash", 3, 48, 32)
    geom = geometry_of(frame, frame_profile(frame, SSSParams()))
    rng = np.random.default_rng(5)
    values = rng.normal(0, 1e39, (geom.size, 3))
    values[:3] = [[np.nan, np.inf, -np.inf], [0.5, -0.5, 1e-50], [1, 2, 3]]
    cases = []
    for name, v, fill in (
        ("rgb", values, 0.0),
        ("one-channel", values[:, 1].copy(), 0.0),
        ("float32-fill", (values[:, 0] / 1e2).astype(np.float32), -1.0),
    ):

        def build(backend, v=v, fill=fill):
            return (geom.shape, geom.index, v.copy(), fill), {"backend": backend}

        def check(a, b, *_):
            assert a.dtype == b.dtype == np.float32
            assert np.array_equal(a, b, equal_nan=True)

        cases.append(Case(name, build, check))
    return cases


def row_mean_cases() -> list[Case]:
    def make(name, size, special):
        def build(backend):
            rng = np.random.default_rng(size)
            rows = rng.lognormal(0, 3, (size, 3))  # a wide range: the order of the sum shows
            rows[::7, 1] *= -1.0
            if special:
                rows[5, 0], rows[9, 2] = np.inf, np.nan
            return (rows,), {"backend": backend}

        def check(a, b, *_):
            assert a.shape == b.shape == (3,)
            same_bits(a, b, name)
            assert np.isnan(a[2]) if special else np.isfinite(a).all()

        return Case(name, build, check)

    return [
        make("one-row", 1, False),
        make("1080p-rows", 915_076, False),
        make("inf-nan", 64, True),
    ]


def estimate_variance_cases() -> list[Case]:
    def make(name, size):
        def build(backend):
            rng = np.random.default_rng(size)
            counts = rng.integers(0, 6, size)
            gamma_sum = rng.random(size) * (rng.random(size) < 0.9)  # some without γ
            active = np.flatnonzero((counts > 0) & (gamma_sum > 0))
            y = rng.lognormal(0, 2, (active.size, 4))
            sums = np.stack([y[:, 0] * counts[active], y[:, 1] * counts[active] + y[:, 2]], 1)
            sums[::13, 1] = sums[::13, 0] ** 2 / counts[active][::13]  # exactly no spread
            sums[::17, 1] = 0.0  # a negative spread: clipped to 0
            sums[::19, 0] = np.nan
            return (sums, active, counts, gamma_sum), {"backend": backend}

        def check(a, b, args_a, _):
            counts = args_a[0][2]
            assert a.dtype == b.dtype == np.float64 and a.shape == counts.shape
            same_bits(a, b, name)
            assert (a == 0).any() and np.isinf(a).any() and np.isnan(a).any()
            assert (a[np.isfinite(a)] >= 0).all()

        return Case(name, build, check)

    return [make("small", 200), make("1080p", 915_076)]


def burley_region_cases() -> list[Case]:
    rng = np.random.default_rng(3)
    d = np.array([[0, 0, 0], [0.01, 0.005, 0.002], [0.02, 0.0, 0.004], [1e-9, 5.0, 0.3]])
    profile = BurleyProfile(d)
    mat = rng.integers(1, 4, 5000)
    r0 = rng.random(5000) * 0.05
    r0[:4] = 0.0
    r0[4:8] = 1e300  # beyond the truncation radius

    def build(backend):
        return (profile, r0.copy(), mat.copy()), {"backend": backend}

    def check(a, b, *_):
        for name in ("gamma", "weight_scale", "lo", "hi"):
            x, y = getattr(a, name), getattr(b, name)
            assert x.dtype == y.dtype == np.float64 and x.shape == y.shape == (5000, 3), name
            if avx512():  # γ, a difference of exponentials, carries their ulp
                np.testing.assert_allclose(y, x, rtol=1e-14, atol=0, err_msg=name)
            else:
                assert np.array_equal(x, y), name
        assert (a.gamma[:, 1][mat == 2] == 0).all()  # a channel without scattering
        assert (a.gamma > 0).any() and (a.gamma <= 1).all()

    return [Case("mixed-slots", build, check)]


# -- SPVG -------------------------------------------------------------------------------
def _spvg_inputs():
    rng = np.random.default_rng(7)
    n = 2000
    var = rng.lognormal(-9, 3, n)
    var[:6] = [np.nan, np.inf, 0.0, 1e300, -1.0, 1e-300]
    mbar = rng.uniform(1, 80, n)
    mbar[6:10] = [np.nan, np.inf, -np.inf, 0.0]
    valid = rng.random(n) < 0.7
    gmax = rng.uniform(0, 0.05, n)
    return var, mbar, valid, gmax


def spvg_counts_cases() -> list[Case]:
    def make(name, **params):
        def build(backend):
            var, mbar, valid, gmax = _spvg_inputs()
            return (var, mbar, valid, gmax, SSSParams(backend=backend, **params)), {}

        def check(a, b, *_):
            same_bits(a, b, "counts")
            assert (a == 0).any() and (a > 0).any()

        return Case(name, build, check)

    return [make("defaults"), make("wide", beta_min=1, beta_max=4096, kappa=1.0, eta=0.05)]


def spvg_update_cases() -> list[Case]:
    def build(backend):
        rng = np.random.default_rng(9)
        var, mbar, valid, _ = _spvg_inputs()
        n = var.size
        mu = rng.normal(0, 2, n)
        mu[:3] = [np.nan, np.inf, -np.inf]
        tracked = rng.normal(0, 3, n)
        tracked[3:6] = [1e200, -1e200, np.nan]
        counts = rng.integers(0, 64, n)
        return (mu, var, mbar, valid, tracked, counts, SSSParams(backend=backend)), {}

    def check(a, b, *_):
        for name, x, y in zip(("mu", "var", "mbar", "valid"), a, b):
            same_bits(x, y, name)
        assert np.isfinite(a[0]).all() and (a[1] >= 0).all()

    return [Case("extremes", build, check)]


# -- the history --------------------------------------------------------------------------
def history_step_cases() -> list[Case]:
    def make(method, weighted):
        cv = {"as": "none", "as_ccv": "constant", "as_ocv": "online"}[method]

        def build(backend):
            rng = np.random.default_rng(5)
            shape, n = (19, 31), 400
            index = np.sort(rng.choice(shape[0] * shape[1], n, replace=False)).astype(np.int64)
            distant = rng.normal(0, 2, (n, 3))
            distant[:6, 0] = [np.nan, np.inf, -np.inf, 1e39, -1e200, 1e300]
            b = rng.uniform(0, 4, (n, 3))
            b[6:9] = [1e160, 1e308, 0.0]  # huge B: the tracked value's bound
            weight = rng.uniform(0, 1, n) if weighted else np.ones(n)
            if weighted:
                weight[:3] = [0.0, 1.0, 0.5]
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
            params = SSSParams(backend=backend, exposure=2.5, eps_alpha=0.0)
            return (hist, geom, m, valid, distant, b, cv, params), {}

        def check(a, b, args_a, args_b):
            ha, hb = args_a[0][0], args_b[0][0]
            original = build("numpy")[0][0]
            for k in (*H_FIELDS, *J_FIELDS):
                same_bits(ha.buffers[k], hb.buffers[k], k)
            assert np.array_equal(ha.valid, hb.valid) and ha.valid.any() and not ha.valid.all()
            assert np.array_equal(ha.cv_valid, hb.cv_valid)
            (alpha_a, var_a), (alpha_b, var_b) = a, b
            same_bits(alpha_a, alpha_b, "alpha")
            same_bits(var_a, var_b, "variance")
            if cv == "online":  # J moved, and α took values inside D and on its bounds
                assert not np.array_equal(ha.buffers["sxx"], original.buffers["sxx"])
                taken = alpha_a[args_a[0][2] > 0]
                assert (taken == 0).any() and ((taken > 0) & (taken < 1)).any()
                assert (taken > 1).any()
            assert np.isfinite(ha.buffers["mu"]).all() and (ha.buffers["var"] >= 0).all()

        return Case(f"{method}-{'weighted' if weighted else 'unweighted'}", build, check)

    return [make(m, w) for m in ("as", "as_ccv", "as_ocv") for w in (True, False)]


_COLUMNS = ("acc_r", "var", "sxy")


def _columns_history(scaled: bool) -> History:
    hist = History.empty((19, 29), "float32", 1e-3, 1e-4, temporal=True)
    if scaled:  # the float16 scales, forced on float32 buffers
        hist.cov_scale, hist.var_scale = 1e3, 1e4
    return hist


def _columns_values() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(5)
    index = rng.choice(19 * 29, 300, replace=False).astype(np.int64)
    values = rng.normal(0, 1e3, (300, 3)) * rng.choice([1e-40, 1.0, 1e36], (300, 3))
    values[:6, 0] = [np.nan, np.inf, -np.inf, 4e38, -4e38, -0.0]
    values[6:9, 1] = [np.nan, 1e35, -1e35]  # past float32 once scaled
    return index, values


def history_write_cases() -> list[Case]:
    cases = []
    for scaled in (False, True):

        def build(backend, scaled=scaled):
            index, values = _columns_values()
            return (_columns_history(scaled), _COLUMNS, index, values), {"backend": backend}

        def check(a, b, args_a, args_b):
            for name in _COLUMNS:
                same_bits(args_a[0][0].buffers[name], args_b[0][0].buffers[name], name)
            assert np.isfinite(args_b[0][0].buffers["acc_r"]).all()

        cases.append(Case("scaled" if scaled else "unscaled", build, check))

    def build_scalar(backend):
        index, _ = _columns_values()
        # One row for every pixel, as History.write passes a scalar.
        return (_columns_history(False), ("sxx",), index[:7], np.full((1, 1), 2.5)), {
            "backend": backend
        }

    def check_scalar(a, b, args_a, args_b):
        same_bits(args_a[0][0].buffers["sxx"], args_b[0][0].buffers["sxx"], "sxx")
        assert (args_a[0][0].buffers["sxx"] == 2.5).sum() == 7

    cases.append(Case("scalar-broadcast", build_scalar, check_scalar))
    return cases


def history_read_cases() -> list[Case]:
    cases = []
    for scaled in (False, True):

        def build(backend, scaled=scaled):
            hist = _columns_history(scaled)
            index, values = _columns_values()
            hist.write_columns(_COLUMNS, index, values)
            return (hist, _COLUMNS, index), {"backend": backend}

        def check(a, b, *_):
            assert a.dtype == np.float64
            same_bits(a, b, "columns")

        cases.append(Case("scaled" if scaled else "unscaled", build, check))
    return cases


def reproject_cases() -> list[Case]:
    def make(precision, moving, separate=False, in_place=False):
        def build(backend):
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
            if separate:  # buffers of their own, not the rows of one array (History.empty's)
                hist.buffers = {k: v.copy() for k, v in hist.buffers.items()}
            depth = (hist.depth * rng.choice([1.0, 1.05, 1.2], shape)).astype(np.float32)
            depth[:, 0] = np.inf
            material = np.where(rng.random(shape) < 0.9, hist.material, 2).astype(np.int32)
            motion = None
            if moving:
                motion = rng.normal(0, 4, (*shape, 2)).astype(np.float32)
                motion[::5] = np.round(motion[::5] * 2) / 2  # ties: x.5
                motion[1, :4] = [[np.nan, 0], [np.inf, 1], [-np.inf, 1], [1e30, -1e30]]
            elif in_place:  # a still camera's motion pass: zeros, and tiny values
                motion = np.zeros((*shape, 2), np.float32)
                motion[::3] = rng.uniform(-0.49, 0.49, (motion[::3].shape))
            return (hist, motion, depth, material), {"backend": backend, "in_place": in_place}

        def check(a, b, *_):
            for name in ("valid", "cv_valid", "material", "depth"):
                x, y = getattr(a, name), getattr(b, name)
                assert x.dtype == y.dtype and np.array_equal(x, y), name
            assert a.buffers.keys() == b.buffers.keys()
            for k in a.buffers:
                same_bits(a.buffers[k], b.buffers[k], k)
            assert a.valid.any() and not a.valid.all()
            # reset where the surface is not the same
            assert (a.buffers["acc_n"] == 0).sum() > (a.buffers["mu"] == 0).sum()

        label = f"{precision}-{'moving' if moving else 'still'}{'-separate' if separate else ''}"
        return Case(label + ("-in-place" if in_place else ""), build, check)

    cases = [make(p, m) for p in ("float16", "float32") for m in (True, False)]
    in_place = [make(p, m, in_place=True) for p in ("float16", "float32") for m in (True, False)]
    return [*cases, *in_place, make("float32", True, separate=True)]


# -- the temporal reuse --------------------------------------------------------------------
def neighbourhood_cases() -> list[Case]:
    def make(case):
        def build(backend):
            frame = two_materials() if case == "materials" else surface_frames()[case]
            geom = geometry_of(frame, frame_profile(frame, SSSParams()))
            rng = np.random.default_rng(4)
            values = rng.lognormal(0, 2, (geom.size, 3))
            values[rng.random(geom.size) < 0.05, 0] = np.nan
            active = rng.random(geom.size) < 0.8
            if case != "materials":  # speckled slots
                geom = dataclasses.replace(geom, mat=rng.integers(1, 3, geom.size).astype(np.int32))
            return (geom, values, active), {"backend": backend}

        def check(a, b, args_a, _):
            size = args_a[0][0].size
            for x, y in zip(a, b):
                assert x.shape == y.shape == (size, 3)
                assert np.array_equal(x, y, equal_nan=True)
            assert np.isfinite(a[0]).all() and (a[1] > 0).any()

        return Case(case, build, check)

    return [make(c) for c in ("perspective", "crop", "materials")]


def reuse_step_cases() -> list[Case]:
    frame = surface_frames()["perspective"]
    geom = geometry_of(frame, frame_profile(frame, SSSParams()))

    def make(mode, clamp, noisy):
        def build(backend):
            rng = np.random.default_rng(1)
            p = geom.size
            distant, control = rng.lognormal(0, 1, (2, p, 3))
            proxy = rng.normal(1, 1, (p, 3))
            distant[::37, 1] = np.nan
            control[::41, 0] = 0.0  # a black control
            proxy[::43, 2] = np.inf
            noise = rng.lognormal(-1, 1, p)
            noise[::29] = np.nan
            noise[::31] = np.inf
            n = rng.integers(0, 30, p).astype(np.float64)
            prev, ctl_prev, prox_prev = rng.lognormal(0, 1, (3, p, 3))
            prox_prev[::17] = -1.0  # a negative proxy
            args = (
                geom, distant, control, rng.random(p), proxy if mode == "multiplicative" else None,
                rng.random(p) < 0.85, n, prev, None if mode == "plain" else ctl_prev,
                prox_prev if mode == "multiplicative" else None, 1e-3 * np.ones(3),
            )  # fmt: skip
            kwargs = dict(
                mode=mode, min_weight=0.1, clamp=clamp, tolerance=0.3,
                noise=noise if noisy else None, floor=1e-12, backend=backend,
            )  # fmt: skip
            return args, kwargs

        def check(a, b, *_):
            # libm's log and exp against NumPy's, the luminance summed in channel order
            # against a matrix product: a few ulps of each value, or of the largest where
            # a difference cancels; NaN and ±inf in the same places.
            for x, y in zip(a, b):
                assert np.array_equal(np.isnan(x), np.isnan(y))
                assert np.array_equal(np.isinf(x), np.isinf(y))
                assert np.array_equal(x[np.isinf(x)], y[np.isinf(y)])
                ok = np.isfinite(x)
                scale = float(np.abs(x[ok]).max(initial=0.0))
                np.testing.assert_allclose(y[ok], x[ok], rtol=1e-13, atol=1e-13 * scale)
            assert (a[2] > 1).any() and (a[2] == 0).any()

        return Case(f"{mode}-{'clamp' if np.isfinite(clamp) else 'no-clamp'}-"
                    f"{'noise' if noisy else 'no-noise'}", build, check)  # fmt: skip

    return [
        make(mode, clamp, noisy)
        for mode in ("plain", "subtractive", "multiplicative")
        for clamp in (2.0, np.inf)
        for noisy in (True, False)
    ]


def reuse_cases() -> list[Case]:
    """The whole reuse step on a float32 history: what the NumPy side reads, computes and
    stores against the compiled passes that read and store the buffers themselves."""
    frame = surface_frames()["perspective"]
    geom = geometry_of(frame, frame_profile(frame, SSSParams()))

    def make(mode, clamp, noisy):
        def build(backend):
            rng = np.random.default_rng(2)
            p = geom.size
            hist = History.empty(geom.shape, temporal=True, cv=False)
            idx = geom.index
            for name in T_FIELDS:
                hist.buffers[name].reshape(-1)[idx] = rng.lognormal(0, 1, p)
            hist.buffers["acc_n"].reshape(-1)[idx] = rng.integers(0, 30, p)
            hist.buffers["prox_g"].reshape(-1)[idx[::17]] = -1.0  # a negative proxy
            hist.buffers["acc_b"].reshape(-1)[idx[::19]] = np.nan  # stays NaN: stored as 0
            distant, control = rng.lognormal(0, 1, (2, p, 3))
            proxy = rng.normal(1, 1, (p, 3))
            distant[::37, 1] = np.nan
            control[::41, 0] = 0.0  # a black control
            control[::47, 2] = 1e300  # stored as float32's largest
            proxy[::43, 2] = np.inf
            noise = rng.lognormal(-1, 1, p)
            noise[::29] = np.nan
            noise[::31] = np.inf
            args = (
                hist, geom, distant, control, rng.random(p),
                proxy if mode == "multiplicative" else None, rng.random(p) < 0.85,
                1e-3 * np.ones(3),
            )  # fmt: skip
            kwargs = dict(
                mode=mode, min_weight=0.1, clamp=clamp, tolerance=0.3,
                noise=noise if noisy else None, floor=1e-12, backend=backend,
            )  # fmt: skip
            return args, kwargs

        def check(a, b, args_a, args_b):
            # libm's log and exp against NumPy's (the reuse_step twin's check): a few
            # ulps of each value, or of the largest where a difference cancels; NaN and
            # ±inf in the same places.
            for x, y in zip(a, b):
                assert np.array_equal(np.isnan(x), np.isnan(y))
                assert np.array_equal(np.isinf(x), np.isinf(y))
                ok = np.isfinite(x)
                scale = float(np.abs(x[ok]).max(initial=0.0))
                np.testing.assert_allclose(y[ok], x[ok], rtol=1e-13, atol=1e-13 * scale)
            assert (a[1] > 1).any() and (a[1] == 0).any()
            # The stores: this frame's control and proxy bit for bit; the accumulation
            # and the count, from values within those ulps, within a float32 rounding.
            ha, hb = args_a[0][0], args_b[0][0]
            for name in T_FIELDS:
                x, y = ha.buffers[name], hb.buffers[name]
                assert x.dtype == y.dtype == np.float32
                if name.startswith(("ctl", "prox")):
                    same_bits(x, y, name)
                else:
                    np.testing.assert_allclose(y, x, rtol=2**-23, atol=0, err_msg=name)
            fresh = build("numpy")[0][0]  # the history before the step
            stored = {"acc_r": True, "acc_n": True, "ctl_g": mode != "plain"}
            stored["prox_b"] = mode == "multiplicative"
            for name, changed in stored.items():
                after = hb.buffers[name].reshape(-1)[geom.index]
                same = np.array_equal(after, fresh.buffers[name].reshape(-1)[geom.index])
                assert same != changed, name

        return Case(f"{mode}-{'clamp' if np.isfinite(clamp) else 'no-clamp'}-"
                    f"{'noise' if noisy else 'no-noise'}", build, check)  # fmt: skip

    return [
        make(mode, clamp, noisy)
        for mode in ("plain", "subtractive", "multiplicative")
        for clamp in (2.0, np.inf)
        for noisy in (True, False)
    ]


# -- the separable passes and the composite --------------------------------------------------
def separable_pass_cases() -> list[Case]:
    def make(case, name, options):
        params = SeparableParams(**options)

        def build(backend):
            frame = two_materials() if case == "materials" else surface_frames()[case]
            profile = frame_profile(frame, SSSParams())
            geom = geometry_of(frame, profile)
            tab = _stack(build_kernels(profile, params), profile.n_slots, params)
            key = 10 if params.jitter else None
            slope = 2.0 if params.follow == "slope" else None
            args = (
                frame.lighting, frame.depth, geom.slots, _pixels(geom), geom.shape, tab,
                params.terms, key, slope, params.filter == "linear",
            )  # fmt: skip
            return args, {"backend": backend}

        def check(a, b, *_):
            (xa, fa), (xb, fb) = a, b
            assert fa == fb and fa > 0
            assert xa.shape == xb.shape and (xa > 0).any()
            if params.follow == "exponential":  # exp: an ulp between the libraries
                np.testing.assert_allclose(xb, xa, rtol=0, atol=1e-6 * xa.max())
            else:
                assert np.array_equal(xa, xb)

        return Case(f"{case}-{name}", build, check)

    options = {
        "nearest": {},
        "linear": {"filter": "linear"},
        "jitter": {"jitter": True, "jitter_threshold": 1.0},
        "svd2-linear-jitter": {"kernel": "svd2", "taps": 11, "filter": "linear", "jitter": True},
        "exponential": {"follow": "exponential"},
    }
    return [
        make(case, name, o)
        for case in ("perspective", "crop", "materials")
        for name, o in options.items()
    ]


def composite_cases() -> list[Case]:
    cases = []
    for crop in (False, True):
        frame = scene_frame("flash", 3, 48, 32)
        if crop:
            frame = crop_frame(frame, (4, 28, 6, 40), (8, 24, 10, 36))
        geom = geometry_of(frame, frame_profile(frame, SSSParams()))
        rng = np.random.default_rng(5)
        shaded = geom.at(frame.lighting).astype(np.float64) * rng.random((geom.size, 3)) * 2
        shaded[:5] = [[np.nan, np.inf, -np.inf], [-1.0, 1e300, 0.0], [-0.0, 3.5e38, np.nan]] + [
            [1.0, 2.0, 3.0]
        ] * 2
        for weight_name, weight in (
            ("no-weight", None),
            ("weight", rng.random(geom.size)),
            ("weight-ones", np.ones(geom.size)),
        ):

            def build(backend, frame=frame, geom=geom, weight=weight, shaded=shaded):
                return (frame, geom.index, shaded.copy(), weight), {"backend": backend}

            def check(a, b, args_a, _):
                frame_a = args_a[0][0]
                for x, y in zip(a, b):
                    assert x.dtype == y.dtype == np.float32
                    assert x.shape == y.shape == frame_a.lighting.shape
                    assert np.array_equal(x, y)
                assert not np.array_equal(a[0], frame_a.combined)  # the SSS pixels changed

            cases.append(Case(f"{'crop' if crop else 'whole'}-{weight_name}", build, check))
    return cases


CASES: dict[str, Callable[[], list[Case]]] = {
    "sampling": sampling_cases,
    "estimate_variance": estimate_variance_cases,
    "surface": surface_cases,
    "float_image": float_image_cases,
    "row_mean": row_mean_cases,
    "burley_region": burley_region_cases,
    "spvg_counts": spvg_counts_cases,
    "spvg_update": spvg_update_cases,
    "history_step": history_step_cases,
    "history_read": history_read_cases,
    "history_write": history_write_cases,
    "reproject": reproject_cases,
    "neighbourhood": neighbourhood_cases,
    "reuse_step": reuse_step_cases,
    "reuse": reuse_cases,
    "separable_pass": separable_pass_cases,
    "composite": composite_cases,
}

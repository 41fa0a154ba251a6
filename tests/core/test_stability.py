"""Numerical stability at the extremes: parameters, passes, and long runs.

Invariants checked after every frame (:func:`check_frame`):

- no NaN or inf in any output image (L, composite, α, γ, σ²) or history
  buffer, and no NumPy RuntimeWarning (pytest turns those raised in cvsss
  into errors, see pyproject.toml);
- sample counts in {0} ∪ [β_min, β_max] on SSS pixels, 0 elsewhere;
- α in its bound D = [0, (f̄ + ḡ)/ḡ] (ḡ = 0: [0, 1]), taken from the very
  values the pipeline passed to the coefficient; α = 1 for CCV, 0 without CV
  or without samples;
- σ² >= 0 and m̄ within [0, max(β_max, n_init)].

The "torture" sequence (:func:`torture_frame`, 32x32) puts every pass extreme
of issue #7 in one image and cycles them over time: hard shadows (G = 0 on
stripes, so Var(g) = 0), an HDR block up to 1e6, zero-lighting rows, whole
frames of zero or of 1e6 lighting, background depth 1e10, depth 0, a slot
with d -> 0 (1e-30, 1e-12, 0), a slot with d much larger than the screen
(1e6, 1e3, 10 scene units), a single pixel of its own SSS material, float16
input passes, 1-pixel camera motion (disocclusions) and depth jumps that
invalidate the history.

Frame counts (the processor costs 2-4 ms per 32x32 frame here):

- fast lane: each parameter extreme alone x 3 adaptive methods x 2 history
  precisions, 12 frames (4 for β_max = 1024); each pass extreme alone x 6
  methods x 2 precisions, 6 frames; hypothesis over random combinations of
  extremes, 6 frames at 16x16; hypothesis on the kernels.
- slow lane (``-m slow``, still part of ``make test``, ~2 min): 10 000 frames
  for three representative configurations (online CV with a float16 history
  and the paper's defaults, β = [1, 4]; online CV, float32, η = 1e-6,
  η_cv = 1e-9, κ = 1, ε_α = 0; no CV, float16, η = 1, σ0² = 1e-12, κ = 0,
  ε_u = 0, β_min = β_max = 2), and 100 frames for every parameter extreme in
  both precisions, the method rotating over as / as_ocv / as_ccv (30 frames
  for β_max = 1024, which costs ~100 ms per frame). A full 10 000-frame run
  of every configuration would take over an hour.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cvsss.core import SSSParams, make_processor
from cvsss.core.camera import Camera
from cvsss.core.frame import Frame, MaterialSpec
from cvsss.core.mc import adaptive, control_variates
from cvsss.core.mc.history import History
from cvsss.core.mc.update import TRACK_LIMIT

ADAPTIVE = ("as", "as_ocv", "as_ccv")
ALL_METHODS = ("as", "as_ocv", "as_ccv", "fixed", "reference", "none")
PRECISIONS = ("float32", "float16")
HALF_MAX = 65504.0

#: Each parameter at a limit of its range (issue #7), one at a time.
PARAM_EXTREMES = {
    "eta=1e-6": {"eta": 1e-6},
    "eta=1": {"eta": 1.0},
    "eta_cv=1e-9": {"eta_cv": 1e-9},
    "eta_cv=1": {"eta_cv": 1.0},
    "s0=1e-12": {"target_variance": 1e-12},
    "s0=1e6": {"target_variance": 1e6},
    "kappa=0": {"kappa": 0.0},
    "kappa=1": {"kappa": 1.0},
    "eps_u=0": {"eps_u": 0.0},
    "eps_u=1": {"eps_u": 1.0},
    "eps_alpha=0": {"eps_alpha": 0.0},
    "eps_alpha=1": {"eps_alpha": 1.0},
    "beta_min=beta_max": {"beta_min": 5, "beta_max": 5},
    "beta_max=1": {"beta_min": 1, "beta_max": 1},
    "beta_max=1024": {"beta_min": 8, "beta_max": 1024},
}


# -- the torture sequence ------------------------------------------------------------------
SIZE = 32
MATERIALS = {
    1: MaterialSpec(1, "skin", (0.01, 0.004, 0.002)),
    2: MaterialSpec(2, "d->0", (1e-30, 1e-12, 0.0)),
    3: MaterialSpec(3, "d>>screen", (1e6, 1e3, 10.0)),
    4: MaterialSpec(4, "single pixel", (0.02, 0.02, 0.02)),
}
PERIOD = 24


def torture_frame(n: int, size: int = SIZE) -> Frame:
    """Frame ``n`` of the torture sequence (see module docstring); pattern period 24."""
    h = w = size
    yy, xx = np.mgrid[0:h, 0:w]
    q = max(size // 8, 1)
    depth = np.full((h, w), 2.0)
    depth[:q] = 1e10  # background
    depth[q, :q] = 0.0  # depth 0
    if n % 13 == 12:
        depth[h // 2 :] *= 1.3  # depth jump: history invalid there
    mat = np.ones((h, w), np.int32)
    mat[:, : w // 4] = 2
    mat[:, -(w // 4) :] = 3
    mat[h - q :, :] = 0  # no SSS
    mat[h // 2, w // 2] = 4  # a single SSS pixel of its own material
    light = np.full((h, w, 3), 1.0)
    light *= np.array([1.0, 0.8, 0.6])
    light[(xx // 3) % 2 == 0] = 0.0  # hard shadow stripes: G = 0, Var(g) = 0
    light[2 * q : 3 * q, q : 5 * q] = 1e6  # HDR block
    light[4 * q : 5 * q] = 0.0  # zero-lighting rows
    scale = [1.0, 0.0, np.sin(0.7 * n) + 1.0, 1e-30, 1.0, 3.0][n % 6]
    light *= scale
    if n % 11 == 10:
        light[:] = 1e6  # whole frame of HDR lighting
    albedo = np.full((h, w, 3), 0.8)
    motion = None
    if n % 5 == 4:
        motion = np.zeros((h, w, 2), np.float32)
        motion[..., 0] = 1.0  # everything came from one pixel to the right
    dtype = np.float32
    if n % 4 == 3:  # half-float passes (HDR above 65504 would be inf there)
        dtype = np.float16
        light = np.minimum(light, 6e4)
        depth = np.where(depth > 6e4, np.inf, depth)
    return Frame(
        number=n,
        lighting=light.astype(dtype),
        albedo=albedo.astype(dtype),
        combined=(albedo * light).astype(dtype),
        depth=depth.astype(dtype),
        material=mat,
        camera=Camera(w, h),
        materials=dict(MATERIALS),
        motion=motion,
    )


@pytest.fixture(scope="module")
def torture32():
    return [torture_frame(n) for n in range(PERIOD)]


TORTURE16 = [torture_frame(n, 16) for n in range(PERIOD)]


def numbered(frames, n: int) -> Frame:
    f = copy.copy(frames[n % len(frames)])
    f.number = n
    return f


# -- the invariants -----------------------------------------------------------------------------
@dataclass
class CoefficientSpy:
    """Records the bound D of every α the pipeline computes (P Alg. 2)."""

    upper: list = field(default_factory=list)

    def install(self, monkeypatch) -> None:
        real = control_variates.cv_coefficient

        def spy(s_xy, s_yy, f_bar, g_bar, eps_alpha):
            alpha = real(s_xy, s_yy, f_bar, g_bar, eps_alpha)
            g = np.asarray(g_bar, dtype=np.float64)
            with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
                upper = np.where(g > 0, (np.maximum(f_bar, 0.0) + g) / g, 1.0)
            self.upper = [np.nan_to_num(upper, posinf=np.finfo(np.float64).max)]
            assert np.all(np.isfinite(alpha)) and np.all(alpha >= 0)
            assert np.all(alpha <= self.upper[0])
            return alpha

        monkeypatch.setattr(control_variates, "cv_coefficient", spy)


def check_frame(res, proc, spy: CoefficientSpy | None = None) -> None:
    p = proc.params
    for name in ("sss", "composite", "alpha", "gamma", "variance"):
        a = getattr(res, name)
        assert np.all(np.isfinite(a)), f"{name} not finite at frame {res.number}"
    assert np.all(res.sss >= 0) and np.all(res.composite >= 0)
    assert np.all(res.variance >= 0)
    assert np.all((res.gamma >= 0) & (res.gamma <= 1))
    c = res.counts
    assert c.dtype == np.int32
    assert np.all(c[~res.mask] == 0)
    kind = proc.method.kind
    if kind == "adaptive":
        assert np.all((c == 0) | ((c >= p.beta_min) & (c <= p.beta_max))), res.number
    elif kind == "fixed":
        assert np.all((c == 0) | (c == p.fixed_spp))
    elif kind == "reference":
        assert np.all((c == 0) | (c == p.reference_spp))
    else:
        assert np.all(c == 0)
    assert 0.0 <= res.spp <= max(p.beta_max, p.fixed_spp, p.reference_spp)
    alpha = res.alpha[res.mask]
    sampled = c[res.mask] > 0
    assert np.all(alpha[~sampled] == 0.0)
    if proc.method.cv == "constant":
        assert np.all(alpha[sampled] == 1.0)
    elif proc.method.cv == "online":
        assert np.all(alpha >= 0.0)
        if spy is not None and spy.upper and sampled.any():
            upper = spy.upper[0][sampled]
            assert np.all(alpha[sampled] <= upper * (1 + 1e-6) + 1e-30), res.number
    else:
        assert np.all(alpha == 0.0)
    h = proc.history
    if h is not None:
        for key, buf in h.buffers.items():
            assert np.all(np.isfinite(buf)), f"history {key} not finite at frame {res.number}"
        assert np.all(h.buffers["var"] >= 0)
        mbar = h.buffers["mbar"][h.valid]
        assert np.all((mbar >= 0) & (mbar <= max(p.beta_max, p.initial_count) + 1e-3))


def run_sequence(frames, method: str, params: SSSParams, n_frames: int, spy=None) -> list[float]:
    proc = make_processor(method, params)
    spp = []
    for n in range(n_frames):
        res = proc.process(numbered(frames, n))
        check_frame(res, proc, spy)
        spp.append(res.spp)
    return spp


# -- kernels under hypothesis --------------------------------------------------------------------
any_floats = hnp.arrays(
    np.float64,
    16,
    elements=st.floats(allow_nan=True, allow_infinity=True, width=64),
)


def _params(d: dict) -> SSSParams:
    d = dict(d)
    lo, hi = d.pop("beta")
    return SSSParams(beta_min=lo, beta_max=hi, **d)


extreme_params = st.fixed_dictionaries(
    {
        "eta": st.sampled_from([1e-6, 0.2, 1.0]),
        "eta_cv": st.sampled_from([1e-9, 1e-6, 1.0]),
        "target_variance": st.sampled_from([1e-12, 1e-4, 1e6]),
        "kappa": st.sampled_from([0.0, 0.2, 1.0]),
        "eps_u": st.sampled_from([0.0, 0.01, 1.0]),
        "eps_alpha": st.sampled_from([0.0, 1e-6, 1.0]),
        "beta": st.sampled_from([(1, 1), (5, 5), (1, 4), (8, 64), (1, 4096)]),
        "history_precision": st.sampled_from(PRECISIONS),
    }
).map(_params)


KERNEL_SETTINGS = settings(max_examples=75, deadline=None, derandomize=True)


@KERNEL_SETTINGS
@given(any_floats, any_floats, any_floats, extreme_params, st.integers(0, 2**16 - 1))
def test_sample_counts_always_in_range(var, mbar, gamma, params, valid_bits):
    valid = np.array([(valid_bits >> i) & 1 for i in range(16)], dtype=bool)
    m = adaptive.sample_counts(var, mbar, valid, gamma, params)
    assert m.dtype == np.int32
    assert np.all((m == 0) | ((m >= params.beta_min) & (m <= params.beta_max)))


@KERNEL_SETTINGS
@given(
    any_floats,
    any_floats,
    any_floats,
    any_floats,
    extreme_params,
    hnp.arrays(np.int64, 16, elements=st.integers(0, 4096)),
)
def test_update_history_stays_finite(mu, var, mbar, tracked, params, counts):
    valid = np.isfinite(mu)
    mu2, var2, mbar2, valid2 = adaptive.update_history(
        mu, var, mbar, valid, tracked, counts, params
    )
    for a in (mu2, var2, mbar2):
        assert np.all(np.isfinite(a))
    assert np.all(var2 >= 0)
    assert np.array_equal(valid2, counts > 0)


nonneg_floats = hnp.arrays(
    np.float64, 16, elements=st.floats(0.0, 3.4e38, allow_subnormal=True, width=64)
)


@KERNEL_SETTINGS
@given(
    any_floats,
    any_floats,
    nonneg_floats,
    nonneg_floats,
    st.sampled_from([0.0, 1e-300, 1e-6, 1.0, 1e300]),
)
def test_cv_coefficient_in_its_bound(s_xy, s_yy, f_bar, g_bar, eps):
    s_xy = np.nan_to_num(s_xy)  # history reads are finite (storage is clipped)
    s_yy = np.nan_to_num(s_yy)
    alpha = control_variates.cv_coefficient(s_xy, s_yy, f_bar, g_bar, eps)
    assert np.all(np.isfinite(alpha)) and np.all(alpha >= 0)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        upper = np.where(g_bar > 0, (f_bar + g_bar) / g_bar, 1.0)
    assert np.all(alpha <= upper)
    res = control_variates.residual(f_bar, g_bar, alpha)
    assert np.all(np.isfinite(res))


@KERNEL_SETTINGS
@given(
    st.sampled_from(PRECISIONS),
    any_floats,
    st.sampled_from([1e-9, 1e-6, 1.0]),
    st.sampled_from([1e-12, 1e-4, 1e6]),
    st.sampled_from(["mu", "var", "sxy", "zf"]),
)
def test_history_storage_never_holds_inf_or_nan(precision, values, eta_cv, s0, name):
    h = History.empty((4, 4), precision, eta_cv, s0)
    idx = np.arange(16)
    h.write(name, idx, values)
    assert np.all(np.isfinite(h.buffers[name]))
    assert np.all(np.isfinite(h.read(name, idx)))


def test_tracked_luminance_is_bounded_for_any_exposure():
    for exposure in (1e-300, 1e300):
        for method in ADAPTIVE:
            run_sequence(TORTURE16, method, SSSParams(exposure=exposure, beta_max=8), 12)
    assert TRACK_LIMIT**2 < np.finfo(np.float64).max


# -- the processor: parameters at their limits --------------------------------------------
@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("method", ADAPTIVE)
@pytest.mark.parametrize("extreme", list(PARAM_EXTREMES))
def test_parameter_extreme(torture32, monkeypatch, extreme, method, precision):
    spy = CoefficientSpy()
    spy.install(monkeypatch)
    params = SSSParams(history_precision=precision, **PARAM_EXTREMES[extreme])
    n = 4 if params.beta_max > 64 else 12
    spp = run_sequence(torture32, method, params, n, spy)
    if params.eps_u == 1.0:
        assert max(spp) == 0.0  # γ < 1 everywhere: nothing is sampled
    else:
        assert max(spp) > 0.0


@settings(
    max_examples=30,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(extreme_params, st.sampled_from(ADAPTIVE))
def test_random_combinations_of_extremes(monkeypatch, params, method):
    spy = CoefficientSpy()
    spy.install(monkeypatch)
    run_sequence(TORTURE16, method, params, 6, spy)


# -- the processor: passes at their limits ----------------------------------------------------
def plane(
    n: int,
    *,
    size=(32, 32),
    light=1.0,
    depth=2.0,
    mat=1,
    d=(0.01, 0.004, 0.002),
    dtype=np.float32,
    motion=None,
) -> Frame:
    h, w = size
    flash = 1.0 + np.sin(0.9 * n)
    b = np.broadcast_to(np.asarray(light, np.float64), (h, w, 3)) * flash
    z = np.broadcast_to(np.asarray(depth, np.float64), (h, w))
    m = np.broadcast_to(np.asarray(mat), (h, w)).astype(np.int32)
    a = np.full((h, w, 3), 0.8)
    with np.errstate(over="ignore"):
        return Frame(
            n,
            b.astype(dtype),
            a.astype(dtype),
            (a * b).astype(dtype),
            z.astype(dtype),
            m,
            Camera(w, h),
            {1: MaterialSpec(1, "m", d)},
            motion=motion,
        )


def _shadow_light():
    b = np.ones((32, 32, 3))
    b[:, :16] = 0.0
    return b


def _hdr_light():
    b = np.ones((32, 32, 3))
    b[::2] = 1e6
    return b


def _single_pixel():
    m = np.zeros((32, 32), np.int32)
    m[16, 16] = 1
    return m


PASS_EXTREMES = {
    "zero lighting": {"light": 0.0},
    "HDR 1e6": {"light": _hdr_light()},
    "all 1e6": {"light": 1e6},
    "hard shadow": {"light": _shadow_light()},
    "depth 0": {"depth": 0.0},
    "depth 1e10": {"depth": 1e10},
    "d -> 0": {"d": (1e-30, 1e-30, 1e-30)},
    "d >> screen": {"d": (1e6, 1e6, 1e6)},
    "single SSS pixel": {"mat": _single_pixel()},
    "1x1 image": {"size": (1, 1), "d": (1.0, 0.5, 0.2)},
    "float16 passes": {"dtype": np.float16, "light": _hdr_light() * 0.06},
    "NaN passes": {"light": np.nan, "depth": np.nan},
    "huge motion": {"motion": np.full((32, 32, 2), 3e38, np.float32)},
}


@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("method", ALL_METHODS)
@pytest.mark.parametrize("case", list(PASS_EXTREMES))
def test_pass_extreme(monkeypatch, case, method, precision):
    spy = CoefficientSpy()
    spy.install(monkeypatch)
    params = SSSParams(history_precision=precision, beta_max=16, fixed_spp=4, reference_spp=16)
    proc = make_processor(method, params)
    kw = PASS_EXTREMES[case]
    for n in range(6):
        frame = plane(n, **kw)
        res = proc.process(frame)
        check_frame(res, proc, spy)
    if case in ("depth 0", "depth 1e10", "NaN passes"):
        assert not res.mask.any() and np.array_equal(res.composite, frame.combined)
    if case == "zero lighting":
        assert np.all(res.sss == 0) and np.all(res.composite == 0)
    if case == "single SSS pixel":
        assert res.mask.sum() == 1
    if case == "1x1 image" and method != "none":
        assert res.samples > 0
    if case == "hard shadow" and method == "as_ocv":
        # Shadowed pixels far from the edge never see light: G = 0 there and
        # the bound D is [0, 1].
        assert np.all(res.alpha[:, :8] <= 1.0)
    if case == "NaN passes":
        assert res.repaired == 2 * 32 * 32 * 3 + 32 * 32


def test_float16_passes_give_the_float32_result():
    light = _hdr_light() * 0.06
    for method in ADAPTIVE:
        a = make_processor(method, SSSParams())
        b = make_processor(method, SSSParams())
        for n in range(4):
            half = plane(n, light=light, dtype=np.float16)
            full = Frame(
                n,
                half.lighting.astype(np.float32),
                half.albedo,
                half.combined,
                half.depth,
                half.material,
                half.camera,
                half.materials,
            )
            ra, rb = a.process(half), b.process(full)
            assert np.array_equal(ra.composite, rb.composite)
            assert np.array_equal(ra.counts, rb.counts)


def test_hard_shadow_has_zero_variance_of_g(monkeypatch):
    # Where G = 0 every frame, Var(g) = Σ_yy = 0: α falls back to ε_α/ε_α = 1
    # (or 1 with ε_α = 0: den = 0) and Res = f̄.
    for eps in (0.0, 1e-6):
        proc = make_processor("as_ocv", SSSParams(eps_alpha=eps))
        for n in range(6):
            res = proc.process(plane(n, light=_shadow_light(), d=(0.02, 0.02, 0.02)))
        # r_max = 16·d is ~7 pixels: columns < 8 never receive light.
        shadow = res.mask.copy()
        shadow[:, 8:] = False
        sampled = shadow & (res.counts > 0)
        assert sampled.any()
        assert np.all(proc.history.buffers["syy"][sampled] == 0)
        assert np.all(res.alpha[sampled] == 1.0)


# -- long runs (slow lane) ---------------------------------------------------------------------------
LONG_RUNS = {
    "as_ocv float16, paper defaults, β=[1,4]": (
        "as_ocv",
        {"history_precision": "float16", "beta_min": 1, "beta_max": 4},
    ),
    "as_ocv float32, η=1e-6, η_cv=1e-9, κ=1, ε_α=0, β=[1,2]": (
        "as_ocv",
        {"eta": 1e-6, "eta_cv": 1e-9, "kappa": 1.0, "eps_alpha": 0.0, "beta_min": 1, "beta_max": 2},
    ),
    "as float16, η=1, σ0²=1e-12, κ=0, ε_u=0, β_min=β_max=2": (
        "as",
        {
            "history_precision": "float16",
            "eta": 1.0,
            "target_variance": 1e-12,
            "kappa": 0.0,
            "eps_u": 0.0,
            "beta_min": 2,
            "beta_max": 2,
        },
    ),
}


@pytest.mark.slow
@pytest.mark.parametrize("name", list(LONG_RUNS))
def test_ten_thousand_frames(torture32, monkeypatch, name):
    method, overrides = LONG_RUNS[name]
    spy = CoefficientSpy()
    spy.install(monkeypatch)
    spp = run_sequence(torture32, method, SSSParams(**overrides), 10_000, spy)
    assert len(spp) == 10_000 and max(spp) > 0


@pytest.mark.slow
@pytest.mark.parametrize("precision", PRECISIONS)
@pytest.mark.parametrize("extreme", list(PARAM_EXTREMES))
def test_parameter_extreme_long(torture32, monkeypatch, extreme, precision):
    # The method rotates with the extreme so every method meets both precisions.
    i = list(PARAM_EXTREMES).index(extreme) + PRECISIONS.index(precision)
    spy = CoefficientSpy()
    spy.install(monkeypatch)
    params = SSSParams(history_precision=precision, **PARAM_EXTREMES[extreme])
    run_sequence(torture32, ADAPTIVE[i % 3], params, 30 if params.beta_max > 64 else 100, spy)

"""Separable SSS (Jimenez et al. 2015): kernels (S.1–S.6), passes, invariants, jitter."""

import dataclasses
import itertools

import numpy as np
import pytest

from cvsss.core import SSSParams
from cvsss.core.frame import Frame
from cvsss.core.method import MethodOptions
from cvsss.core.methods import make_processor
from cvsss.core.params import ParameterError
from cvsss.core.profiles import BurleyProfile, presets
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.profiles.radial import discretize, radial_model
from cvsss.core.separable.kernels import (
    KERNELS,
    SeparableParams,
    build_kernels,
    kernel_errors,
    pre_integrated_terms,
    relative_error,
    slot_terms,
    svd_terms,
)
from cvsss.core.synthetic import flat_plane, scene_frame

CHROMATIC = (0.02, 0.008, 0.003)  # metres; ~0.9, 0.36, 0.13 px·16 at 2 m, 64 px wide


def burley_kernel(d=0.01, m=65):
    prof = BurleyProfile(np.array([[0, 0, 0], [d, d, d]]))
    return discretize(radial_model(prof, 1), 0, m)


def separable(frame, **kw):
    sss = kw.pop("sss", SSSParams())
    return make_processor("separable", sss, MethodOptions(separable=SeparableParams(**kw))).process(
        frame
    )


def test_params_validation():
    assert SeparableParams(kernel="svd3").terms == 3
    assert SeparableParams(kernel="gaussians", gaussians=5).terms == 5
    for kw, fragment in [
        ({"kernel": "svd9"}, "kernel must be one of"),
        ({"taps": 13}, "taps must be one of"),
        ({"jitter_threshold": 1.5}, "jitter_threshold"),
        ({"gaussians": 0}, "gaussians must be"),
        ({"grid": 64}, "grid must be an odd"),
        ({"follow": "maybe"}, "follow must be one of"),
        ({"filter": "cubic"}, "filter must be one of"),
    ]:
        with pytest.raises(ParameterError, match=fragment):
            SeparableParams(**kw)


def test_svd_rank_k_error_decreases_and_rank1_is_optimal():
    kern, _ = burley_kernel()
    errors = [relative_error(kern, svd_terms(kern, k, conserve=False)) for k in (1, 2, 3, 4)]
    assert all(a > b for a, b in itertools.pairwise(errors))
    # Eckart–Young: the truncated SVD error is the tail of the singular values.
    s = np.linalg.svd(kern, compute_uv=False)
    assert errors[0] == pytest.approx(np.sqrt(np.sum(s[1:] ** 2)) / np.linalg.norm(kern), rel=1e-9)
    # No rank-1 kernel does better: the pre-integrated one, nor perturbations of the optimum.
    assert relative_error(kern, pre_integrated_terms(kern)) >= errors[0]
    ((h, v),) = svd_terms(kern, 1, conserve=False)
    rng = np.random.default_rng(2)
    for _ in range(20):
        dh, dv = rng.normal(size=(2, h.size)) * 1e-3 * np.abs(h).max()
        assert relative_error(kern, [(h + dh, v + dv)]) >= errors[0]
    # The energy-conserving variant used at run time sums to ‖R‖₁.
    total = sum(a.sum() * b.sum() for a, b in svd_terms(kern, 3))
    assert total == pytest.approx(kern.sum(), rel=1e-12)


def _conv2d(image, kern):
    """Linear 2D convolution (same size, zero padding) by FFT."""
    sh = (image.shape[0] + kern.shape[0], image.shape[1] + kern.shape[1])
    out = np.fft.irfft2(np.fft.rfft2(image, sh) * np.fft.rfft2(kern, sh), sh)
    h, w = kern.shape[0] // 2, kern.shape[1] // 2
    return out[h : h + image.shape[0], w : w + image.shape[1]]


def test_pre_integrated_is_exact_for_additively_separable_lighting():
    kern, _ = burley_kernel(m=33)
    ((a, b),) = pre_integrated_terms(kern)
    approx = np.outer(b, a)
    x = np.arange(160)
    rng = np.random.default_rng(4)
    step = np.where(x < 80, 0.1, 1.0)
    for image in (
        np.tile(step, (120, 1)),  # an axis-aligned step edge
        np.tile(step, (120, 1)) + rng.random(120)[:, None],
    ):  # E1(x) + E2(y)
        exact = _conv2d(image, kern)[40:-40, 40:-40]
        assert np.max(np.abs(_conv2d(image, approx)[40:-40, 40:-40] - exact)) < 1e-12
    # ... but not for a diagonal edge (the separable kernel is not radially symmetric).
    yy, xx = np.mgrid[0:120, 0:160]
    diag = np.where(xx + yy < 140, 0.1, 1.0)
    err = np.abs(_conv2d(diag, approx) - _conv2d(diag, kern))[40:-40, 40:-40]
    assert err.max() > 1e-3


def test_kernel_errors_are_reported_and_ordered():
    frame = flat_plane(d=CHROMATIC)
    prof = frame_profile(frame, SSSParams())
    errs = kernel_errors(prof, 1, gaussians=3, grid=65)
    assert set(errs) == set(KERNELS)
    for k, e in errs.items():
        assert e.shape == (3,) and np.all(np.isfinite(e)) and np.all(e >= 0), k
    assert np.all(errs["svd4"] < errs["svd3"]) and np.all(errs["svd3"] < errs["svd2"])
    assert np.all(errs["svd4"] < 0.05) and np.all(errs["gaussians"] < 0.2)
    # Measured presets under the dipole profile too (Figure S.3 in numbers).
    m = presets.get("skin1")
    from cvsss.core.profiles import DipoleProfile

    dip = DipoleProfile(np.array([[0.0] * 3, m.sigma_a]), np.array([[0.0] * 3, m.sigma_s]), m.eta)
    e2 = kernel_errors(dip, 1, kernels=("pre_integrated", "svd2"), grid=65)
    assert np.all(e2["svd2"] < e2["pre_integrated"])


def _const_frame(frame: Frame, rgb) -> Frame:
    light = np.broadcast_to(np.asarray(rgb, np.float32), frame.lighting.shape).copy()
    return dataclasses.replace(frame, lighting=light, combined=frame.albedo * light)


@pytest.mark.parametrize("kernel", KERNELS)
def test_constant_lighting_is_unchanged(kernel):
    # Sphere and tilted slab of two materials, depth discontinuities, image borders.
    frame = _const_frame(scene_frame("static", 1, 96, 54), [0.3, 0.7, 1.9])
    for kw in (
        {"taps": 11},
        {"taps": 25, "jitter": True, "follow": "exponential", "filter": "linear"},
    ):
        res = separable(frame, kernel=kernel, gaussians=2, grid=65, **kw)
        got = res.sss[res.mask]
        assert np.allclose(got, [0.3, 0.7, 1.9], rtol=2e-6, atol=0), (kernel, kw)


@pytest.mark.parametrize(
    ("kernel", "filt"),
    [
        ("pre_integrated", "nearest"),
        ("pre_integrated", "linear"),
        ("svd2", "nearest"),
        ("gaussians", "linear"),
        ("artist", "nearest"),
    ],
)
def test_energy_conserved_on_a_step_edge(kernel, filt):
    x = np.arange(64)[None, :, None]
    b = (
        np.broadcast_to(np.where(x < 32, 0.05, 1.0), (48, 64, 3)) * np.array([1.0, 0.8, 0.6])
    ).astype(np.float32)
    frame = flat_plane(d=CHROMATIC, lighting=b)
    res = separable(frame, kernel=kernel, taps=17, gaussians=2, grid=65, filter=filt)
    inner = slice(16, 48)  # lighting is constant within the kernel range of both ends
    assert np.allclose(res.sss[:, inner].sum(axis=1), b[:, inner].sum(axis=1), rtol=1e-5)
    assert np.max(np.abs(res.sss - b)) > 0.05  # and it did scatter


def test_jitter_removes_banding_on_a_step_edge():
    """Power of the banding at and above the tap frequency, with and without jitter.

    A step edge across x on a plane; the row-averaged result is compared with
    the exact convolution of the (linearly interpolated) step with the
    pre-integrated kernel; the power spectrum of the difference is summed at
    spatial frequencies >= 1/Δ, Δ the largest spacing of the jittered taps
    in pixels — the staircase of the discrete taps lives there.
    """
    w, h, lo, hi = 256, 64, 0.05, 1.0
    x = np.arange(w)[None, :, None]
    b = np.broadcast_to(np.where(x < w // 2, lo, hi), (h, w, 3)).astype(np.float32)
    frame = flat_plane(w, h, d=(0.03, 0.03, 0.03), lighting=b)
    fw = frame.camera.footprint(2.0)[0]
    params = SeparableParams(taps=17, grid=129)
    prof = frame_profile(frame, SSSParams())
    kern, delta, _ = slot_terms(radial_model(prof, 1), params, 0)
    a = kern.sum(axis=0)
    t = (np.arange(a.size) - a.size // 2) * delta / fw
    ref = np.array(
        [np.sum(a * (lo + (hi - lo) * np.clip(px + t - (w // 2 - 1), 0, 1))) for px in range(w)]
    )
    k = build_kernels(prof, params)[1]
    jittered = np.abs(k.offsets) <= params.jitter_threshold * k.range
    spacing = np.max(np.diff(k.offsets[jittered])) / fw

    def banding(res):
        diff = res.sss[:, 40:-40, 0].mean(axis=0) - ref[40:-40]
        power = np.abs(np.fft.rfft(diff)) ** 2
        return power[np.fft.rfftfreq(diff.size) >= 1.0 / spacing].sum()

    plain = banding(separable(frame, taps=17))
    jitter = banding(separable(frame, taps=17, jitter=True))
    everywhere = banding(separable(frame, taps=17, jitter=True, jitter_threshold=1.0))
    assert jitter < 0.35 * plain
    assert everywhere < jitter


def test_frame_result_and_determinism():
    frame = scene_frame("flash", 4, 64, 36)
    res = separable(frame, kernel="svd2", taps=11, jitter=True)
    # Its sample count is what it reads per pixel: 2 passes x J = 2 terms x 11 taps.
    assert res.method == "separable" and res.spp == 44.0
    assert np.all(res.counts[res.mask] == 44) and np.all(res.counts[~res.mask] == 0)
    assert res.samples == 44 * int(res.mask.sum())
    assert np.all(res.alpha == 0) and res.sampling_ms > 0
    ref_gamma = make_processor("fixed", SSSParams()).process(frame).gamma
    assert np.array_equal(res.gamma, ref_gamma)
    off = ~res.mask
    assert np.array_equal(res.composite[off], frame.combined[off])
    again = separable(frame, kernel="svd2", taps=11, jitter=True)
    other = separable(frame, kernel="svd2", taps=11, jitter=True, sss=SSSParams(seed=3))
    assert np.array_equal(res.sss, again.sss) and not np.array_equal(res.sss, other.sss)


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e30, 0.0])
def test_bad_values_never_leak(bad):
    frame = scene_frame("flash", 3, 64, 36)
    frame.lighting[10:14, 10:30] = bad
    frame.depth[5:8, 20:24] = bad
    frame = dataclasses.replace(frame)  # validates (and repairs) the bad values again
    for kernel in ("pre_integrated", "svd3"):
        res = separable(frame, kernel=kernel, jitter=True)
        for arr in (res.sss, res.composite, res.gamma):
            assert np.all(np.isfinite(arr)) and np.all(arr >= 0)

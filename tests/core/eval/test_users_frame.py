"""The user's-frame figures: one exposure per frame, the subsurface mask, the effect in dB."""

import math

import numpy as np
import pytest

from cvsss.core.eval.metrics import PSNR_CAP_DB
from cvsss.core.eval.users_frame import (
    display,
    effect_db,
    frame_exposure,
    frame_figures,
    lighting_scale,
    mean_figures,
    object_errors,
    psnr_display,
    subsurface_mask,
)


def _srgb(x: float) -> float:
    """sRGB OETF of one value, written out (IEC 61966-2-1)."""
    return 12.92 * x if x <= 0.0031308 else 1.055 * x ** (1 / 2.4) - 0.055


def test_display_is_exposure_then_srgb_then_clip():
    image = np.array([[[0.1, 0.3, 2.0], [-1.0, np.nan, 0.001]]])
    got = display(image, 2.0)
    want = [[_srgb(0.2), _srgb(0.6), 1.0], [0.0, 0.0, _srgb(0.002)]]
    np.testing.assert_allclose(got[0], want, rtol=1e-12)
    # Alpha is dropped.
    rgba = np.concatenate([image, np.full((1, 2, 1), 0.5)], axis=-1)
    np.testing.assert_array_equal(display(rgba, 2.0), got)


def test_frame_exposure_is_over_the_whole_frame():
    gt = np.zeros((10, 10, 3))
    gt[..., 1] = np.arange(100).reshape(10, 10) / 99.0  # green is the brightest channel
    assert frame_exposure(gt) == pytest.approx(1.0 / np.percentile(gt[..., 1], 99.0))
    assert frame_exposure(np.zeros((3, 3, 4))) == 1.0


def test_a_constant_offset_gives_the_psnr_by_hand():
    # Ground truth 0.25 everywhere except one bright pixel row that sets p99 to 1.
    gt = np.full((100, 100, 3), 0.25)
    gt[:2] = 1.0
    k = frame_exposure(gt)
    assert k == pytest.approx(1.0)
    test = gt + 0.05  # the bright rows clip to 1 and do not differ on a display
    # By hand: 98 % of the pixels differ by srgb(0.30) - srgb(0.25) in every channel.
    step = _srgb(0.30) - _srgb(0.25)
    want = -10 * math.log10(0.98 * step**2)
    assert psnr_display(test, gt, k) == pytest.approx(want, rel=1e-9)
    # On the dim pixels alone the error is the step everywhere.
    dim = np.zeros((100, 100), bool)
    dim[2:] = True
    assert psnr_display(test, gt, k, dim) == pytest.approx(-20 * math.log10(step), rel=1e-9)
    assert psnr_display(gt, gt, k) == PSNR_CAP_DB
    assert math.isnan(psnr_display(test, gt, k, np.zeros((100, 100), bool)))
    with pytest.raises(ValueError, match="pixels"):
        psnr_display(test[:50], gt, k)


def test_the_mask_is_one_percent_of_the_peak():
    gt_off = np.full((4, 5, 3), 0.5)
    gt_off[0, 0] = 2.0
    gt = gt_off.copy()
    k = 1.0 / 2.0  # the peak is 2
    gt[1, 1, 2] += 0.019  # 0.95 % of the peak: not subsurface
    gt[2, 2, 0] -= 0.021  # 1.05 %, darker: subsurface
    gt[3, 3] += 0.5
    mask = subsurface_mask(gt, gt_off, k)
    want = np.zeros((4, 5), bool)
    want[2, 2] = want[3, 3] = True
    np.testing.assert_array_equal(mask, want)


def test_the_effect_equal_to_cycles_is_capped_and_an_error_costs_by_hand(rng):
    gt_off = rng.random((20, 30, 3)) + 0.1
    d_gt = rng.random((20, 30, 3)) * 0.2
    gt = gt_off + d_gt
    mask = np.ones((20, 30), bool)
    k = 0.5
    # The engine's frame changes by exactly Cycles' change: nothing to tell apart.
    assert effect_db(gt, gt_off, gt, gt_off, mask, k) == PSNR_CAP_DB
    # A change 0.01 too large everywhere: MSE = (k * 0.01)^2.
    frame = gt + 0.01
    want = -10 * math.log10((0.5 * 0.01) ** 2)
    assert effect_db(frame, gt_off, gt, gt_off, mask, k) == pytest.approx(want)
    # No subsurface pixel, no figure.
    assert math.isnan(effect_db(frame, gt_off, gt, gt_off, ~mask, k))


def test_the_scale_cancels_a_global_lighting_factor(rng):
    gt_off = rng.random((16, 16, 3)) + 0.05
    d_gt = rng.random((16, 16, 3)) * 0.3
    gt = gt_off + d_gt
    mask = rng.random((16, 16)) < 0.5
    # An engine that lights everything 40 % darker but scatters exactly like Cycles.
    frame_off, frame = 0.6 * gt_off, 0.6 * gt
    assert lighting_scale(gt_off, frame_off, mask) == pytest.approx(1 / 0.6)
    assert effect_db(frame, frame_off, gt, gt_off, mask, k=1.0) >= 90.0
    # Without the scale the darker engine's effect is 40 % short: a finite figure.
    assert effect_db(frame, frame_off, gt, gt_off, mask, k=1.0, s=1.0) < 40.0
    # Its frame, compared on a display, is far off.
    assert psnr_display(frame, gt, frame_exposure(gt)) < 20.0
    assert math.isnan(lighting_scale(gt_off, np.zeros_like(gt_off), mask))
    assert math.isnan(lighting_scale(gt_off, frame_off, np.zeros((16, 16), bool)))


def test_frame_figures_share_one_exposure(rng):
    gt_off = rng.random((40, 60, 3)) * 0.5
    gt = gt_off.copy()
    gt[10:20, 10:30] += 0.3  # the subsurface region
    frame = gt.copy()
    frame[:, 40:] += 0.02  # off only where subsurface does not reach
    figures = frame_figures(frame, gt, gt_off, frame_off=gt_off)
    k = frame_exposure(gt)
    assert figures.exposure == k
    assert figures.subsurface_share == pytest.approx(200 / 2400)
    assert figures.psnr_subsurface_db == PSNR_CAP_DB
    assert figures.effect_db == PSNR_CAP_DB
    assert figures.lighting_scale == pytest.approx(1.0)
    rest = np.ones((40, 60), bool)
    rest[10:20, 10:30] = False
    assert figures.psnr_rest_db == pytest.approx(psnr_display(frame, gt, k, rest))
    assert figures.psnr_whole_db == pytest.approx(psnr_display(frame, gt, k))
    # The whole-frame figure averages the rest with perfect subsurface pixels.
    assert figures.psnr_whole_db > figures.psnr_rest_db
    # Without a frame without subsurface there is no effect.
    assert math.isnan(frame_figures(frame, gt, gt_off).effect_db)


def test_mean_figures_leave_out_nan(rng):
    gt_off = rng.random((8, 8, 3))
    gt = gt_off + 0.2
    a = frame_figures(gt + 0.01, gt, gt_off)
    b = frame_figures(gt + 0.02, gt, gt_off, frame_off=gt_off)
    mean = mean_figures([a, b])
    assert mean["psnr_whole_db"] == pytest.approx((a.psnr_whole_db + b.psnr_whole_db) / 2)
    assert mean["effect_db"] == pytest.approx(b.effect_db)
    assert mean_figures([]) == {}


def test_object_errors_split_the_subsurface_pixels_by_hand():
    # Ground truth 0.25, with subsurface everywhere but the last column (0.25 off, the
    # same there); the bright first row sets p99, so k = 1.
    gt = np.full((6, 5, 3), 0.25)
    gt[0] = 1.0
    gt_off = np.full((6, 5, 3), 0.2)
    gt_off[0] = 0.9
    gt_off[:, 4] = gt[:, 4]
    objects = np.zeros((6, 5), int)
    objects[1:3] = 3  # object 3: rows 1-2 (8 subsurface pixels)
    objects[3:] = 7  # object 7: rows 3-5 (12)
    frame = gt.copy()
    frame[1:3] = 0.30  # off by srgb(0.30) - srgb(0.25) in each channel
    frame[3:, :, 0] = 0.20  # off in red only: a third of that channel's square
    frame[5, 4] = 0.9  # not a subsurface pixel: counts nowhere
    got = object_errors(frame, gt, gt_off, objects)
    assert sorted(got) == [0, 3, 7]  # row 0 (object 0) differs by 0.1: subsurface
    assert got[0] == {"pixels": 4, "display_sse": 0.0, "effect_sse": got[0]["effect_sse"]}
    assert got[3]["pixels"] == 8 and got[7]["pixels"] == 12
    up = (_srgb(0.30) - _srgb(0.25)) ** 2
    down = (_srgb(0.20) - _srgb(0.25)) ** 2 / 3
    assert got[3]["display_sse"] == pytest.approx(8 * up, rel=1e-9)
    assert got[7]["display_sse"] == pytest.approx(12 * down, rel=1e-9)
    assert math.isnan(got[3]["effect_sse"])  # no frame without subsurface given
    # The effect: an engine lit alike (s = 1) whose change is 0.01 too large on object 3.
    frame_off = gt_off.copy()
    frame2 = gt.copy()
    frame2[1:3] += 0.01
    effect = object_errors(frame2, gt, gt_off, objects, frame_off)
    assert effect[3]["effect_sse"] == pytest.approx(8 * 0.01**2, rel=1e-6)
    assert effect[7]["effect_sse"] == pytest.approx(0.0, abs=1e-20)
    # The frame's own figures, passed in, give the same sums (their exposure and scale).
    figures = frame_figures(frame2, gt, gt_off, frame_off)
    assert object_errors(frame2, gt, gt_off, objects, frame_off, figures) == effect
    # An object's PSNR from its sums: object 3 alone, as psnr_display on its pixels.
    k = frame_exposure(gt)
    alone = psnr_display(frame, gt, k, objects == 3)
    assert -10 * math.log10(got[3]["display_sse"] / 8) == pytest.approx(alone, rel=1e-9)
    with pytest.raises(ValueError, match="objects"):
        object_errors(frame, gt, gt_off, objects[:3])

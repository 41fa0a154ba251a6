"""Metrics: the ground-truth PSNR and its exposure rule, channel and rim ratios, silhouettes."""

import numpy as np
import pytest

from cvsss.core.color import srgb_encode
from cvsss.core.eval.metrics import (
    PSNR_CAP_DB,
    channel_ratio,
    gt_exposure,
    psnr_gt,
    silhouette,
)


def test_gt_exposure_is_one_over_p99_of_the_brightest_channel(rng):
    gt = rng.random((50, 40, 3)) * [1.0, 2.0, 0.5]
    k = gt_exposure(gt)
    assert k == pytest.approx(1.0 / np.percentile(gt.max(axis=-1), 99.0))
    # A single firefly does not decide it.
    gt[0, 0] = 1e6
    assert gt_exposure(gt) == pytest.approx(k, rel=0.05)
    assert gt_exposure(np.zeros((4, 4, 3))) == 1.0


def test_psnr_gt_by_hand(rng):
    gt = rng.random((30, 20, 3)) * 4.0
    ours = gt * 1.1
    mask = np.zeros((30, 20), bool)
    mask[5:25, 3:17] = True
    k = gt_exposure(gt[mask])
    mse = np.mean((srgb_encode(ours[mask] * k) - srgb_encode(gt[mask] * k)) ** 2)
    assert psnr_gt(ours, gt, mask) == pytest.approx(10 * np.log10(1 / mse))
    assert psnr_gt(gt, gt, mask) == PSNR_CAP_DB
    assert np.isnan(psnr_gt(ours, gt, np.zeros_like(mask)))
    # The whole image is another figure (its own exposure).
    assert psnr_gt(ours, gt) != pytest.approx(psnr_gt(ours, gt, mask))
    # Scale invariant: the exposure follows the ground truth.
    assert psnr_gt(ours * 7, gt * 7, mask) == pytest.approx(psnr_gt(ours, gt, mask))
    # RGB, not luminance: a colour shift of equal luminance still costs.
    shifted = gt.copy()
    shifted[..., 0] *= 1.2
    shifted[..., 1] -= 0.2126 * 0.2 * gt[..., 0] / 0.7152
    assert psnr_gt(shifted, gt, mask) < 40


def test_channel_ratio():
    gt = np.ones((4, 4, 3)) * [1.0, 2.0, 4.0]
    ours = gt * [1.08, 1.0, 0.5]
    mask = np.ones((4, 4), bool)
    np.testing.assert_allclose(channel_ratio(ours, gt, mask), [1.08, 1.0, 0.5])
    assert np.isnan(channel_ratio(ours, gt, ~mask)).all()


def test_silhouette_finds_edges_not_the_border():
    mat = np.zeros((8, 10), np.int32)
    mat[2:6, 3:8] = 1
    depth = np.full((8, 10), 2.0)
    depth[mat == 0] = np.inf
    mask = mat > 0
    rim = silhouette(mask, mat, depth)
    inner = np.zeros_like(mask)
    inner[3:5, 4:7] = True
    np.testing.assert_array_equal(rim, mask & ~inner)
    # The image border is not a silhouette; a depth step is.
    full = np.ones((5, 5), bool)
    z = np.full((5, 5), 2.0)
    assert not silhouette(full, full.astype(int), z).any()
    z[:, 3:] = 3.0
    assert silhouette(full, full.astype(int), z)[:, 2:4].all()


def test_edge_kinds_partition_the_silhouette():
    """A block (material 1) on a table (material 2) before the background: the block's
    top is an outer silhouette, its foot a contact edge, the table behind its sides is
    occluded by it; the kinds partition silhouette()."""
    from cvsss.core.eval.metrics import EDGE_KINDS, edge_kinds

    mat = np.full((10, 12), 2, np.int32)
    mat[:3] = 0  # background above the table
    depth = np.full((10, 12), 4.0)
    depth[:3] = np.inf
    mat[2:7, 4:8] = 1  # the block stands on the table, in front of it
    depth[2:7, 4:8] = 3.0
    depth[7:, :] = 3.0  # the table's front edge, at the block's depth
    mask = mat > 0
    kinds = edge_kinds(mask, mat, depth)
    assert tuple(kinds) == EDGE_KINDS
    union = np.zeros_like(mask)
    for a in EDGE_KINDS:
        for b in EDGE_KINDS:
            if a != b:
                assert not (kinds[a] & kinds[b]).any()
        union |= kinds[a]
    np.testing.assert_array_equal(union, silhouette(mask, mat, depth))
    assert kinds["outer"][2, 5] and kinds["outer"][3, 4]  # block top, block side (table behind)
    assert kinds["occluded"][4, 3]  # the table next to the block, covered by it
    assert kinds["contact"][7, 5] and kinds["contact"][6, 5]  # the block's foot on the table

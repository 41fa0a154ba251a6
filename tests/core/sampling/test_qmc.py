import numpy as np

from cvsss.core.sampling import pcg3d, pixel_offsets, r2_points


def test_pcg3d_reference_value():
    # Value of the reference GLSL pcg3d (Jarzynski & Olano 2020) for (0, 0, 0),
    # computed with Python integers modulo 2**32.
    assert [int(v) for v in pcg3d(np.uint32(0), np.uint32(0), np.uint32(0))] == [
        2611992518,
        2833812075,
        1058359340,
    ]


def test_offsets_deterministic_and_decorrelated():
    x = np.arange(64 * 64) % 64
    y = np.arange(64 * 64) // 64
    a = pixel_offsets(x, y, 3, 42)
    b = pixel_offsets(x, y, 3, 42)
    c = pixel_offsets(x, y, 4, 42)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert not np.array_equal(a[0], c[0])
    # Uniform on [0, 1): mean ~ 0.5, neighbouring pixels uncorrelated.
    assert abs(a[0].mean() - 0.5) < 0.02
    assert abs(np.corrcoef(a[0][:-1], a[0][1:])[0, 1]) < 0.05


def test_r2_is_low_discrepancy():
    k = np.arange(1, 257)
    u, v = r2_points(np.zeros(256), np.zeros(256), k)
    assert np.all((u >= 0) & (u < 1) & (v >= 0) & (v < 1))
    # Every cell of an 8x8 grid receives 4 ± 2 of 256 R2 points.
    h, _, _ = np.histogram2d(u, v, bins=8, range=[[0, 1], [0, 1]])
    assert h.min() >= 2 and h.max() <= 6


def test_direction_table_bins_are_uniform_and_symmetric():
    """The sampler's 4096 directions: unit vectors at the bin centres, the top 12 bits
    of the angle coordinate select the bin, and every bin is equally likely."""
    from cvsss.core.sampling.qmc import DIRECTION_BITS, DIRECTIONS, r2_fixed

    bins = 1 << DIRECTION_BITS
    assert DIRECTIONS.shape == (bins, 2) and DIRECTIONS.dtype == np.float32
    np.testing.assert_allclose(np.hypot(DIRECTIONS[:, 0], DIRECTIONS[:, 1]), 1.0, atol=1e-6)
    # A symmetric set: the mean direction and the mean of cos 2θ, sin 2θ vanish.
    assert np.abs(DIRECTIONS.mean(axis=0)).max() < 1e-6
    theta = np.arctan2(DIRECTIONS[:, 1].astype(np.float64), DIRECTIONS[:, 0])
    assert abs(np.cos(2 * theta).mean()) < 1e-6
    # Bin i covers the angle coordinates [i, i + 1)/bins; its direction is the centre.
    centre = 2 * np.pi * (np.arange(bins) + 0.5) / bins
    np.testing.assert_allclose(np.mod(theta, 2 * np.pi), centre, atol=1e-6)
    # The R2 angle coordinates of one pixel's 4096 samples fill the bins evenly.
    _, v = r2_fixed(np.uint32(12345), np.uint32(678), np.arange(1, bins + 1))
    counts = np.bincount((v >> np.uint32(32 - DIRECTION_BITS)).astype(np.int64), minlength=bins)
    assert counts.max() <= 2

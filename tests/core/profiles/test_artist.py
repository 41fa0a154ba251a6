"""Artist-friendly profile (Jimenez et al. 2015): sampler, γ = c, fits, Eq. 17 against the dipole."""

import numpy as np
import pytest

from cvsss.core.profiles import ArtistProfile, DipoleProfile, presets
from cvsss.core.profiles.artist import KEEP_SIGMAS, distant_mean, eq17_strength, from_radial
from cvsss.core.profiles.radial import RadialModel, radial_model
from cvsss.core.synthetic import flat_plane

from helpers import assert_radii_follow_cdf, shade


def artist(
    strength=(0.6, 0.5, 0.4),
    near=(0.01, 0.006, 0.003),
    far=(0.04, 0.02, 0.01),
    weight=(0.5, 0.6, 0.7),
) -> ArtistProfile:
    pad = lambda v, fill: np.array([[fill] * 3, v], dtype=np.float64)  # noqa: E731
    return ArtistProfile(pad(strength, 0.0), pad(near, 1.0), pad(far, 1.0), pad(weight, 1.0))


def test_pdf_integrates_to_one_and_matches_cdf():
    prof = artist()
    rmax = prof.support(1)
    assert np.allclose(rmax, KEEP_SIGMAS * np.array([0.04, 0.02, 0.01]))
    r = np.linspace(0.0, rmax.max(), 200_001)
    p = prof.radial_pdf(r, 1)
    for c in range(3):
        inside = r <= rmax[c]
        y, x = p[c][inside], r[inside]
        assert np.sum(0.5 * (y[1:] + y[:-1]) * np.diff(x)) == pytest.approx(1.0, abs=1e-6)
    cum = np.concatenate(
        [np.zeros((3, 1)), np.cumsum(0.5 * (p[:, 1:] + p[:, :-1]) * np.diff(r), axis=1)], axis=1
    )
    assert np.max(np.abs(np.minimum(cum, 1.0) - prof.radial_cdf(r, 1))) < 1e-6
    # pdf_channels (float32, estimator layout) agrees with the float64 radial pdf.
    rs = np.linspace(0.0, 0.15, 997).astype(np.float32)
    fast = prof.pdf_channels(rs, np.ones(rs.size, np.int32))
    assert np.allclose(fast, prof.radial_pdf(rs.astype(np.float64), 1), rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize(("channel", "r0"), [(0, 0.0), (0, 0.012), (2, 0.004)])
def test_sampler_chi_square(channel, r0):
    """Exact two-component sampler of the distant region against the CDF (fixed seed)."""
    prof = artist()
    region = prof.region(np.array([r0]), np.array([1]))
    assert 0.0 < region.hi[0, channel] < 1.0  # both Gaussians take part
    n = 200_000
    rng = np.random.default_rng(5 + channel)
    u = rng.random(n).astype(np.float32)
    r = prof.sample(
        u,
        np.full(n, region.lo[0, channel], np.float32),
        np.full(n, region.hi[0, channel], np.float32),
        np.ones(n, np.int32),
        np.full(n, channel),
    )
    rmax = prof.support(1)[channel]
    assert r.min() >= r0 - 1e-7 and r.max() <= rmax * (1 + 1e-6)
    edges = np.linspace(r0, rmax, 61)
    assert_radii_follow_cdf(prof, r, edges, channel)


def test_gamma_is_strength_and_weight_scale_depends_on_pixel():
    prof = artist()
    assert prof.pixel_weight_scale
    r0 = np.array([0.0, 0.005, 0.04, 1.0])
    reg = prof.region(r0, np.ones(r0.size, np.int32))
    assert np.allclose(reg.gamma[:2], [0.6, 0.5, 0.4])
    assert np.allclose(reg.gamma[2], [0.6, 0.5, 0.0])  # r0 beyond the blue support (0.034)
    assert np.all(reg.gamma[3] == 0)
    # γ/mass grows as the distant region shrinks: a per-pixel weight scale.
    assert reg.weight_scale[1, 0] > reg.weight_scale[0, 0] > 0
    assert np.allclose(prof.direct_weight(1), [0.4, 0.5, 0.6])
    assert not prof.scatters()[0] and prof.scatters()[1] and prof.chromatic()[1]


def test_validation():
    with pytest.raises(ValueError, match="strength must be in"):
        artist(strength=(1.5, 0.5, 0.5))
    with pytest.raises(ValueError, match="near must be in"):
        artist(near=(0.0, 0.01, 0.01))
    with pytest.raises(ValueError, match="weight must be in"):
        artist(weight=(0.5, -0.1, 0.5))


def test_from_radial_recovers_three_gaussians():
    """Fitting 3 Gaussians and dropping the narrowest recovers the other two."""
    w = np.array([0.2, 0.5, 0.3])
    sd = np.array([0.002, 0.01, 0.03])
    rmax = KEEP_SIGMAS * sd[-1] * 1.2

    def pdf(r):
        r = np.asarray(r, dtype=np.float64)
        p = sum(wi * r / s**2 * np.exp(-r * r / (2 * s**2)) for wi, s in zip(w, sd))
        return np.tile(np.where(r <= rmax, p, 0.0), (3, 1))

    def cdf(r):
        r = np.minimum(np.asarray(r, dtype=np.float64), rmax)
        return np.tile(sum(wi * -np.expm1(-r * r / (2 * s**2)) for wi, s in zip(w, sd)), (3, 1))

    p = from_radial(RadialModel(pdf, cdf, np.full(3, rmax), np.zeros(3)))
    assert np.allclose(p["strength"], 0.8, atol=0.02)
    assert np.allclose(p["near"], 0.01, rtol=0.05)
    assert np.allclose(p["far"], 0.03, rtol=0.05)
    assert np.allclose(p["weight"], 0.5 / 0.8, atol=0.03)


# -- through the unified estimator ---------------------------------------------------------
def run(frame, prof, counts, seed=0):
    return shade(frame, counts, prof, seed=seed)


#: ~4.5 / 2.7 / 1.3 px (near) and 18 / 9 / 4.5 px (far) at 2 m, 64 px wide.
PLANE = dict(near=(0.1, 0.06, 0.03), far=(0.4, 0.2, 0.1))


@pytest.mark.parametrize("m", [0, 1, 7, 64])
def test_constant_lighting_is_exact(m):
    b = np.full((48, 64, 3), [0.3, 0.7, 1.9], np.float32)
    frame = flat_plane(lighting=b)
    geom, est, shaded = run(frame, artist(**PLANE), m)
    assert geom.size == 48 * 64
    assert np.max(np.abs(shaded - b.reshape(-1, 3)[0])) <= 1e-12 * 1.9
    assert est.samples == m * geom.size


def test_unbiased_on_flat_plane():
    """8-spp estimates averaged over seeds match a 2048-spp reference (row-averaged edge profile)."""
    x = np.arange(64)[None, :, None]
    b = (
        np.broadcast_to(np.where(x < 32, 0.05, 1.0), (16, 64, 3)) * np.array([1.0, 0.8, 0.6])
    ).astype(np.float32)
    frame = flat_plane(64, 16, lighting=b)
    prof = artist(**PLANE)
    seeds = 40
    runs = np.stack(
        [run(frame, prof, 8, seed=s)[2].reshape(16, 64, 3).mean(axis=0) for s in range(seeds)]
    )
    ref = run(frame, prof, 2048, seed=10_000)[2].reshape(16, 64, 3).mean(axis=0)
    mean = runs.mean(axis=0)
    se = runs.std(axis=0, ddof=1) / np.sqrt(seeds)
    assert np.mean(np.abs(mean - ref) <= 4 * se + 5e-4) >= 0.99
    assert np.max(np.abs(ref - b[0])) > 0.05


# -- consistency with the dipole (P Eq. 17) ---------------------------------------------------
def _skin1(single: bool):
    m = presets.get("skin1")
    return DipoleProfile(
        np.array([[0.0] * 3, m.sigma_a]),
        np.array([[0.0] * 3, m.sigma_s]),
        m.eta,
        unit=1e-3,
        single_scattering=single,
    )


def _edge(x0: float):
    return lambda dx, dy: np.where((dx + x0)[:, None] < 0, 0.1, 1.0) * np.ones((1, 3))


def test_eq17_against_the_dipole():
    dipole = _skin1(True)
    p = from_radial(radial_model(_skin1(False), 1))  # R_ms − R_G0 of skin1
    art = ArtistProfile(
        np.array([[0.0] * 3, p["strength"]]),
        np.array([[1.0] * 3, p["near"]]),
        np.array([[1.0] * 3, p["far"]]),
        np.array([[1.0] * 3, p["weight"]]),
    )
    assert np.all((p["strength"] > 0.5) & (p["strength"] < 1.0))
    b = np.array([1.0, 1.0, 1.0])
    strengths = {}
    for r0 in (0.2e-3, 1e-3):  # pixel footprints of a close-up and a medium shot
        for x0 in (-2e-3, -0.5e-3, 0.0, 0.5e-3, 2e-3):  # distance to a shadow edge
            light = _edge(x0)
            gd, lsd = distant_mean(dipole, 1, r0, light)
            ga, lsa = distant_mean(art, 1, r0, light)
            c = eq17_strength(gd, b, lsd, lsa)
            # Eq. 17's c makes the artist-friendly result equal the dipole's.
            assert np.allclose((1 - c) * b + c * lsa, (1 - gd) * b + gd * lsd, atol=1e-12)
            # With the dipole as its own "artist" model Eq. 17 gives γ_d.
            assert np.allclose(eq17_strength(gd, b, lsd, lsd), gd)
            strengths[r0, x0] = c
        # On the edge itself both distant averages are the mean of the two sides: c = γ_d.
        assert np.allclose(strengths[r0, 0.0], gd, atol=1e-9)
    # A constant strength cannot be consistent at every resolution: the
    # consistent c follows γ_d = 1 − cdf_d(r0), which drops with the footprint.
    assert np.all(strengths[0.2e-3, 0.0] - strengths[1e-3, 0.0] > 0.2)
    # Linear lighting: E[B] = B for both, every c is consistent (0/0).
    ramp = lambda dx, dy: (0.5 + 10.0 * dx)[:, None] * np.ones((1, 3))  # noqa: E731
    gd, lsd = distant_mean(dipole, 1, 1e-3, ramp)
    _, lsa = distant_mean(art, 1, 1e-3, ramp)
    assert np.allclose(lsd, 0.5, atol=1e-9) and np.allclose(lsa, 0.5, atol=1e-9)
    assert np.all(np.isnan(eq17_strength(gd, np.full(3, 0.5), lsd, lsa)))

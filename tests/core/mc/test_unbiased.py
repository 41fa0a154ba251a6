"""The distant estimator is unbiased for the integral it defines: checked by quadrature.

On a fronto-parallel single-material plane the estimator (docs/explanation/design.md §5) defines,
per SSS pixel p and channel c,

    L_c(p) = (1 − γ_c)·B_c(p) + γ_c·∫_{r0}^{r_max} p̂_c(r)·(1/2π)∫ B_c(q(r, θ)) dθ dr,

with p̂_c the channel's radial pdf renormalised on the distant region,
``q(r, θ)`` the pixel nearest to ``p + (r cos θ / w, r sin θ / h)`` (w, h the
footprint at p) and ``B(q) = B(p)`` when q is off screen. This test evaluates
that integral by deterministic quadrature (equal-mass cells in r from the
profile's CDF, midpoints in θ) — independently of the sampler, the channel
mixture and the weights — and checks that the mean of the 16-spp estimator
over 64 seeds (1024 samples per pixel) agrees, for Burley, the dipole and the
artist-friendly profile, each with one profile for all channels and with
different ones per channel.

Tolerances: each pixel and channel within 4.5 standard errors of the mean
(the quadrature's own error is under 0.1 SE, checked below), and the
least-squares slope of the estimated scattering (mean − B) on the
quadrature's (L − B) over all pixels and channels within 4 standard errors
of 1 (its standard error is 0.5–1 %: a systematic over- or under-scattering
of 3 % fails). Ordinary least squares on purpose: weighting by the estimated
variances biases the slope low, since runs with a rare bright sample have both
a higher mean and a higher variance.
"""

from __future__ import annotations

import numpy as np
import pytest

from cvsss.core.eval.metrics import silhouette
from cvsss.core.frame import MaterialSpec
from cvsss.core.geometry import geometry_of, surface
from cvsss.core.params import SSSParams
from cvsss.core.profiles import burley
from cvsss.core.profiles.factory import frame_profile
from cvsss.core.profiles.radial import radial_model
from cvsss.core.synthetic import flat_plane, sphere, tilted_plane

from helpers import shade

W, H = 64, 48
SEEDS = 64
SPP = 16
PIXELS = 24
R_CELLS = 1200
THETAS = 512

#: name -> (profile kind, Burley d in metres, options); the plane is at 2 m, 0.0225 m/px.
CASES = {
    "burley": ("burley", (0.012, 0.012, 0.012), {}),
    "burley-chromatic": ("burley", (0.02, 0.008, 0.003), {}),
    "dipole": (
        "dipole",
        (0.01,) * 3,
        {"sigma_a": [0.02] * 3, "sigma_s": [1.0] * 3, "eta": 1.3, "scale": 20.0},
    ),
    "dipole-chromatic": ("dipole", (0.01,) * 3, {"preset": "skin1", "scale": 20.0}),
    "artist": (
        "artist",
        (0.01,) * 3,
        {"strength": [0.7] * 3, "near": [0.015] * 3, "far": [0.05] * 3, "weight": [0.6] * 3},
    ),
    "artist-chromatic": (
        "artist",
        (0.01,) * 3,
        {
            "strength": [0.8, 0.6, 0.4],
            "near": [0.02, 0.012, 0.006],
            "far": [0.07, 0.04, 0.02],
            "weight": [0.5, 0.6, 0.7],
        },
    ),
}


def lighting() -> np.ndarray:
    """A shadow edge, a diagonal stripe and a smooth texture, three different channels."""
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    edge = np.where(x < W // 2, 0.08, 1.0)
    stripe = np.where(np.abs((x - y) - 6.0) < 3.0, 0.25, 1.0)
    texture = 0.8 + 0.2 * np.sin(x / 3.1) * np.cos(y / 4.3)
    base = edge * stripe * texture
    return np.stack([base, 0.9 * base**1.2, 0.7 * base + 0.05], axis=-1).astype(np.float32)


def plane(case: str):
    kind, d, options = CASES[case]
    frame = flat_plane(W, H, d=d, lighting=lighting())
    frame.materials[1] = MaterialSpec(1, "plane", d, profile=kind, options=options)
    return frame


def burley_model_cdf(d: np.ndarray, truncate: float = 16.0):
    """The truncated, renormalised Burley CDF per channel, closed form (docs/explanation/design.md §4)."""

    def cdf(r):
        r = np.asarray(r, dtype=np.float64)[None, :]
        rr = np.minimum(r, truncate * d[:, None])
        c = 1 - 0.25 * np.exp(-rr / d[:, None]) - 0.75 * np.exp(-rr / (3 * d[:, None]))
        total = 1 - 0.25 * np.exp(-truncate) - 0.75 * np.exp(-truncate / 3)
        return c / total

    return cdf, truncate * d


def quadrature(frame, profile, geom, pixels: np.ndarray) -> np.ndarray:
    """(len(pixels), 3) L by quadrature over r and θ (see module doc)."""
    kind = frame.materials[1].profile
    if kind == "burley":
        cdf, rmax = burley_model_cdf(np.asarray(frame.materials[1].d))
    else:
        model = radial_model(profile, 1)
        cdf, rmax = model.cdf, model.rmax
    light = frame.lighting.reshape(-1, 3).astype(np.float64)
    theta = (np.arange(THETAS) + 0.5) * (2 * np.pi / THETAS)
    cos_t, sin_t = np.cos(theta), np.sin(theta)
    out = np.zeros((pixels.size, 3))
    for i, k in enumerate(pixels):
        x, y, r0 = geom.x[k], geom.y[k], geom.r0[k]
        b = light[geom.index[k]]
        for c in range(3):
            gamma = geom.gamma[k, c]
            if gamma == 0 or r0 >= rmax[c]:
                out[i, c] = b[c]
                continue
            # Equal-mass cells of the channel's pdf on [r0, r_max], from its CDF.
            grid = np.concatenate(
                [np.geomspace(r0, rmax[c], 20000), np.linspace(r0, rmax[c], 20000)]
            )
            grid = np.unique(grid)
            mass = cdf(grid)[c]
            levels = np.linspace(mass[0], mass[-1], R_CELLS + 1)
            edges = np.interp(levels, mass, grid)
            mid = np.interp(0.5 * (levels[1:] + levels[:-1]), mass, grid)
            del edges
            qx = np.rint(x + mid[:, None] * cos_t[None, :] / geom.fw[k]).astype(np.int64)
            qy = np.rint(y + mid[:, None] * sin_t[None, :] / geom.fh[k]).astype(np.int64)
            inside = (qx >= 0) & (qx < W) & (qy >= 0) & (qy < H)
            value = np.where(inside, light[np.where(inside, qy * W + qx, geom.index[k]), c], b[c])
            out[i, c] = (1 - gamma) * b[c] + gamma * value.mean()
    return out


@pytest.fixture(scope="module", params=list(CASES))
def case(request):
    frame = plane(request.param)
    profile = frame_profile(frame, SSSParams())
    geom = geometry_of(frame, profile)
    rng = np.random.default_rng(20211)
    # Pixels within 8 px of the shadow edge or on the stripe, where the estimate is not trivial.
    near = np.flatnonzero((np.abs(geom.x - W // 2) <= 8) | (np.abs((geom.x - geom.y) - 6) <= 5))
    pixels = np.sort(rng.choice(near, PIXELS, replace=False))
    runs = np.stack([shade(frame, SPP, profile, seed=s)[2][pixels] for s in range(SEEDS)])
    return request.param, frame, profile, geom, pixels, runs


def assert_unbiased(name, runs, expected, b, max_slope_se):
    """Every pixel's mean within 4.5 standard errors of ``expected``, and the scattered
    part (estimate − B against quadrature − B) with slope 1 within 4 of its standard
    errors, that standard error below ``max_slope_se``. Returns (mean, se, active)."""
    mean = runs.mean(axis=0)
    se = runs.std(axis=0, ddof=1) / np.sqrt(SEEDS)
    active = se > 0
    z = (mean - expected)[active] / se[active]
    assert np.all(np.abs(z) <= 4.5), (name, float(np.abs(z).max()))
    e, m, s = (expected - b)[active], (mean - b)[active], se[active]
    slope = float(np.sum(e * m) / np.sum(e * e))
    slope_se = float(np.sqrt(np.sum(e * e * s * s)) / np.sum(e * e))
    assert slope_se < max_slope_se, (name, slope_se)
    assert abs(slope - 1.0) <= 4 * slope_se, (name, slope, slope_se)
    return mean, se, active


def test_estimator_is_unbiased_against_quadrature(case):
    name, frame, profile, geom, pixels, runs = case
    expected = quadrature(frame, profile, geom, pixels)
    b = frame.lighting.reshape(-1, 3)[geom.index[pixels]]
    # Not trivially equal to the unscattered lighting: scattering moved energy.
    assert np.max(np.abs(expected - b)) > 0.02, name
    _, _, active = assert_unbiased(name, runs, expected, b, 0.012)
    assert active.mean() > 0.9, name  # the estimate is doing something on these pixels


def test_quadrature_is_converged():
    """Halving the quadrature's resolution moves it by far less than the estimator's error."""
    global R_CELLS, THETAS
    frame = plane("burley-chromatic")
    profile = frame_profile(frame, SSSParams())
    geom = geometry_of(frame, profile)
    pixels = np.flatnonzero(np.abs(geom.x - W // 2) <= 1)[:6]
    fine = quadrature(frame, profile, geom, pixels)
    saved = R_CELLS, THETAS
    try:
        R_CELLS, THETAS = R_CELLS // 2, THETAS // 2
        coarse = quadrature(frame, profile, geom, pixels)
    finally:
        R_CELLS, THETAS = saved
    runs = np.stack([shade(frame, SPP, profile, seed=s)[2][pixels] for s in range(SEEDS)])
    se = runs.std(axis=0, ddof=1) / np.sqrt(SEEDS)
    assert np.max(np.abs(fine - coarse)) < 0.1 * np.min(se[se > 0])


def test_burley_closed_form_matches_the_profile():
    """The quadrature's Burley CDF is the design's (§4), independent of core.profiles.burley."""
    d = np.array([0.02, 0.008, 0.003])
    cdf, rmax = burley_model_cdf(d)
    r = np.linspace(0, 0.4, 101)
    total = 1 - 0.25 * np.exp(-16.0) - 0.75 * np.exp(-16.0 / 3)
    expected = burley.cdf(np.minimum(r[None, :], 16 * d[:, None]), d[:, None]) / total
    np.testing.assert_allclose(cdf(r), expected, rtol=1e-12, atol=1e-15)


# -- surface distances: tilted plane and sphere -----------------------------------------------
SURFACE_CASES = {
    "tilted-plane": lambda light: tilted_plane(
        W, H, tilt=60.0, d=(0.02, 0.008, 0.003), lighting=light
    ),
    "sphere": lambda light: sphere(W, H, radius=0.45, d=(0.02, 0.008, 0.003), lighting=light),
}


def _points(camera, depth):
    """Camera-space points of the pixel centres (the test's own reconstruction)."""
    wu, hu = camera.unit_footprint()
    cx, cy = camera.principal_point
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    z = depth.astype(np.float64)
    return np.stack([(xx - cx) * wu * z, (yy - cy) * hu * z, z], axis=-1)


def _side(p, axis):
    """The test's own step between pixel points along ``axis``: central where both
    neighbours continue the surface (depth steps within 2x), else the side with the
    smaller depth step."""
    fwd = np.full_like(p, np.nan)
    bwd = np.full_like(p, np.nan)
    if axis == 1:
        fwd[:, :-1] = bwd[:, 1:] = p[:, 1:] - p[:, :-1]
    else:
        fwd[:-1] = bwd[1:] = p[1:] - p[:-1]
    with np.errstate(invalid="ignore"):
        fwd[~np.isfinite(fwd).all(-1)] = np.nan
        bwd[~np.isfinite(bwd).all(-1)] = np.nan
        af, ab = np.abs(fwd[..., 2]), np.abs(bwd[..., 2])
        pick = np.isnan(af) | (ab < af)
        both = np.isfinite(af + ab) & (
            np.maximum(af, ab) <= 2 * np.minimum(af, ab) + 1e-6 * p[..., 2]
        )
    return np.where(both[..., None], (fwd + bwd) / 2, np.where(pick[..., None], bwd, fwd))


def _pixel_area(p):
    """Area per pixel from the cross product of the test's own steps (:func:`_side`)."""
    with np.errstate(invalid="ignore"):
        return np.linalg.norm(np.cross(_side(p, 1), _side(p, 0)), axis=-1)


def _normals(p):
    """Unit normals of the test's own pixel patches, towards the camera (float64)."""
    with np.errstate(invalid="ignore"):
        n = np.cross(_side(p, 1), _side(p, 0))
        n /= np.linalg.norm(n, axis=-1, keepdims=True)
        flip = np.sum(n * p, axis=-1) > 0
    return np.where(flip[..., None], -n, n)


def _orthonormals(n):
    """Cycles' make_orthonormals: T = normalize((1, 1, 1) × N) (or (−1, 1, 1) × N), B = N × T."""
    if n[0] != n[1] or n[0] != n[2]:
        t = np.array([n[2] - n[1], n[0] - n[2], n[1] - n[0]])
    else:
        t = np.array([n[2] - n[1], n[0] + n[2], -n[1] - n[0]])
    t /= np.linalg.norm(t)
    return t, np.cross(n, t)


def surface_quadrature(frame, profile, geom, pixels, disk=False, hidden=1.0):
    """L by quadrature of the surface-distance integral the estimator defines (module doc).

    Samples follow the surface where the depth is within 2·r of the centre's or of
    its tangent plane. With ``disk``, a sample's value counts G = |Δ|·Σ_a m_a/ρ_a
    times (Cycles' disk kernel over the surface kernel, SSSParams.distance "cycles").
    With ``hidden`` < 1, a sample that lands on the image off the surface and not on
    something nearer counts −(1 − hidden)·B(p) (the frame has no indirect light) at
    the profile's own weight.
    """
    cdf, rmax = burley_model_cdf(np.asarray(frame.materials[1].d))
    d = np.asarray(frame.materials[1].d)
    cam = frame.camera
    wu, hu = cam.unit_footprint()
    cx, cy = cam.principal_point
    p = _points(cam, frame.depth)
    flat_area = wu * hu * frame.depth.astype(np.float64) ** 2
    area = np.where(
        np.isfinite(_pixel_area(p)), np.minimum(_pixel_area(p), 8 * flat_area), flat_area
    )
    light = frame.lighting.reshape(-1, 3).astype(np.float64)
    depth = frame.depth.reshape(-1).astype(np.float64)
    theta = (np.arange(THETAS) + 0.5) * (2 * np.pi / THETAS)
    out = np.zeros((pixels.size, 3))

    def profile_2d(r, c):  # R_c(r) = pdf/(2πr), Burley truncated (unnormalised is fine)
        dc = d[c]
        rr = np.asarray(r)
        val = (np.exp(-rr / dc) + np.exp(-rr / (3 * dc))) / (8 * np.pi * dc * rr)
        return np.where(rr <= 16 * dc, val, 0.0)

    normals = _normals(p).reshape(-1, 3)
    for i, k in enumerate(pixels):
        x, y, r0 = geom.x[k], geom.y[k], geom.r0[k]
        zp = depth[geom.index[k]]
        b = light[geom.index[k]]
        n_p = normals[geom.index[k]]
        t_p, b_p = _orthonormals(n_p)
        x_p = np.array([(x - cx) * wu * zp, (y - cy) * hu * zp, zp])
        for c in range(3):
            gamma = geom.gamma[k, c]
            grid = np.unique(
                np.concatenate([np.geomspace(r0, rmax[c], 20000), np.linspace(r0, rmax[c], 20000)])
            )
            mass = cdf(grid)[c]
            levels = np.linspace(mass[0], mass[-1], R_CELLS + 1)
            r = np.interp(0.5 * (levels[1:] + levels[:-1]), mass, grid)[:, None]
            sx = x + r * np.cos(theta)[None, :] / geom.fw[k]
            sy = y + r * np.sin(theta)[None, :] / geom.fh[k]
            qx, qy = np.rint(sx).astype(np.int64), np.rint(sy).astype(np.int64)
            inside = (qx >= 0) & (qx < W) & (qy >= 0) & (qy < H)
            q = np.where(inside, qy * W + qx, geom.index[k])
            zq = depth[q]
            # Within 2r of the centre's depth, or of its tangent plane along the ray
            # through the landing pixel.
            ray = np.stack([(qx - cx) * wu, (qy - cy) * hu, np.ones(qx.shape)], -1)
            with np.errstate(divide="ignore", invalid="ignore"):
                z_plane = (n_p @ x_p) / (ray @ n_p)
            near = (np.abs(zq - zp) <= 2.0 * r) | (
                (z_plane > 0) & (np.abs(zq - z_plane) <= 2.0 * r)
            )
            ok = inside & (frame.material.reshape(-1)[q] == 1) & near
            zq = np.where(ok, zq, zp)
            dx = ((sx - cx) * zq - (x - cx) * zp) * wu
            dy = ((sy - cy) * zq - (y - cy) * zp) * hu
            dz = zq - zp
            dist = np.sqrt(dx * dx + dy * dy + dz * dz)
            jac = area.reshape(-1)[q] / (wu * hu * zp * zp)
            g = profile_2d(dist, c) / profile_2d(r, c) * jac
            value = light[q, c]
            if disk:
                # G from the landing pixel's own point (its centre).
                delta = np.stack(
                    [
                        ((qx - cx) * zq - (x - cx) * zp) * wu,
                        ((qy - cy) * zq - (y - cy) * zp) * hu,
                        dz,
                    ],
                    -1,
                )
                n_q = normals[q]
                inv = np.zeros_like(dist)
                total = np.zeros_like(dist)
                along = [delta @ a for a in (n_p, t_p, b_p)]
                for j, (axis, pick) in enumerate(((n_p, 0.5), (t_p, 0.25), (b_p, 0.25))):
                    m = (pick * np.abs(n_q @ axis)) ** 2
                    rho = np.hypot(along[(j + 1) % 3], along[(j + 2) % 3])
                    inv += m / np.maximum(rho, 0.5 * geom.fw[k])
                    total += m
                value = value * np.linalg.norm(delta, axis=-1) * inv / total
            fill = inside & ~ok & ~(zp - depth[q] > 0.1 * zp)
            f = np.where(ok, g * (value - b[c]), np.where(fill, -(1.0 - hidden) * b[c], 0.0))
            out[i, c] = b[c] + gamma * f.mean()
    return out


@pytest.fixture(scope="module", params=list(SURFACE_CASES))
def surface_case(request):
    light = lighting()
    frame = SURFACE_CASES[request.param](light)
    params = SSSParams(distance="surface")
    profile = frame_profile(frame, params)
    geom = geometry_of(frame, profile, surface_distance=True)
    rng = np.random.default_rng(7)
    # Pixels near the shadow edge, the stripe, and (sphere) the silhouette.
    rim = silhouette(geom.mask(), frame.material, frame.depth).reshape(-1)[geom.index]
    near = np.flatnonzero(
        (np.abs(geom.x - W // 2) <= 6) | (np.abs((geom.x - geom.y) - 6) <= 4) | rim
    )
    pixels = np.sort(rng.choice(near, PIXELS, replace=False))
    runs = np.stack(
        [shade(frame, SPP, profile, seed=s, surface=True)[2][pixels] for s in range(SEEDS)]
    )
    return request.param, frame, profile, geom, pixels, runs


def test_surface_estimator_is_unbiased_against_quadrature(surface_case):
    name, frame, profile, geom, pixels, runs = surface_case
    expected = surface_quadrature(frame, profile, geom, pixels)
    b = frame.lighting.reshape(-1, 3)[geom.index[pixels]]
    mean, se, _ = assert_unbiased(name, runs, expected, b, 0.02)
    # The surface weights do change the result against the planar radius.
    planar = np.stack([shade(frame, SPP, profile, seed=s)[2][pixels] for s in range(8)]).mean(0)
    assert np.max(np.abs(planar - mean)) > 4 * float(np.max(se)), name


@pytest.mark.parametrize("name", list(SURFACE_CASES))
def test_pixel_area_matches_the_analytic_surface(name):
    """The estimator's area per pixel (finite differences) against the exact one."""
    frame = SURFACE_CASES[name](None)
    s = surface(frame)
    cam = frame.camera
    wu, hu = cam.unit_footprint()
    cx, cy = cam.principal_point
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float64)
    v = np.stack([(xx - cx) * wu, (yy - cy) * hu, np.ones_like(xx)], -1)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)
    p = _points(cam, frame.depth)
    if name == "sphere":
        n = p - np.array([0.0, 0.0, 2.0])
    else:
        a = np.radians(60.0)
        n = np.broadcast_to(np.array([np.sin(a), 0.0, -np.cos(a)]), p.shape)
    with np.errstate(invalid="ignore"):
        n = n / np.linalg.norm(n, axis=-1, keepdims=True)
    z = frame.depth.astype(np.float64)
    exact = wu * hu * z * z * np.abs(v[..., 2]) / np.abs(np.sum(v * n, axis=-1))
    # Inside the image (the border has one-sided differences only) and, on the sphere,
    # where the surface faces the camera (near the silhouette a pixel's parallelogram of
    # neighbour steps and the curved patch differ more: within 20 % where |v·n| > 0.3).
    inner = frame.material > 0
    inner[[0, -1], :] = inner[:, [0, -1]] = False
    with np.errstate(invalid="ignore"):
        facing = np.abs(np.sum(v * n, axis=-1))
    got = s.area.reshape(H, W)
    tight = inner & (facing > 0.5)
    np.testing.assert_allclose(got[tight], exact[tight], rtol=0.015)
    loose = inner & (facing > 0.3)
    np.testing.assert_allclose(got[loose], exact[loose], rtol=0.2)


@pytest.fixture(scope="module")
def sphere_disk_case():
    light = lighting()
    frame = SURFACE_CASES["sphere"](light)
    profile = frame_profile(frame, SSSParams(distance="cycles"))
    geom = geometry_of(frame, profile, surface_distance=True)
    rng = np.random.default_rng(11)
    rim = silhouette(geom.mask(), frame.material, frame.depth).reshape(-1)[geom.index]
    near = np.flatnonzero(
        (np.abs(geom.x - W // 2) <= 6) | (np.abs((geom.x - geom.y) - 6) <= 4) | rim
    )
    pixels = np.sort(rng.choice(near, PIXELS, replace=False))
    runs = np.stack(
        [
            shade(frame, SPP, profile, seed=s, surface=True, disk=True)[2][pixels]
            for s in range(SEEDS)
        ]
    )
    return frame, profile, geom, pixels, runs


def test_disk_kernel_is_unbiased_against_quadrature(sphere_disk_case):
    """distance "cycles" on a sphere: unbiased for the integral with Cycles' disk kernel,
    which differs from the surface kernel there (curvature: Cycles' energy gain)."""
    frame, profile, geom, pixels, runs = sphere_disk_case
    expected = surface_quadrature(frame, profile, geom, pixels, disk=True)
    b = frame.lighting.reshape(-1, 3)[geom.index[pixels]]
    assert_unbiased("sphere-disk", runs, expected, b, 0.02)
    # The kernel matters here: Cycles' kernel gains energy on the curved surface (measured
    # 1.1 % on these pixels, up to 4 %).
    plain = surface_quadrature(frame, profile, geom, pixels)
    gain = float(np.mean(expected / plain))
    assert gain > 1.005, gain


def test_hidden_light_fill_is_unbiased_against_quadrature():
    """SSSParams.hidden_light < 1 on a sphere (silhouettes: samples off the surface): the
    estimator is unbiased for the integral with the fill, which darkens the rims."""
    light = lighting()
    frame = SURFACE_CASES["sphere"](light)
    profile = frame_profile(frame, SSSParams())
    geom = geometry_of(frame, profile, surface_distance=True)
    rim = silhouette(geom.mask(), frame.material, frame.depth).reshape(-1)[geom.index]
    rng = np.random.default_rng(5)
    pixels = np.sort(rng.choice(np.flatnonzero(rim), PIXELS, replace=False))
    runs = np.stack(
        [
            shade(frame, SPP, profile, seed=s, surface=True, hidden=0.5)[2][pixels]
            for s in range(SEEDS)
        ]
    )
    expected = surface_quadrature(frame, profile, geom, pixels, hidden=0.5)
    b = frame.lighting.reshape(-1, 3)[geom.index[pixels]]
    assert_unbiased("sphere-hidden", runs, expected, b, 0.02)
    plain = surface_quadrature(frame, profile, geom, pixels)
    assert np.mean(expected / plain) < 0.98  # the fill darkens silhouette pixels


@pytest.mark.parametrize("tilt", [0.0, 60.0, 78.0])
def test_disk_kernel_equals_the_surface_kernel_on_a_plane(tilt):
    """On any plane Cycles' disk kernel is the Burley kernel (G = 1): same results."""
    frame = tilted_plane(W, H, tilt=tilt, d=(0.02, 0.008, 0.003), lighting=lighting())
    profile = frame_profile(frame, SSSParams())
    a = shade(frame, SPP, profile, seed=3, surface=True)[2]
    b = shade(frame, SPP, profile, seed=3, surface=True, disk=True)[2]
    np.testing.assert_allclose(b, a, rtol=1e-4, atol=1e-6)


def test_samples_follow_a_steep_plane():
    """A plane seen 78° off its normal: the depth changes 4.7·r across a sample's radius,
    beyond the slope of 2, but within the tangent-plane rule: the surface modes take
    nearly every sample there, the planar mode (centre depth only) loses most."""
    frame = tilted_plane(W, H, tilt=78.0, d=(0.02, 0.008, 0.003), lighting=lighting())
    profile = frame_profile(frame, SSSParams())
    _, planar, _ = shade(frame, SPP, profile, seed=1)
    _, steep, _ = shade(frame, SPP, profile, seed=1, surface=True)
    assert planar.fallback > 0.5 * planar.samples
    # What remains: samples that leave the image or the plane.
    assert steep.fallback < 0.25 * planar.fallback


def test_surface_weights_equal_planar_on_a_fronto_plane():
    frame = plane("burley-chromatic")
    profile = frame_profile(frame, SSSParams())
    a = shade(frame, SPP, profile, seed=3)[2]
    b = shade(frame, SPP, profile, seed=3, surface=True)[2]
    np.testing.assert_allclose(a, b, rtol=2e-5, atol=1e-6)

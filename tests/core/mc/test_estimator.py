"""Unified direct/distant estimator: invariants, unbiasedness, fallbacks, bad input."""

import dataclasses
import warnings

import numpy as np
import pytest

from cvsss.core import SSSParams, make_processor
from cvsss.core.camera import Camera
from cvsss.core.geometry import geometry_of
from cvsss.core.mc.estimator import estimate_distant
from cvsss.core.mc.samples import _pdf, _pdf_at, active_pixels
from cvsss.core.params import CONTACT_LOSS
from cvsss.core.profiles import BurleyProfile
from cvsss.core.profiles.factory import ProfileChoice, frame_profile
from cvsss.core.synthetic import flat_plane, scene_frame

from helpers import shade, shadow_edge

CHROMATIC = (0.02, 0.008, 0.003)  # metres; ~2.7, 1.1, 0.4 px at 2 m, 64 px wide


def run(frame, counts, seed=0, slope=2.0):
    return shade(frame, counts, seed=seed, slope=slope)


@pytest.mark.parametrize("m", [0, 1, 2, 7, 64, 300])
def test_constant_lighting_is_exact_for_any_count(m):
    b = np.full((48, 64, 3), [0.3, 0.7, 1.9], np.float32)
    frame = flat_plane(d=CHROMATIC, lighting=b)
    geom, est, shaded = run(frame, m)
    assert geom.size == 48 * 64
    assert (
        np.array_equal(
            shaded, np.broadcast_to(b.reshape(-1, 3)[0], shaded.shape).astype(np.float64)
        )
        or np.max(np.abs(shaded - b.reshape(-1, 3)[0])) <= 1e-12 * 1.9
    )
    assert est.samples == m * geom.size


def test_zero_counts_reduce_to_diffuse():
    rng = np.random.default_rng(3)
    b = rng.random((48, 64, 3)).astype(np.float32)
    frame = flat_plane(d=CHROMATIC, lighting=b)
    _, est, shaded = run(frame, 0)
    assert est.samples == 0
    assert np.allclose(shaded, b.reshape(-1, 3), rtol=0, atol=1e-7)


def test_unbiased_on_flat_plane():
    """Mean of the 8-spp estimator over seeds matches a 2048-spp reference.

    Per pixel, |mean − ref| must be below 4 standard errors of the mean plus
    the reference's own error bound (1e-3 of the lighting range); checked on
    the pixels around a shadow edge, where the estimate is not trivial.
    """
    frame = flat_plane(d=CHROMATIC, lighting=shadow_edge())
    seeds = 48
    runs = np.stack([run(frame, 8, seed=s)[2] for s in range(seeds)])
    _, _, ref = run(frame, 2048, seed=10_000)
    mean = runs.mean(axis=0)
    se = runs.std(axis=0, ddof=1) / np.sqrt(seeds)
    edge = np.abs(np.arange(48 * 64) % 64 - 32) <= 6
    err = np.abs(mean - ref)[edge]
    bound = 4 * se[edge] + 1e-3
    assert np.mean(err <= bound) >= 0.995
    # And the estimate is really doing something at the edge.
    assert np.max(np.abs(ref - frame.lighting.reshape(-1, 3))[edge]) > 0.05


def test_energy_conserved_on_flat_plane():
    """Scattering moves energy across the edge but keeps the total (interior rows)."""
    frame = flat_plane(d=CHROMATIC, lighting=shadow_edge())
    _, _, ref = run(frame, 1024, seed=5)
    img = ref.reshape(48, 64, 3)
    b = frame.lighting
    # Away from the image border, total per row is conserved within 0.5 %.
    inner = slice(20, 44)
    assert np.allclose(img[:, inner].sum(axis=1), b[:, inner].sum(axis=1), rtol=5e-3)


def test_other_material_and_depth_fall_back_to_centre():
    frame = flat_plane(d=CHROMATIC, lighting=shadow_edge())
    # Right half: another material -> left pixels must not see its lighting.
    frame.material[:, 32:] = 2
    frame.materials[2] = type(frame.materials[1])(2, "other", CHROMATIC)
    _, est, shaded = run(frame, 64)
    left = (np.arange(48 * 64) % 64) < 32
    assert np.allclose(shaded[left], frame.lighting.reshape(-1, 3)[left], atol=1e-12)
    assert est.fallback > 0
    # Same material but a depth step of 1 m at the edge: also no bleeding.
    frame2 = flat_plane(d=CHROMATIC, lighting=shadow_edge())
    frame2.depth[:, 32:] = 3.0
    _, _, shaded2 = run(frame2, 64)
    assert np.allclose(shaded2[left], frame2.lighting.reshape(-1, 3)[left], atol=1e-12)


def test_bit_identical_reruns_and_seed_dependence():
    frame = flat_plane(d=CHROMATIC, lighting=shadow_edge())
    a = run(frame, 16, seed=3)[2]
    b = run(frame, 16, seed=3)[2]
    c = run(frame, 16, seed=4)[2]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_chunking_does_not_change_result():
    frame = scene_frame("static", 2, 96, 54)
    prof = BurleyProfile(frame.d_table())
    geom = geometry_of(frame, prof)
    m = np.full(geom.size, 13)
    kw = dict(frame=2, seed=1, depth_slope=2.0)
    a = estimate_distant(geom, frame.lighting, frame.depth, prof, m, **kw)
    b = estimate_distant(geom, frame.lighting, frame.depth, prof, m, chunk_samples=1024, **kw)
    assert a.samples == b.samples
    assert np.allclose(a.distant, b.distant, rtol=1e-12, atol=1e-12)


def test_background_and_non_sss_untouched():
    frame = scene_frame("static", 1, 96, 54)
    res = make_processor("fixed", SSSParams(fixed_spp=8)).process(frame)
    off = ~res.mask
    assert np.array_equal(res.composite[off], frame.combined[off])
    assert np.all(res.counts[off] == 0)
    assert res.mask.sum() == np.count_nonzero(frame.material > 0)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 1e30, 0.0])
def test_bad_values_never_leak(bad):
    frame = scene_frame("flash", 3, 64, 36)
    frame.lighting[10:14, 10:30] = bad
    frame.lighting[20, :] = bad
    frame.depth[5:8, 20:24] = bad
    frame = dataclasses.replace(frame)  # validates (and repairs) the bad values again
    p = SSSParams()
    for method in ("fixed", "as", "as_ocv", "as_ccv"):
        proc = make_processor(method, p)
        for _ in range(3):
            res = proc.process(frame)
            for arr in (res.sss, res.composite, res.alpha, res.gamma, res.variance):
                assert np.all(np.isfinite(arr))
            c = res.counts[res.mask]
            assert np.all((c == 0) | ((c >= p.beta_min) & (c <= max(p.beta_max, p.fixed_spp))))


@pytest.mark.parametrize("d", [1e20, 1e30])
def test_offsets_far_beyond_the_image_fall_back_without_warnings(d):
    """d so large that offsets in pixels overflow an integer: clipped, never cast raw."""
    frame = flat_plane(d=(d, d, d), lighting=shadow_edge())
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. "invalid value encountered in cast"
        _, est, shaded = run(frame, 8)
    assert est.fallback == est.samples > 0  # every sample lands off screen
    assert np.isfinite(shaded).all()
    assert np.allclose(shaded, frame.lighting.reshape(-1, 3), atol=1e-6)


# -- objects (the Object Index pass) ------------------------------------------------------
KERNELS = {"planar": {}, "surface": {"surface": True}, "cycles": {"surface": True, "disk": True}}


def _bent_plane(tilt_degrees: float):
    """A plane facing an orthographic camera (1 cm pixels) on the left half, bent at
    the image's middle column into a face tilted ``tilt_degrees`` away from the
    camera on the right (its depth grows by tan(tilt) cm per column), lit 1 on the
    right and 0.05 on the left."""
    frame = flat_plane(d=(0.02, 0.01, 0.005), lighting=shadow_edge())
    frame.camera = Camera(width=64, height=48, type="ORTHO", ortho_scale=0.64)
    x = np.arange(64, dtype=np.float64)
    bend = np.where(x >= 32, np.tan(np.radians(tilt_degrees)) * (x - 31.5) * 0.01, 0.0)
    frame.depth = np.broadcast_to(2.0 + bend, (48, 64)).astype(np.float32).copy()
    return frame


@pytest.mark.parametrize("kernel", KERNELS)
def test_the_default_slope_follows_a_box_edge_of_66_degrees(kernel):
    """Light crosses the edge of a box seen from the corner (Blender's cube from its
    default camera): with the default depth slope the dim face next to a bend of 66°
    (depth slope tan 66° = 2.25) takes every sample that lands on the lit face, as it
    does with no depth test at all; at 72° (3.08) the test drops some of them."""
    column = np.arange(48 * 64) % 64
    left_of_edge = (column >= 28) & (column < 32)
    kw = KERNELS[kernel]
    for tilt, followed in ((66.0, True), (72.0, False)):
        frame = _bent_plane(tilt)
        light = frame.lighting.reshape(-1, 3)[left_of_edge].astype(np.float64)
        _, _, by_default = shade(frame, 64, slope=SSSParams().depth_slope, **kw)
        _, _, unbounded = shade(frame, 64, slope=1e6, **kw)
        assert (unbounded[left_of_edge][:, 0] > light[:, 0]).all()  # red reaches 4 px
        if followed:
            assert np.allclose(by_default[left_of_edge], unbounded[left_of_edge], atol=1e-12)
            # The slope of 2, the default before, dropped some of them.
            _, _, two = shade(frame, 64, slope=2.0, **kw)
            assert two[left_of_edge].sum() < unbounded[left_of_edge].sum()
        else:
            assert by_default[left_of_edge].sum() < unbounded[left_of_edge].sum()


def two_objects(right_light: float = 0.2, right_depth: float = 2.0):
    """A fronto-parallel plane of one material at 2 m: the left half is object 1, lit at 1,
    the right half object 2, lit at ``right_light`` and at ``right_depth``."""
    x = np.arange(64)[None, :, None]
    light = np.broadcast_to(np.where(x < 32, 1.0, right_light), (48, 64, 3)).astype(np.float32)
    frame = flat_plane(d=CHROMATIC, lighting=light)
    depth = frame.depth.copy()
    depth[:, 32:] = right_depth
    objects = np.broadcast_to(np.where(x[..., 0] < 32, 1, 2), (48, 64)).astype(np.int32)
    return dataclasses.replace(frame, depth=depth, objects=objects)


@pytest.mark.parametrize("kernel", KERNELS)
def test_no_light_passes_from_one_object_to_another(kernel):
    """Cycles scatters within one object: with the Object Index pass each half keeps its
    own light exactly (samples that land on the other object fall back); without it, two
    objects of one material at one depth are one surface and light crosses."""
    frame = two_objects()
    geom, est, apart = shade(frame, 64, **KERNELS[kernel])
    left = geom.x < 32
    np.testing.assert_allclose(apart[left], 1.0, rtol=2e-6)
    np.testing.assert_allclose(apart[~left], 0.2, rtol=2e-6)
    assert est.fallback > 0
    _, _, joined = shade(dataclasses.replace(frame, objects=None), 64, **KERNELS[kernel])
    red = joined[:, 0]  # the widest channel (d = 2 cm, 2.7 px)
    assert red[left & (geom.x >= 30)].max() < 0.97
    assert red[~left & (geom.x <= 33)].min() > 0.23


@pytest.mark.parametrize("kernel", KERNELS)
def test_a_touching_object_on_the_plane_keeps_a_share_of_the_light(kernel):
    """SSSParams.contact: a sample on another object in the centre's own plane (which faces
    the camera as squarely) stands for the centre's surface ending on that object, at
    height 0 of it: it keeps 1 − CONTACT_LOSS of the centre's light. Object 1 then gets
    what one surface whose right half is lit at that share gives (the same samples;
    planar weights exactly, plane-point weights to float rounding)."""
    frame = two_objects()
    geom, est, touched = shade(frame, 64, contact=0.5, **KERNELS[kernel])
    kept = frame.lighting.copy()
    kept[:, 32:] = np.float32(1.0) - np.float32(CONTACT_LOSS)
    dark = dataclasses.replace(frame, objects=None, lighting=kept)
    _, ref, expected = shade(dark, 64, **KERNELS[kernel])
    left = geom.x < 32
    if kernel == "planar":
        np.testing.assert_array_equal(touched[left], expected[left])
    else:
        np.testing.assert_allclose(touched[left], expected[left], rtol=2e-5, atol=1e-7)
    # Darker towards the contact, untouched far from it, never negative.
    assert touched[left & (geom.x == 31), 0].max() < 0.9
    np.testing.assert_allclose(touched[left & (geom.x < 8)], 1.0, rtol=2e-6)
    assert touched.min() >= 0.0
    # Touching samples are taken, not fallbacks: object 1 falls back less than with contact 0.
    _, apart, _ = shade(frame, 64, **KERNELS[kernel])
    assert est.fallback < apart.fallback


@pytest.mark.parametrize("kernel", KERNELS)
def test_an_object_off_the_plane_is_not_touching(kernel):
    """Object 2 0.4 m in front of object 1's plane (far above contact·r): its samples
    fall back as with contact 0."""
    frame = two_objects(right_depth=1.6)
    _, _, a = shade(frame, 64, contact=0.5, **KERNELS[kernel])
    _, _, b = shade(frame, 64, contact=0.0, **KERNELS[kernel])
    np.testing.assert_array_equal(a, b)


def _crease(top_depth, bottom_depth, *, top_object: int, bottom_object: int):
    """An orthographic camera (1 cm pixels) on two objects of one material that meet at the
    row between 23 and 24: rows 0-23 are ``top_object`` at ``top_depth(row)``, rows 24-47
    ``bottom_object`` at ``bottom_depth(row)`` (metres); lit 1, with a Burley d of 2 cm."""
    frame = flat_plane(d=(0.02, 0.01, 0.005))
    frame.camera = Camera(width=64, height=48, type="ORTHO", ortho_scale=0.64)
    row = np.arange(48, dtype=np.float64)[:, None]
    depth = np.where(row < 24, top_depth(row), bottom_depth(row))
    frame.depth = np.broadcast_to(depth, (48, 64)).astype(np.float32).copy()
    frame.objects = np.broadcast_to(np.where(row < 24, top_object, bottom_object), (48, 64)).astype(
        np.int32
    )
    return frame


#: A table top seen at 60° from the view axis: its depth grows by tan 60° cm per row up.
def _table(row):
    return 2.0 + np.tan(np.radians(60.0)) * (47.5 - row) * 0.01


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("kernel", ["surface", "cycles"])
def test_an_object_standing_on_a_surface_hides_it_unlit(kernel, backend):
    """A block facing the camera (rows 0-23, object 2) stands on a table top seen at 60°
    (object 1), at the row where the two meet: it faces the camera twice as squarely as
    the top, so every sample of the top that lands on it counts as the top running on
    under it, unlit. The top's rows get what the top continued through the block's
    rows, unlit there, gives (the same samples at the same points of the top's plane,
    but for the crease's own row, whose normal the depth buffer bends, and the samples
    that land on it: each row's mean within 2 %)."""
    contact = SSSParams().contact
    opts = dict(KERNELS[kernel], backend=backend, contact=contact, slope=2.5)
    frame = _crease(lambda r: _table(23.5), _table, top_object=2, bottom_object=1)
    geom, est, got = shade(frame, 64, **opts)
    covered = _crease(_table, _table, top_object=1, bottom_object=1)
    covered.objects = None
    covered.lighting[:24] = 0.0
    _, _, expected = shade(covered, 64, **opts)
    rows = np.arange(24, 48)
    got_rows = np.array([got[geom.y == y].mean(axis=0) for y in rows])
    expected_rows = np.array([expected[geom.y == y].mean(axis=0) for y in rows])
    np.testing.assert_allclose(got_rows, expected_rows, rtol=0.02)
    # A quarter darker at the block's foot (without the rule: as lit as the open top).
    assert got_rows[0, 0] < 0.75
    _, _, apart = shade(frame, 64, **dict(opts, contact=0.0))
    assert apart[geom.y == 24, 0].mean() > 0.99


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("kernel", ["surface", "cycles"])
def test_a_surface_ending_on_a_slanted_one_loses_light_at_its_foot(kernel, backend):
    """The front face of a slab (rows 0-23, object 1, facing the camera) stands on a floor
    seen at 60° (object 2) in front of it. The floor faces the camera less squarely than
    the face, so the face ends on it: a sample of the face's row on the floor (0.5 cm
    above it, within CONTACT_FOOT·contact·d) that lands on the floor keeps 1 −
    CONTACT_LOSS of the face's light, and the row gets what the face continued below the
    floor at that share of its light gives (the same samples, at the same points of the
    face's plane: to float rounding). Rows more than contact·d (2.8 cm) above the floor
    come out exactly as without the rule."""
    contact = SSSParams().contact
    opts = dict(KERNELS[kernel], backend=backend, slope=2.5)
    frame = _crease(lambda r: _table(23.5) + 0.0 * r, _table, top_object=1, bottom_object=2)
    geom, _, got = shade(frame, 64, contact=contact, **opts)
    _, _, apart = shade(frame, 64, contact=0.0, **opts)
    continued = _crease(lambda r: _table(23.5) + 0.0 * r, lambda r: _table(23.5) + 0.0 * r,
                        top_object=1, bottom_object=1)  # fmt: skip
    continued.objects = None
    continued.lighting[24:] = np.float32(1.0) - np.float32(CONTACT_LOSS)
    _, _, expected = shade(continued, 64, **opts)
    foot = geom.y == 23
    np.testing.assert_allclose(got[foot], expected[foot], rtol=2e-5, atol=1e-7)
    assert (got[foot, 0] < apart[foot, 0]).all()
    # d = 2 cm in red: beyond 1.4·2 cm = 2.8 cm (rows 0-20 of 1 cm) no sample loses light.
    far = geom.y < 23.5 - contact * 2.0
    assert far.any()
    np.testing.assert_array_equal(got[far], apart[far])


@pytest.mark.parametrize("backend", ["numpy", "numba"])
@pytest.mark.parametrize("kernel", KERNELS)
def test_a_hidden_sample_reads_the_visible_side_mirrored(kernel, backend):
    """SSSParams.hidden_mirror: a sample beyond a silhouette (the background right of
    column 32) reads the pixel opposite it through the centre. With lighting that depends
    on x only and peaks at the silhouette, the silhouette's pixels then get what the
    surface continued by its mirror image gives: there the same samples land on pixels
    lit as the mirrored ones (planar weights exactly; the surface kernels weigh accepted
    samples by the surface, the mirrored ones at their planar weight, equal on this
    plane to float rounding). Without the mirror the rim keeps its own peak light."""
    w, h, edge = 64, 48, 32
    d = (0.006, 0.004, 0.002)  # metres; red reaches 16·d ≈ 13 px at 2 m
    x = np.arange(w)
    ramp = (0.2 + 0.04 * np.minimum(x, 2 * edge - x)).astype(np.float32)
    light = np.ascontiguousarray(np.broadcast_to(ramp[None, :, None], (h, w, 3)))
    full = flat_plane(w, h, d=d, lighting=light)
    half = flat_plane(w, h, d=d, lighting=light.copy())
    half.material[:, edge + 1 :] = 0
    half.depth[:, edge + 1 :] = np.inf
    half.lighting[:, edge + 1 :] = 7.0  # a sample must not read where it landed
    opts = dict(KERNELS[kernel], backend=backend)
    geom, est, mirrored = shade(half, 64, mirror=True, **opts)
    gfull, _, expected = shade(full, 64, **opts)
    # The silhouette column, away from the top and bottom (where a mirror image would
    # leave the image).
    rim = (geom.x == edge) & (geom.y >= 16) & (geom.y < 32)
    at_full = np.flatnonzero(np.isin(gfull.index, geom.index[rim]))
    if kernel == "planar":
        np.testing.assert_array_equal(mirrored[rim], expected[at_full])
    else:
        np.testing.assert_allclose(mirrored[rim], expected[at_full], rtol=2e-5, atol=1e-7)
    # The continued surface is dimmer than the rim: light leaves the rim.
    peak = ramp[edge]
    assert mirrored[rim, 0].max() < peak
    _, _, kept = shade(half, 64, **opts)
    assert kept[rim, 0].min() > mirrored[rim, 0].max()
    # Inside, beyond the samples' reach of the silhouette, nothing changes.
    inner = geom.x < edge - 14
    np.testing.assert_array_equal(mirrored[inner], kept[inner])
    # A mirror image off the centre's depth is no continuation: the rim's samples
    # beyond the silhouette fall back to the centre as without the mirror.
    step = dataclasses.replace(half, depth=half.depth.copy())
    step.depth[:, :edge] = 3.0
    _, _, stepped = shade(step, 64, mirror=True, **opts)
    _, _, stepped_off = shade(step, 64, **opts)
    np.testing.assert_array_equal(stepped[rim], stepped_off[rim])


@pytest.mark.parametrize(
    "choice",
    [
        ProfileChoice(),
        ProfileChoice(profile="dipole", slot_materials=((1, "skin1"), (2, "marble"))),
        ProfileChoice(profile="artist"),
    ],
    ids=["burley", "dipole", "artist"],
)
def test_density_of_a_few_samples_is_the_batch_density_picked(choice):
    """The hidden-light fill weighs only its own samples (``_pdf_at``, of scattered pixels):
    bit for bit what the batch's densities (``_pdf``, every sample) give at those samples,
    per-pixel weight scale included (the artist profile's)."""
    frame = scene_frame("flash", 2, 96, 54)
    profile = frame_profile(frame, SSSParams(), choice)
    geom = geometry_of(frame, profile, surface_distance=True)
    counts = (np.arange(geom.size) % 5 + 1).astype(np.int64)
    active = np.flatnonzero(geom.gamma_sum > 0)  # as estimate_distant picks them
    pix = active_pixels(geom, profile, counts, active, 2, 7)
    local = np.repeat(np.arange(active.size), pix.counts)
    rng = np.random.default_rng(11)
    r = (rng.random(local.size) * 0.02).astype(np.float32)  # scene units
    mat = np.repeat(pix.mat, pix.counts)
    batch = _pdf(profile, r, mat, pix, 0, pix.counts)
    some = np.sort(rng.choice(local.size, 200, replace=False))
    picked = _pdf_at(profile, r[some], pix, local[some])
    assert picked.shape == (3, some.size) and picked.dtype == np.float32
    assert np.count_nonzero(picked) > picked.size // 4  # densities, not zeros
    np.testing.assert_array_equal(picked, batch[:, some])

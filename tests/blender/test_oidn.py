"""OIDN called directly (sss_addon/blender/oidn.py) against Blender's compositor Denoise
node, the oracle built in conftest apart from the add-on's code."""

import numpy as np
import pytest

from cvsss.sss_addon.blender import oidn
from cvsss.sss_addon.blender.denoise_frame import (
    DenoiseSettings,
    FrameDenoiser,
    context_noise,
)
from cvsss.sss_addon.blender.oidn import Filters

#: The node's menu items for Cycles' prefilter and quality names.
NODE = {"NONE": "None", "FAST": "Fast", "ACCURATE": "Accurate", "HIGH": "High",
        "BALANCED": "Balanced"}  # fmt: skip


def _frame(height: int, width: int, seed: int):
    """A noisy frame with noisy guides: (rgba, albedo, normal), top row first. Not
    symmetric top to bottom, so a flipped row order would show."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width] / np.array([height, width])[:, None, None]
    albedo = np.stack([0.2 + 0.6 * x, 0.3 + 0.5 * y**2, 0.4 + 0 * x], -1)
    albedo[: height // 3, width // 2 :] = (0.8, 0.1, 0.1)  # an edge the guides keep
    light = 0.5 + 2.0 * np.exp(-((x - 0.3) ** 2 + (y - 0.2) ** 2) / 0.05)
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :3] = albedo * light[..., None] * rng.gamma(4.0, 0.25, (height, width, 3))
    tilt = np.stack([x - 0.5, 0.3 * y, 1 + 0 * x], -1)
    normal = tilt / np.linalg.norm(tilt, axis=-1, keepdims=True)
    normal += rng.normal(0, 0.05, normal.shape)
    noisy_albedo = albedo * rng.uniform(0.9, 1.1, albedo.shape)
    return rgba, noisy_albedo.astype(np.float32), normal.astype(np.float32)


def test_blenders_library_is_called_directly():
    """The bpy module ships OIDN 2; the add-on finds it (else every frame would take the
    compositor, slower)."""
    assert oidn.library() is not None
    assert FrameDenoiser(DenoiseSettings()).filters is not None


@pytest.mark.parametrize("prefilter", ["NONE", "FAST", "ACCURATE"])
@pytest.mark.parametrize(
    "guides,quality",
    [("RGB_ALBEDO_NORMAL", "HIGH"), ("RGB_ALBEDO", "BALANCED"), ("RGB", "HIGH")],
)
def test_the_filters_give_the_denoise_nodes_pixels(oidn, prefilter, guides, quality):
    """Bit for bit the node's output, for each prefilter and guide set; frames after the
    first reuse the filters and still match, and so does the compositor fallback."""
    settings = DenoiseSettings(prefilter=prefilter, quality=quality, guides=guides)
    use_albedo, use_normal = {"RGB": (0, 0), "RGB_ALBEDO": (1, 0), "RGB_ALBEDO_NORMAL": (1, 1)}[
        guides
    ]
    with FrameDenoiser(settings) as direct:
        assert direct.filters is not None
        for seed in (1, 2):
            rgba, albedo, normal = _frame(24, 40, seed)
            want = oidn(
                rgba[..., :3],
                albedo if use_albedo else None,
                normal if use_normal else None,
                NODE[prefilter],
                NODE[quality],
            )
            got = direct(rgba, albedo, normal)
            np.testing.assert_array_equal(got[..., :3], want)
            np.testing.assert_array_equal(got[..., 3], rgba[..., 3])
            assert np.abs(got[..., :3] - rgba[..., :3]).max() > 0.05  # it denoised
    fallback = FrameDenoiser(settings, direct=False)
    assert fallback.filters is None
    np.testing.assert_array_equal(fallback(rgba, albedo, normal)[..., :3], want)


def test_a_new_size_builds_new_filters(oidn):
    """A frame of another size after the first is denoised at its own size."""
    settings = DenoiseSettings(prefilter="ACCURATE", quality="HIGH")
    with FrameDenoiser(settings) as denoiser:
        denoiser(*_frame(24, 40, 3))
        rgba, albedo, normal = _frame(30, 20, 4)
        got = denoiser(rgba, albedo, normal)
    assert got.shape == (30, 20, 4)
    np.testing.assert_array_equal(
        got[..., :3], oidn(rgba[..., :3], albedo, normal, "Accurate", "High")
    )


def test_closed_filters_refuse_to_run():
    filters = oidn.Filters("NONE", "HIGH", albedo=False, normal=False)
    filters.close()
    filters.close()
    with pytest.raises(oidn.OidnError, match="closed"):
        filters.run(np.zeros((4, 4, 3), np.float32))


def test_guides_other_than_those_built_for_are_refused():
    filters = oidn.Filters("NONE", "HIGH", albedo=True, normal=True)
    with pytest.raises(ValueError, match="guides"):
        filters.run(np.zeros((4, 4, 3), np.float32))


@pytest.mark.parametrize("prefilter", ["NONE", "FAST", "ACCURATE"])
def test_run_again_is_the_node_on_the_new_image_with_the_last_guides(oidn, prefilter):
    """The main filter alone, on the guides the last run prefiltered: the node's pixels
    for the new image with those guides."""
    rgba, albedo, normal = _frame(24, 40, 5)
    other = _frame(24, 40, 6)[0]
    direct = Filters(prefilter, "HIGH", albedo=True, normal=True)
    try:
        direct.run(rgba, albedo, normal)
        got = direct.run_again(other)
        with pytest.raises(ValueError, match="size"):
            direct.run_again(other[:10])
    finally:
        direct.close()
    want = oidn(other[..., :3], albedo, normal, NODE[prefilter], "High")
    np.testing.assert_array_equal(got, want)


def test_the_noise_round_the_mask_is_read_as_a_relative_deviation():
    """A grey frame with relative Gaussian noise σ next to the mask reads σ (within a
    tenth); noise only beyond the reach, or none, reads 0; dark pixels are left out."""
    rng = np.random.default_rng(3)
    grey = np.full((60, 80, 3), 0.5)
    mask = np.zeros((60, 80), bool)
    mask[:, :40] = True
    for sigma in (0.02, 0.1, 0.2):
        noisy = grey * (1 + sigma * rng.standard_normal((60, 80, 1)))
        assert context_noise(noisy, mask) == pytest.approx(sigma, rel=0.1)
    far = grey.copy()
    far[:, 40 + 8 + 2 :] *= 1 + 0.1 * rng.standard_normal((60, 30, 1))
    assert context_noise(far, mask) == 0.0
    assert context_noise(grey, mask) == 0.0
    dark = grey * (1 + 0.1 * rng.standard_normal((60, 80, 1)))
    dark[:, 40:] *= 1e-5  # under 1/1000 of the frame's median
    assert context_noise(dark, mask) == 0.0


def test_the_pixels_off_the_mask_are_denoised_beside_stand_in_noise(oidn, delivered_denoise):
    """A finished frame whose masked half is smooth: the post's pixels keep the node's
    output on the frame, every other pixel takes the node's output on the frame with
    stand-in noise on the mask (conftest's rule, written apart), σ = the gain × the
    noise round the mask, at most 0.5; and that brings them closer to the denoise of the
    frame all noisy. With the gain 0 (the settings' default), a mask of every pixel or
    none, or nothing noisy round the mask, the frame is denoised once."""
    rgba, albedo, normal = _frame(24, 40, 7)
    plain = oidn(rgba[..., :3], albedo, normal, "Accurate", "High")  # the frame all noisy
    mask = np.zeros((24, 40), bool)
    mask[:, 20:] = True
    rgba[mask, :3] = rgba[mask, :3].mean(0)  # the post's smooth light
    result = type("Result", (), {"mask": mask})()
    once = oidn(rgba[..., :3], albedo, normal, "Accurate", "High")
    for gain in (0.1, 4.0):  # σ under the cap, and capped (the gamma noise reads ~0.5)
        sigma = min(gain * context_noise(rgba, mask), 0.5)
        assert 0.01 < sigma and (sigma < 0.5) == (gain < 1)
        with FrameDenoiser(DenoiseSettings(stand_in_gain=gain)) as denoiser:
            got = denoiser.finished(rgba, result, None, (albedo, normal))
        want = delivered_denoise(rgba[..., :3], albedo, normal, mask, sigma, "Accurate", "High")
        np.testing.assert_array_equal(got[..., :3], want)
        np.testing.assert_array_equal(got[mask, :3], once[mask])
        assert np.abs(got[~mask, :3] - once[~mask]).max() > 1e-4  # the second denoise counts
    # ... and brings the noisy half closer to how the frame all noisy was denoised.
    closer = np.abs(got[~mask, :3] - plain[~mask]).mean()
    assert closer < np.abs(once[~mask] - plain[~mask]).mean()
    smooth = rgba.copy()
    smooth[~mask, :3] = 0.3  # nothing noisy round the post's pixels
    for settings, m, frame in (
        (DenoiseSettings(), mask, rgba),
        (DenoiseSettings(stand_in_gain=4.0), np.ones_like(mask), rgba),
        (DenoiseSettings(stand_in_gain=4.0), np.zeros_like(mask), rgba),
        (DenoiseSettings(stand_in_gain=4.0), mask, smooth),
    ):
        result.mask = m
        with FrameDenoiser(settings) as denoiser:
            single = denoiser.finished(frame, result, None, (albedo, normal))
        np.testing.assert_array_equal(
            single[..., :3], oidn(frame[..., :3], albedo, normal, "Accurate", "High")
        )


def test_the_scene_denoises_twice_from_64_samples():
    """A scene's denoiser settings carry the stand-in gain 5 from 64 Cycles samples per
    pixel, none below; the log line says so."""
    import bpy

    from cvsss.sss_addon.blender.denoise_frame import cycles_denoise

    scene = bpy.data.scenes.new("stand-in samples")
    try:
        scene.render.engine = "CYCLES"
        scene.cycles.samples = 63
        below = cycles_denoise(scene)
        scene.cycles.samples = 64
        at = cycles_denoise(scene)
    finally:
        bpy.data.scenes.remove(scene)
    assert below.stand_in_gain == 0.0 and "stand-in" not in below.describe()
    assert at.stand_in_gain == 5.0
    assert at.describe().endswith(
        "; where noisy pixels border the post's, those denoised again beside stand-in noise "
        "(5× theirs)"
    )
    assert DenoiseSettings.from_dict(at.to_dict()) == at
    assert DenoiseSettings.from_dict({"quality": "HIGH"}).stand_in_gain == 0.0  # old sidecars
    with pytest.raises(ValueError, match="stand_in_gain"):
        DenoiseSettings(stand_in_gain=-1.0)

"""OIDN called directly (sss_addon/blender/oidn.py) against Blender's compositor Denoise
node, the oracle built in conftest apart from the add-on's code."""

import numpy as np
import pytest

from cvsss.sss_addon.blender import oidn
from cvsss.sss_addon.blender.denoise_frame import DenoiseSettings, FrameDenoiser

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

"""Denoising a finished frame the way the scene's Cycles denoiser would have.

When a Cycles render denoises (``scene.cycles.use_denoising`` and the view
layer's Denoising), the frame the user gets is OpenImageDenoise's output.
The pass render has Subsurface Weight 0 and no denoising of its own, so the
finished frame F (the core's composite) is denoised afterwards with the same
settings (:func:`scene_denoise`), guided by the pass render's Denoising
Albedo and Denoising Normal (``view_layer.cycles.denoising_store_passes``).

EEVEE's passes carry no noise; the post's samples bring the only noise of its
frame, on the subsurface pixels. :func:`eevee_denoise` denoises the post's
lighting there (OIDN without guides on L, which holds no albedo; the composite
is then made again, :meth:`FrameDenoiser.finished`; every other pixel stays
EEVEE's), unless the scene's *Denoise Subsurface* is off. Measured with
``tools/measure/eevee_denoise.py`` on the demo scenes (320×180, frames 21–22,
as_ccv, 64 samples a pixel on a first frame): OIDN on the finished frame's
subsurface pixels raised the subsurface effect against Cycles' ground truth by
0.3 dB (flash), 1.5 dB (regular) and 1.7 dB (boids), the whole frame by
0.1–0.5 dB; the albedo guide (EEVEE's Diffuse Color) moved the effect by −0.12
to +0.07 dB. Denoising the lighting instead of the frame, so that the albedo's
texture never goes through the denoiser, adds up to a quarter of a dB more
(docs/explanation/accuracy.md §2.5).

:class:`FrameDenoiser` calls the OIDN library Blender ships (:mod:`.oidn`)
the way Blender's compositor Denoise node does, and keeps its filters from
one frame to the next. Where the library cannot be called (or the scene
denoises on the GPU) it runs the node itself in a temporary scene
(:func:`compositor_denoise`: Image nodes holding F and the guides → Denoise →
File Output, a 32-bit multilayer EXR in a temporary folder, read back). Both
give the node's pixels bit for bit, and fed Cycles' own Noisy Image and
guides the node gives Cycles' denoised Combined bit for bit for every
prefilter, guide set and quality (the stored Denoising Albedo is the raw
guide; it is prefiltered as Cycles does). Two settings have no compositor
twin: OptiX (the frame gets OIDN) and Cycles' "follow scene" quality, which
the node would take from the compositor's own setting, so the quality is
always set explicitly.

The post's pixels are a smooth estimate, and OIDN judges how hard to denoise from
the noise it sees around a pixel: in a frame that is mostly the post's, the pixels
left to Cycles (its own subsurface on thin parts, the floor, the background) came out
denoised less than in the plain render, worst in small frames. From
:data:`STAND_IN_MIN_SAMPLES` samples per pixel a Cycles frame is therefore denoised
twice (:meth:`FrameDenoiser.beside_stand_in`): the post's pixels keep the denoise of
the frame, every other pixel takes that of the frame with stand-in noise on the
post's pixels. The second run is OIDN's main filter alone, on the guides the first
prefiltered (:meth:`.oidn.Filters.run_again`; docs/explanation/design.md §2.4).

Why the finished frame and not the passes: denoising the passes the post
reads (``--denoise-passes``, :mod:`.denoise`) and compositing them gave
0.05–0.08 dB more against Cycles' ground truth at 4 and 16 spp and the same
at 64 spp (``tools/measure/apply_on_render_quality.py``, 128×72), for three
or four denoiser runs per frame instead of one, and with fixed denoiser
settings rather than the scene's. So a scene that denoises gets its
finished frames denoised (Apply on Render, ``cvsss render``, ``cvsss
post``), and the passes are not denoised as well.

:class:`DenoisedProcessor` applies it to a run's results (``cvsss render``
and ``cvsss post``): the guides are read from each frame's pass file
(:func:`read_guides`), where the pass render keeps them.
"""

from __future__ import annotations

import contextlib
import dataclasses
import os
import tempfile
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass
from pathlib import Path

import bpy
import numpy as np
import OpenEXR

from ...core.color import luminance
from ...core.io.errors import OutputError
from ...core.io.exr import quiet_native_stderr, read_channels
from ...core.result import relit
from . import oidn
from .denoise import denoised_file_output, tree_copy
from .errors import RenderError
from .internal_renders import internal_render

#: Cycles' prefilter -> the Denoise node's Prefilter menu item.
PREFILTER = {"NONE": "None", "FAST": "Fast", "ACCURATE": "Accurate"}
#: Cycles' quality -> the Denoise node's Quality menu item (never "Follow Scene").
QUALITY = {"HIGH": "High", "BALANCED": "Balanced", "FAST": "Fast"}
#: Cycles' input passes -> the guides linked (albedo, normal).
GUIDES = {
    "RGB": (False, False),
    "RGB_ALBEDO": (True, False),
    "RGB_ALBEDO_NORMAL": (True, True),
}


#: The stand-in noise of the second denoise (:meth:`FrameDenoiser.beside_stand_in`), as
#: a multiple of the relative noise of the pixels round the post's (:func:`context_noise`):
#: the plain render's own subsurface noise on the post's pixels is about this multiple
#: of what is read round them (docs/explanation/accuracy.md §4.1).
STAND_IN_GAIN = 5.0
#: The stand-in noise's bounds: below the lower one the second denoise would change
#: little and is skipped; the upper one keeps ``1 + σ·g`` mostly positive.
STAND_IN_SKIP, STAND_IN_MAX = 0.01, 0.5
#: How far from the post's pixels (city-block, pixels) :func:`context_noise` looks.
CONTEXT_REACH = 8
#: Cycles' samples per pixel from which the finished frame is denoised twice. The second
#: denoise costs OIDN's main filter whatever the samples, while the render's own time
#: grows with them: below this it takes more of the frame's time than the 1.25× target
#: leaves (docs/performance.md).
STAND_IN_MIN_SAMPLES = 64


@dataclass(frozen=True)
class DenoiseSettings:
    """What a scene asks of Cycles' denoiser for a final render.

    Attributes
    ----------
    denoiser : {"OPENIMAGEDENOISE", "OPTIX"}
        Cycles' choice; the finished frame is denoised with OIDN either way.
    prefilter : {"NONE", "FAST", "ACCURATE"}
    quality : {"HIGH", "BALANCED", "FAST"}
    guides : {"RGB", "RGB_ALBEDO", "RGB_ALBEDO_NORMAL"}
    gpu : bool
        Cycles' *Use GPU* for denoising (the compositor's denoise device).
    subsurface_only : bool
        Only the subsurface pixels take the denoised values (EEVEE: :func:`eevee_denoise`);
        :meth:`FrameDenoiser.finished` then denoises the post's lighting, not the frame.
    stand_in_gain : float
        The noise the post's pixels carry in the second denoise, the one that gives every
        other pixel its value (:meth:`FrameDenoiser.beside_stand_in`), as a multiple of
        the noise round them; 0 denoises the finished frame once, as it is.
        :func:`cycles_denoise` sets :data:`STAND_IN_GAIN` from
        :data:`STAND_IN_MIN_SAMPLES` samples per pixel.
    """

    denoiser: str = "OPENIMAGEDENOISE"
    prefilter: str = "ACCURATE"
    quality: str = "HIGH"
    guides: str = "RGB_ALBEDO_NORMAL"
    gpu: bool = False
    subsurface_only: bool = False
    stand_in_gain: float = 0.0

    def __post_init__(self) -> None:
        for name, table in (("prefilter", PREFILTER), ("quality", QUALITY), ("guides", GUIDES)):
            if getattr(self, name) not in table:
                raise ValueError(
                    f"{name} must be one of {', '.join(table)}, got {getattr(self, name)!r}"
                )
        if not 0.0 <= self.stand_in_gain <= 100.0:
            raise ValueError(f"stand_in_gain must be in [0, 100], got {self.stand_in_gain!r}")

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping) -> DenoiseSettings:
        """The settings a :meth:`to_dict` recorded (a pass sidecar's ``"denoise"``)."""
        known = cls.__dataclass_fields__
        return cls(**{k: v for k, v in dict(data).items() if k in known})

    def describe(self) -> str:
        """One line for the log, e.g. ``OIDN, prefilter ACCURATE, HIGH, albedo + normal``."""
        guides = {
            "RGB": "no guides",
            "RGB_ALBEDO": "albedo",
            "RGB_ALBEDO_NORMAL": "albedo + normal",
        }
        how = "OIDN" if self.denoiser == "OPENIMAGEDENOISE" else f"OIDN (for {self.denoiser})"
        if self.subsurface_only:
            return (
                f"{how} on the subsurface pixels' lighting, {self.quality}, {guides[self.guides]}"
            )
        line = f"{how}, prefilter {self.prefilter}, {self.quality}, {guides[self.guides]}"
        if self.stand_in_gain > 0.0:
            line += (
                "; where noisy pixels border the post's, those denoised again beside "
                f"stand-in noise ({self.stand_in_gain:g}× theirs)"
            )
        return line


def cycles_denoise(scene) -> DenoiseSettings:
    """The scene's Cycles denoiser settings, whether its render denoises or not; from
    :data:`STAND_IN_MIN_SAMPLES` samples per pixel, with the second denoise beside
    stand-in noise (:meth:`FrameDenoiser.beside_stand_in`)."""
    c = scene.cycles
    return DenoiseSettings(
        denoiser=str(c.denoiser),
        prefilter=str(c.denoising_prefilter),
        quality=str(c.denoising_quality),
        guides=str(c.denoising_input_passes),
        gpu=bool(getattr(c, "denoising_use_gpu", False)),
        stand_in_gain=STAND_IN_GAIN if int(c.samples) >= STAND_IN_MIN_SAMPLES else 0.0,
    )


def scene_denoise(scene, view_layer) -> DenoiseSettings | None:
    """The denoiser settings of a final render of ``view_layer``, or None when it does
    not denoise (another engine than Cycles, Denoise off in the scene or the layer)."""
    c = getattr(scene, "cycles", None)
    if scene.render.engine != "CYCLES" or c is None or not c.use_denoising:
        return None
    layer = getattr(view_layer, "cycles", None)
    if layer is not None and not layer.use_denoising:
        return None
    return cycles_denoise(scene)


#: The denoise of an EEVEE pass render's finished frames: OIDN on the post's lighting
#: of the subsurface pixels, without guides (the prefilter only filters guides).
EEVEE_DENOISE = DenoiseSettings(
    prefilter="NONE", quality="HIGH", guides="RGB", subsurface_only=True
)


def eevee_denoise(scene) -> DenoiseSettings | None:
    """:data:`EEVEE_DENOISE`, or None when the scene's *Denoise Subsurface* is off."""
    return EEVEE_DENOISE if scene.sss_settings.use_denoise_subsurface else None


def _image(name: str, rgb: np.ndarray, non_color: bool):
    """A packed float image holding ``rgb`` ((H, W, 3), top row first) with alpha 1.

    Alpha 1: the compositor would premultiply a straight alpha; the denoiser
    reads RGB only, and the caller keeps the frame's own alpha.
    """
    height, width = rgb.shape[:2]
    rgba = np.ones((height, width, 4), np.float32)
    rgba[..., :3] = rgb[..., :3]
    image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Non-Color" if non_color else "Linear Rec.709"
    image.pixels.foreach_set(np.ascontiguousarray(rgba[::-1]).reshape(-1))
    # Packed: a generated image is made again from its settings when its buffer is freed.
    image.pack()
    return image


@contextlib.contextmanager
def _datablocks() -> Iterator[list]:
    """A list the block appends temporary datablocks to; all removed on exit."""
    made: list = []
    try:
        yield made
    finally:
        for block in reversed(made):
            with contextlib.suppress(ReferenceError):
                _remove(block)


def _remove(block) -> None:
    if isinstance(block, bpy.types.Scene):
        bpy.data.scenes.remove(block)
    elif isinstance(block, bpy.types.NodeTree):
        bpy.data.node_groups.remove(block)
    else:
        bpy.data.images.remove(block)


def _grow(mask: np.ndarray) -> np.ndarray:
    """``mask`` and its four neighbours of each pixel (edges padded with False)."""
    m = np.pad(mask, 1)
    return mask | m[:-2, 1:-1] | m[2:, 1:-1] | m[1:-1, :-2] | m[1:-1, 2:]


def context_noise(rgb: np.ndarray, mask: np.ndarray, reach: int = CONTEXT_REACH) -> float:
    """The relative noise of the pixels round ``mask``: what OIDN sees next to the post's.

    Over the pixels off ``mask`` within ``reach`` pixels of it (city-block), none of
    whose four neighbours is on it, each pixel's luminance departs from the mean of its
    four neighbours' by ``r``, relative to that mean. The noise is the median ``|r|``
    as a standard deviation (×1.4826), divided by √1.25 for the neighbours' own noise
    in the mean. Pixels whose neighbours' mean is under 1/1000 of the frame's median
    luminance are left out (a relative deviation means nothing there).

    Parameters
    ----------
    rgb : (H, W, >=3) float, linear, the finished frame (only the RGB is read)
    mask : (H, W) bool, the post's pixels
    reach : int, pixels

    Returns
    -------
    float, a relative standard deviation (0 for a noise-free neighbourhood, or no
    pixel to measure).

    >>> flat = np.ones((8, 8, 3)); mask = np.zeros((8, 8), bool); mask[:, :3] = True
    >>> context_noise(flat, mask)
    0.0
    """
    y = luminance(np.asarray(rgb, dtype=np.float64)[..., :3])
    mask = np.asarray(mask, dtype=bool)
    p = np.pad(y, 1, mode="edge")
    neighbours = (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:]) / 4.0
    near = mask
    for _ in range(reach):
        near = _grow(near)
    floor = 1e-3 * float(np.median(y))
    measured = near & ~_grow(mask) & (neighbours > max(floor, 1e-12))
    if not measured.any():
        return 0.0
    r = (y[measured] - neighbours[measured]) / neighbours[measured]
    return float(1.4826 * np.median(np.abs(r)) / np.sqrt(1.25))


class FrameDenoiser:
    """OIDN on one finished frame after another, as ``settings`` ask.

    On the CPU the device and filters are built once, for the first frame's size, and
    kept (:class:`.oidn.Filters`): a render of many frames pays for building them once.
    Where Blender's OIDN library cannot be called, or the settings ask for the GPU, each
    frame goes through Blender's compositor Denoise node (:func:`compositor_denoise`).
    Both give the same pixels.

    Parameters
    ----------
    settings : DenoiseSettings
    direct : bool
        False: always the compositor (tests compare the two).

    Notes
    -----
    :meth:`close` (or the end of a ``with`` block) frees OIDN's memory; an object
    never closed frees it when collected.
    """

    def __init__(self, settings: DenoiseSettings, direct: bool = True) -> None:
        self.settings = settings
        use_albedo, use_normal = GUIDES[settings.guides]
        self._noise_field = np.zeros((0, 0), np.float32)
        self.filters: oidn.Filters | None = None
        if direct and not settings.gpu and oidn.library() is not None:
            # A device that fails to start leaves the frames to the compositor.
            with contextlib.suppress(oidn.OidnError):
                self.filters = oidn.Filters(
                    settings.prefilter, settings.quality, use_albedo, use_normal
                )

    def __enter__(self) -> FrameDenoiser:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self.filters is not None:
            self.filters.close()

    def __call__(
        self,
        rgba: np.ndarray,
        albedo: np.ndarray | None,
        normal: np.ndarray | None,
        mask: np.ndarray | None = None,
    ) -> np.ndarray:
        """The denoised frame; arguments and result as :func:`denoise_frame`'s."""
        settings = self.settings
        if settings.subsurface_only and mask is None:
            raise ValueError("denoising the subsurface pixels only needs their mask")
        rgb = self._run(rgba, *self._guides(albedo, normal))
        result = np.array(rgba, dtype=np.float32, copy=True)
        if settings.subsurface_only:
            result[..., :3][mask] = rgb[mask]
        else:
            result[..., :3] = rgb
        return result

    def _guides(self, albedo, normal) -> tuple[np.ndarray | None, np.ndarray | None]:
        """The guides the settings use (None for one they do not)."""
        use_albedo, use_normal = GUIDES[self.settings.guides]
        if (use_albedo and albedo is None) or (use_normal and normal is None):
            raise RenderError(
                "denoising the finished frame needs the pass render's Denoising Albedo and Normal"
            )
        return (albedo if use_albedo else None, normal if use_albedo and use_normal else None)

    def _run(self, rgba: np.ndarray, albedo, normal, again: bool = False) -> np.ndarray:
        """(H, W, 3) float32: OIDN's RGB of ``rgba`` with those guides (None: not used).
        ``again``: the guides are the last run's, and on the CPU only the main filter
        runs (:meth:`.oidn.Filters.run_again`)."""
        if self.filters is not None:
            try:
                if again:
                    return self.filters.run_again(rgba)
                return self.filters.run(rgba, albedo, normal)
            except oidn.OidnError as exc:
                raise RenderError(f"denoising the finished frame failed: {exc}") from None
        return compositor_denoise(rgba, albedo, normal, self.settings)

    def _noise(self, height: int, width: int) -> np.ndarray:
        """(H, W) float32 standard normal noise, the same for every frame of a size (as
        Cycles' own noise is, its seed not animated)."""
        if self._noise_field.shape != (height, width):
            rng = np.random.default_rng(0)
            self._noise_field = rng.standard_normal((height, width)).astype(np.float32)
        return self._noise_field

    def beside_stand_in(self, denoised, rgba, mask, albedo, normal) -> np.ndarray:
        """``denoised`` (``rgba`` denoised) with every pixel off ``mask`` taken from a
        second denoise of ``rgba`` whose ``mask`` pixels carry stand-in noise.

        OIDN judges how hard to denoise from the noise it sees round a pixel. The
        post's pixels are a smooth estimate, so in the finished frame the pixels left
        to Cycles (its own subsurface on thin parts, the floor, the background), as
        noisy as in the plain render, came out denoised less than the plain render's.
        The second denoise gives the post's pixels a stand-in for the noise Cycles'
        subsurface would have had there: their value times ``max(1 + σ·g, 0)``, one
        standard normal ``g`` per pixel for all three channels (the same field every
        frame, as Cycles' noise is with its seed not animated), with ``σ`` the
        settings' ``stand_in_gain`` times :func:`context_noise`, at most
        :data:`STAND_IN_MAX`. Its output is kept only off the mask; the post's pixels
        keep the first denoise's. Where ``σ`` is under :data:`STAND_IN_SKIP` (nothing
        noisy round the post's pixels: a world background) the frame is denoised once.

        Parameters
        ----------
        denoised : (H, W, C) float32, ``rgba`` denoised (this object's last run)
        rgba : (H, W, 3|4) float, linear, the finished frame
        mask : (H, W) bool, the post's pixels
        albedo, normal : (H, W, 3) float or None, the raw guides of that run

        Returns
        -------
        (H, W, C) float32, ``denoised`` with its pixels off the mask replaced.
        """
        mask = np.asarray(mask, dtype=bool)
        if self.settings.stand_in_gain <= 0.0 or not mask.any() or mask.all():
            return denoised
        sigma = min(self.settings.stand_in_gain * context_noise(rgba, mask), STAND_IN_MAX)
        if sigma < STAND_IN_SKIP:
            return denoised
        g = self._noise(*mask.shape)
        noisy = np.array(rgba[..., :3], dtype=np.float32, copy=True)
        noisy[mask] *= np.maximum(1.0 + sigma * g[mask], 0.0)[:, None]
        rest = self._run(noisy, *self._guides(albedo, normal), again=True)
        out = np.array(denoised, dtype=np.float32, copy=True)
        out[..., :3][~mask] = rest[~mask]
        return out

    def finished(self, rgba: np.ndarray, result, frame, guides) -> np.ndarray:
        """The finished frame ``rgba`` of ``result`` (a method's FrameResult on
        ``frame``, its passes) denoised as the settings ask: the whole frame, guided
        by ``guides`` ((albedo, normal), :func:`guides_of`), or, with
        ``subsurface_only`` (EEVEE), the post's lighting alone.

        With ``stand_in_gain`` a whole frame is denoised twice: the post's pixels keep
        the first denoise's values, every other pixel takes a second one's, of the
        frame with stand-in noise on the post's pixels (:meth:`beside_stand_in`).

        EEVEE's passes carry no noise: the noise of its finished frame is that of the
        post's lighting L (:attr:`FrameResult.sss`, no albedo in it, the passes' B off
        the subsurface pixels). OIDN denoises L without guides and the composite is
        made again with it (:func:`core.result.relit`), so only the subsurface pixels
        change and the albedo's texture never goes through the denoiser.

        Returns
        -------
        (H, W, 4) float32: denoised RGB, ``rgba``'s alpha.
        """
        if not self.settings.subsurface_only:
            denoised = self(rgba, *guides, result.mask)
            return self.beside_stand_in(denoised, rgba, result.mask, *guides)
        lighting = np.ones((*result.sss.shape[:2], 4), np.float32)
        lighting[..., :3] = result.sss
        out = np.array(rgba, dtype=np.float32, copy=True)
        out[..., :3] = relit(frame, result.mask, self._run(lighting, None, None))
        return out


def denoise_frame(
    rgba: np.ndarray,
    albedo: np.ndarray | None,
    normal: np.ndarray | None,
    settings: DenoiseSettings,
    mask: np.ndarray | None = None,
) -> np.ndarray:
    """OIDN on a finished frame, as ``settings`` ask (one frame: :class:`FrameDenoiser`
    keeps its filters for the next).

    Parameters
    ----------
    rgba : (H, W, 3|4) float, linear, top row first
        The finished frame; its alpha (if any) is kept as it is.
    albedo : (H, W, 3) float or None
        The pass render's Denoising Albedo (raw: it is prefiltered as Cycles does).
    normal : (H, W, 3) float or None
        The pass render's Denoising Normal.
    settings : DenoiseSettings
    mask : (H, W) bool, optional
        The subsurface pixels; with ``settings.subsurface_only`` only they take the
        denoised RGB (required then).

    Returns
    -------
    (H, W, C) float32, like ``rgba``: denoised RGB, the same alpha.

    Raises
    ------
    RenderError
        The guides the settings ask for are missing, OIDN failed, or the render was
        cancelled.
    OutputError
        The compositor wrote no file.
    """
    with FrameDenoiser(settings) as denoiser:
        return denoiser(rgba, albedo, normal, mask)


def compositor_denoise(
    rgba: np.ndarray,
    albedo: np.ndarray | None,
    normal: np.ndarray | None,
    settings: DenoiseSettings,
) -> np.ndarray:
    """Blender's compositor Denoise node on ``rgba``'s RGB, in a temporary scene.

    Arguments as :func:`denoise_frame`'s (the guides the settings use, or None);
    returns (H, W, 3) float32, top row first.
    """
    height, width = rgba.shape[:2]
    with (
        tempfile.TemporaryDirectory(prefix="cvsss-denoise-frame-") as folder,
        _datablocks() as made,
    ):
        scene = bpy.data.scenes.new("cvsss denoise frame")
        made.append(scene)
        tree = bpy.data.node_groups.new("cvsss denoise frame", "CompositorNodeTree")
        made.append(tree)
        r = scene.render
        r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
        r.use_compositing, r.use_sequencer = True, False
        r.compositor_denoise_device = "GPU" if settings.gpu else "CPU"
        scene.compositing_node_group = tree
        denoise = tree.nodes.new("CompositorNodeDenoise")
        inputs = [("Image", rgba, False)]
        if albedo is not None:
            inputs.append(("Albedo", albedo, False))
        if normal is not None:
            inputs.append(("Normal", normal, True))
        for socket, pixels, non_color in inputs:
            image = _image(f"cvsss denoise {socket}", pixels, non_color)
            made.append(image)
            node = tree.nodes.new("CompositorNodeImage")
            node.image = image
            source = node.outputs["Image"]
            tree.links.new(
                source if socket == "Image" else tree_copy(tree, source), denoise.inputs[socket]
            )
        denoise.inputs["HDR"].default_value = True
        denoise.inputs["Prefilter"].default_value = PREFILTER[settings.prefilter]
        denoise.inputs["Quality"].default_value = QUALITY[settings.quality]
        out = denoised_file_output(tree, folder, "NONE")
        out.file_output_items.new("RGBA", "F")
        tree.links.new(denoise.outputs["Image"], out.inputs["F"])
        with internal_render():
            finished = "FINISHED" in bpy.ops.render.render(scene=scene.name)
        if not finished:
            raise RenderError("denoising the finished frame was cancelled")
        written = sorted(Path(folder).glob("*.exr"))
        if len(written) != 1:
            raise OutputError(Path(folder), "the compositor wrote no denoised frame")
        exr = OpenEXR.File(str(written[0]), separate_channels=True)
        channels = {key: np.asarray(c.pixels) for p in exr.parts for key, c in p.channels.items()}
    return np.stack([channels[f"F.{c}"] for c in "RGB"], -1).astype(np.float32)


#: The guiding passes of Cycles' denoiser, as the pass render stores them.
GUIDE_PASSES = {"Denoising Albedo": "RGB", "Denoising Normal": "XYZ"}


def read_guides(path: str | os.PathLike, layer: str) -> tuple[np.ndarray | None, ...]:
    """(albedo, normal) of view layer ``layer`` in a pass EXR: (H, W, 3) float32 each, top
    row first, None for one the file lacks."""
    with quiet_native_stderr():
        return guides_of(read_channels(path), layer)


def guides_of(channels: Mapping[str, np.ndarray], layer: str) -> tuple[np.ndarray | None, ...]:
    """:func:`read_guides` from a pass file's channels (:func:`core.io.exr.read_channels`)."""
    guides = []
    for name, letters in GUIDE_PASSES.items():
        keys = [f"{layer}.{name}.{c}" for c in letters]
        guides.append(
            np.stack([channels[k] for k in keys], -1).astype(np.float32)
            if all(k in channels for k in keys)
            else None
        )
    return tuple(guides)


class DenoisedProcessor:
    """A method's processor whose results carry a denoised composite (the finished frame
    as the scene's denoiser would give it); everything else is the wrapped processor's.

    Parameters
    ----------
    processor : core.method.Processor
    settings : DenoiseSettings
    guides : callable frame number -> (albedo, normal), or None for a frame that is
        not denoised (warm-up frames, whose results nobody sees)
    """

    def __init__(
        self,
        processor,
        settings: DenoiseSettings,
        guides: Callable[[int], tuple[np.ndarray | None, np.ndarray | None] | None],
    ) -> None:
        self.processor = processor
        self.guides = guides
        self.denoiser = FrameDenoiser(settings)

    def process(self, frame):
        result = self.processor.process(frame)
        guides = self.guides(int(frame.number))
        if guides is None:
            return result
        composite = self.denoiser.finished(result.composite, result, frame, guides)
        return dataclasses.replace(result, composite=composite)

    def __getattr__(self, name: str):
        return getattr(self.processor, name)


def denoising(
    processors: Callable,
    settings: DenoiseSettings,
    guides: Callable[[int], tuple[np.ndarray | None, np.ndarray | None] | None],
) -> Callable:
    """``processors`` (as :class:`core.run.SequenceRun` takes them) whose methods'
    results are denoised (:class:`DenoisedProcessor`); the reference is left as it is."""

    def make(name, params, options):
        processor = processors(name, params, options)
        if name == "reference":
            return processor
        return DenoisedProcessor(processor, settings, guides)

    return make

"""Denoising the passes the post reads with Blender's own OpenImageDenoise.

The pass render writes Cycles' Denoising Albedo and Denoising Normal passes
too (``view_layer.cycles.denoising_store_passes``). :func:`denoise_pass_file`
then loads the pass EXR as an image into a compositor node group of a
temporary scene — Image node → one Denoise node per pass → File Output
(32-bit multilayer EXR) in a temporary folder —, renders that scene (it has
no Render Layers node, so only the compositor runs), and writes the denoised
pixels back into the pass EXR, whose layout stays that of an undenoised
one: the guiding passes are dropped, every other pass (Depth, Material
Index, Vector, Normal) and every header is kept as rendered. The temporary
scene, node group and image are removed afterwards, also on error; the
user's scenes and compositor are never touched.

Guides, measured on the flash demo against 256-spp passes (MSE on SSS
pixels, 4 spp): Combined and Diffuse Color are denoised with the albedo and
normal guides; Diffuse Direct and Indirect, which hold lighting with the
albedo divided out, without guides — OIDN's albedo guide assumes
``image = albedo · lighting`` and keeps albedo edges the lighting passes do
not have (Diffuse Direct came out worse than undenoised with it at 48×32).
Prefilter *Accurate* (the 4-spp guides are noisy themselves), quality *High*.

Diffuse Color is denoised below 16 spp only (:func:`passes_for`). On the
demo scenes at 16 spp (flash, regular, boids; frames 21 and 41, 320×180;
``docs/checks/denoise_passes.py``) the denoised Diffuse Color kept 1.00,
0.95 and 0.88× the undenoised one's squared error on SSS pixels against
256-spp passes, and denoising it took a frame's denoise from 0.67–0.72 s to
0.94–1.02 s; at 4 spp (48×32) it kept 0.82×. Without it, PSNR against
Cycles' ground truth (`none` and `fixed` posts) moved by at most 0.003 dB.
The *Fast* prefilter would denoise a 16-spp frame in 0.29–0.32 s but left
Combined 11–59 % more squared error than *Accurate* on the same frames.
"""

from __future__ import annotations

import contextlib
import tempfile
from pathlib import Path

import bpy
import numpy as np
import OpenEXR

from ...core.io.errors import OutputError
from .errors import RenderError
from .exr_rewrite import rewrite_exr
from .internal_renders import internal_render

#: Passes the post reads and whether each is denoised with the albedo and normal guides.
DENOISED_PASSES = {
    "Combined": True,
    "Diffuse Direct": False,
    "Diffuse Indirect": False,
    "Diffuse Color": True,
}

#: Guiding passes Cycles writes with ``denoising_store_passes`` (dropped after use).
GUIDE_PASSES = ("Denoising Albedo", "Denoising Normal", "Denoising Depth")

#: From this many samples per pixel Diffuse Color is left as rendered (module doc).
COLOR_CLEAN_SPP = 16


def passes_for(samples: int | None) -> list[str]:
    """The passes of :data:`DENOISED_PASSES` denoised for passes rendered at ``samples`` spp.

    >>> passes_for(4)
    ['Combined', 'Diffuse Direct', 'Diffuse Indirect', 'Diffuse Color']
    >>> passes_for(16)
    ['Combined', 'Diffuse Direct', 'Diffuse Indirect']
    """
    clean = samples is not None and samples >= COLOR_CLEAN_SPP
    return [name for name in DENOISED_PASSES if not (clean and name == "Diffuse Color")]


@contextlib.contextmanager
def _temporary(collection, *args):
    """A datablock of ``collection`` (bpy.data.scenes, …) removed when the block ends."""
    block = collection.new(*args)
    try:
        yield block
    finally:
        collection.remove(block)


@contextlib.contextmanager
def _loaded(path: Path):
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        yield image
    finally:
        bpy.data.images.remove(image)


def tree_copy(tree, socket):
    """``socket + 0``: the same pixels as a result of the tree rather than of the image.

    Blender 5.0.1 keeps the prefiltered ("Accurate") guides on the result
    they were computed from; on an Image node's output, which the compositor
    caches, they are never freed (two full-size buffers lost per call,
    reported at exit as "Not freed memory blocks"). On an intermediate
    result they are freed with it.
    """
    node = tree.nodes.new("ShaderNodeVectorMath")
    node.operation = "ADD"
    node.inputs[1].default_value = (0.0, 0.0, 0.0)
    tree.links.new(socket, node.inputs[0])
    return node.outputs[0]


def denoised_file_output(tree, folder: Path | str, codec: str):
    """A File Output node of ``tree`` writing ``folder``/denoised####.exr: a 32-bit
    multilayer EXR of linear data (no view transform), compressed with ``codec``; the
    caller adds its items."""
    out = tree.nodes.new("CompositorNodeOutputFile")
    out.directory = str(folder)
    out.file_name = "denoised"
    out.save_as_render = False  # linear data, no view transform
    fmt = out.format
    if hasattr(fmt, "media_type"):
        fmt.media_type = "MULTI_LAYER_IMAGE"
    fmt.file_format = "OPEN_EXR_MULTILAYER"
    fmt.color_depth = "32"
    fmt.exr_codec = codec
    return out


def _build_tree(tree, image, layer: str, passes: list[str], folder: Path) -> None:
    """Image → Denoise per pass → File Output (multilayer EXR, items named after the passes)."""
    source = tree.nodes.new("CompositorNodeImage")
    source.image = image
    if layer in {item.identifier for item in source.bl_rna.properties["layer"].enum_items}:
        source.layer = layer
    out = denoised_file_output(tree, folder, "ZIP")
    outputs = source.outputs
    guides = {name: tree_copy(tree, outputs[f"Denoising {name}"]) for name in ("Albedo", "Normal")}
    for name in passes:
        node = tree.nodes.new("CompositorNodeDenoise")
        tree.links.new(outputs[name], node.inputs["Image"])
        if DENOISED_PASSES[name]:
            for guide, socket in guides.items():
                tree.links.new(socket, node.inputs[guide])
        node.inputs["HDR"].default_value = True
        node.inputs["Prefilter"].default_value = "Accurate"
        node.inputs["Quality"].default_value = "High"
        out.file_output_items.new("RGBA", name)
        tree.links.new(node.outputs["Image"], out.inputs[name])


def _layout(path: Path, layer: str) -> tuple[set[str], tuple[int, int]]:
    """Pass names of ``layer`` in the EXR, and its (width, height) in pixels."""
    parts = OpenEXR.File(str(path), header_only=True).parts
    low, high = parts[0].header["dataWindow"]
    names = {p.name()[len(layer) + 1 :] for p in parts if p.name().startswith(layer + ".")}
    return names, (int(high[0] - low[0] + 1), int(high[1] - low[1] + 1))


def denoise_pass_file(path: str | Path, layer: str, samples: int | None = None) -> None:
    """Denoise the passes the post reads in a Cycles pass EXR, in place.

    Parameters
    ----------
    path : the pass EXR (multilayer, as the pass render writes it, with the
        ``Denoising Albedo`` and ``Denoising Normal`` passes of ``layer``)
    layer : view layer name (the ``<layer>.<pass>`` prefix)
    samples : Cycles samples per pixel of the passes (None: unknown), which
        choose the passes (:func:`passes_for`)

    Combined, Diffuse Direct, Diffuse Indirect and, below 16 spp, Diffuse
    Color (those the file holds) get their RGB replaced by the denoised RGB
    (Combined keeps its alpha); the guiding passes are removed; the rest is
    unchanged.

    Raises
    ------
    OutputError
        The guiding passes are missing, or the compositor wrote no file.
    """
    path = Path(path)
    present, (width, height) = _layout(path, layer)
    missing = [name for name in ("Denoising Albedo", "Denoising Normal") if name not in present]
    if missing:
        raise OutputError(path, f"no {' or '.join(missing)} pass to guide the denoiser")
    passes = [name for name in passes_for(samples) if name in present]
    with (
        tempfile.TemporaryDirectory(prefix="cvsss-denoise-") as folder,
        _loaded(path) as image,
        _temporary(bpy.data.scenes, "cvsss denoise") as scene,
        _temporary(bpy.data.node_groups, "cvsss denoise", "CompositorNodeTree") as tree,
    ):
        r = scene.render  # the image's size (not known to Blender before it is read)
        r.resolution_x, r.resolution_y, r.resolution_percentage = width, height, 100
        r.use_compositing = True
        r.use_sequencer = False
        r.use_file_extension = True
        scene.compositing_node_group = tree
        _build_tree(tree, image, layer, passes, Path(folder))
        with internal_render():
            finished = "FINISHED" in bpy.ops.render.render(scene=scene.name)
        if not finished:
            raise RenderError(f"denoising {path.name} was cancelled")
        written = sorted(Path(folder).glob("*.exr"))
        if len(written) != 1:
            raise OutputError(path, "the compositor wrote no denoised file")
        exr = OpenEXR.File(str(written[0]), separate_channels=True)
        denoised = {key: np.asarray(c.pixels) for p in exr.parts for key, c in p.channels.items()}

    guides = {f"{layer}.{name}" for name in GUIDE_PASSES}

    def edit(name: str, channels: dict) -> tuple[str, dict] | None:
        if name in guides:
            return None
        pass_name = name[len(layer) + 1 :]
        if pass_name in passes:
            for key in channels:
                channel = key.rpartition(".")[2]
                if channel in ("R", "G", "B"):
                    channels[key] = denoised[f"{pass_name}.{channel}"].astype(np.float32)
        return name, channels

    rewrite_exr(path, edit)

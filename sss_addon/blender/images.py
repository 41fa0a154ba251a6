"""Per-frame maps of a FrameResult as Blender image datablocks.

Each map has one datablock, updated in place frame after frame (rescaled
when the resolution changes). Core images use the EXR row order (top row
first); ``Image.pixels`` start at the bottom row, so rows are flipped here.
Data maps are tagged Non-Color; the result stays scene-linear.
"""

from __future__ import annotations

import bpy
import numpy as np

from ...core.mc.processor import FrameResult

#: Datablock name -> (FrameResult field, is data (Non-Color)).
MAPS = {
    "SSS Sample Count": ("counts", True),
    "SSS CV Alpha": ("alpha", True),
    "SSS Gamma": ("gamma", True),
    "SSS Variance": ("variance", True),
    "SSS Result": ("composite", False),
}


def rgba_rows_flipped(array: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3) image, top row first -> flat RGBA float32, bottom row first.

    Single-channel maps are repeated into R, G and B; alpha is 1.
    """
    a = np.asarray(array, dtype=np.float32)
    height, width = a.shape[:2]
    out = np.ones((height, width, 4), dtype=np.float32)
    out[..., :3] = a[..., None] if a.ndim == 2 else a[..., :3]
    return np.ascontiguousarray(out[::-1]).reshape(-1)


def image_for(name: str, width: int, height: int, data: bool):
    """The float image ``name`` at ``width`` x ``height``, reused when it exists."""
    image = bpy.data.images.get(name)
    if image is not None and (image.source != "GENERATED" or not image.is_float):
        # Someone put a different kind of image under our name: replace it.
        bpy.data.images.remove(image)
        image = None
    if image is None:
        image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    elif tuple(image.size) != (width, height):
        image.scale(width, height)
    colorspace = "Non-Color" if data else None
    if colorspace and image.colorspace_settings.name != colorspace:
        image.colorspace_settings.name = colorspace
    return image


def show_result(result: FrameResult) -> dict[str, object]:
    """Write the maps of ``result`` into their image datablocks.

    Returns
    -------
    dict
        Datablock name -> bpy.types.Image.
    """
    height, width = np.shape(result.counts)
    images = {}
    for name, (field, data) in MAPS.items():
        image = image_for(name, width, height, data)
        image.pixels.foreach_set(rgba_rows_flipped(getattr(result, field)))
        image.update()
        images[name] = image
    return images

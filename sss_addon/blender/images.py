"""Per-frame maps of a FrameResult as Blender image datablocks.

Each map has one datablock, updated in place frame after frame (rescaled
when the resolution changes). The add-on's datablocks carry the custom
property ``cvsss_map`` (the map's name): an image of the user's that has a
map's name is never touched, and the map's datablock then takes Blender's
next free name (``SSS Result.001``). Core images use the EXR row order (top row
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


#: Custom property that marks the add-on's map datablocks (value: the map's name).
TAG = "cvsss_map"


def _generated_float(image) -> bool:
    return image.source == "GENERATED" and image.is_float and image.library is None


def find_map(name: str):
    """The add-on's datablock of map ``name`` (tagged :data:`TAG`), or None."""
    for image in bpy.data.images:
        if image.library is None and image.get(TAG) == name:
            return image
    return None


def image_for(name: str, width: int, height: int, data: bool):
    """The float image of map ``name`` at ``width`` x ``height``, reused when it exists.

    Only the add-on's own datablock is reused (tagged :data:`TAG`). An untagged
    generated float image of that name that nothing uses (an earlier version's)
    is adopted; any other image of the user's keeps its name, pixels and users.
    """
    image = find_map(name)
    if image is not None and not _generated_float(image):
        # The user turned our image into another kind (a file, 8 bits): theirs now.
        del image[TAG]
        image = None
    if image is None:
        old = bpy.data.images.get(name)
        if old is not None and old.get(TAG) is None and _generated_float(old) and old.users == 0:
            image = old
    if image is None:
        image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    image[TAG] = name
    colorspace = "Non-Color" if data else None
    if colorspace and image.colorspace_settings.name != colorspace:
        image.colorspace_settings.name = colorspace
    if tuple(image.size) != (width, height):
        # A generated image is regenerated at its generated size (a colour space change
        # does it): that size, not only the buffer's (Image.scale).
        image.generated_width, image.generated_height = width, height
        if tuple(image.size) != (width, height):
            image.scale(width, height)
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

"""The passes a finished frame is delivered with: the user's, read from the pass render's EXR.

The pass render keeps the user's passes on (:class:`.user_render.KeepingPassSetup`),
so its EXR holds them beside the add-on's own. :class:`FramePasses` picks
the user's out of it for each frame: Combined becomes the finished frame,
Noisy Image (which Cycles writes only when it denoises, and the pass render
does not) the finished frame before its denoise, Object Index and Material
Index go back to the user's numbering (the pass render numbers objects and
materials for the post); every other pass is delivered as rendered.

Blender's multilayer EXR lists a pass's channels alphabetically
(``A, B, G, R``); a render result declares them in Blender's order
(``RGBA``, ``XYZW``, ``UVA``; Cryptomatte ``rgba``), which :func:`pass_layout`
restores.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import OpenEXR

from ....core.io.exr import quiet_native_stderr, use_threads

#: Channel orders of Blender's passes (the EXR sorts them alphabetically).
_ORDERS = ("RGBA", "rgba", "XYZW", "UVA", "XYZ", "RGB")

#: Passes whose values are the add-on's numbering in a pass render.
INDEX_PASSES = ("Object Index", "Material Index")

#: Header fields a delivered result carries again (Cryptomatte's manifests).
STAMP_PREFIXES = ("cryptomatte/",)


def blender_order(channels: str) -> str:
    """``channels`` (letters of one pass, any order) in Blender's order.

    >>> blender_order("ABGR"), blender_order("ZYX"), blender_order("abgr"), blender_order("V")
    ('RGBA', 'XYZ', 'rgba', 'V')
    """
    for order in _ORDERS:
        if set(channels) <= set(order) and len(channels) == len(set(channels)):
            return "".join(c for c in order if c in channels)
    return channels


@dataclass(frozen=True)
class PassSpec:
    """One pass of a render result: its name, channel letters and RNA type."""

    name: str
    channels: str

    @property
    def kind(self) -> str:
        """``COLOR``, ``VALUE`` or ``VECTOR``, as ``RenderEngine.register_pass`` takes it."""
        if self.channels in ("RGBA", "RGB"):
            return "COLOR"
        return "VALUE" if len(self.channels) == 1 else "VECTOR"


def _channels(path: Path) -> dict[str, np.ndarray]:
    use_threads()
    with quiet_native_stderr():
        exr = OpenEXR.File(str(path), separate_channels=True)
    return {key: np.asarray(c.pixels) for part in exr.parts for key, c in part.channels.items()}


def layer_passes(path: Path, layer: str) -> dict[str, np.ndarray]:
    """{pass name: (H, W, C) float32, top row first, channels in Blender's order} of
    ``layer`` in a multilayer EXR."""
    grouped: dict[str, dict[str, np.ndarray]] = {}
    prefix = layer + "."
    for key, pixels in _channels(path).items():
        if key.startswith(prefix):
            name, _, channel = key[len(prefix) :].rpartition(".")
            grouped.setdefault(name, {})[channel] = pixels
    return {
        name: np.stack([chans[c] for c in blender_order("".join(chans))], -1).astype(np.float32)
        for name, chans in grouped.items()
    }


def pass_layout(path: Path, layer: str) -> dict[str, str]:
    """{pass name: channel letters in Blender's order} of ``layer`` in a multilayer EXR."""
    use_threads()
    with quiet_native_stderr():
        parts = OpenEXR.File(str(path), header_only=True).parts
    found: dict[str, str] = {}
    prefix = layer + "."
    for part in parts:
        for key in part.header["channels"]:
            name = getattr(key, "name", key)
            if name.startswith(prefix):
                pass_name, _, channel = name[len(prefix) :].rpartition(".")
                found[pass_name] = found.get(pass_name, "") + channel
    return {name: blender_order(chans) for name, chans in found.items()}


def read_stamp(path: Path) -> dict[str, str]:
    """The header strings of a pass EXR a delivered frame must carry (Cryptomatte)."""
    with quiet_native_stderr():
        header = OpenEXR.File(str(path), header_only=True).parts[0].header
    return {k: str(v) for k, v in header.items() if k.startswith(STAMP_PREFIXES)}


def remap(values: np.ndarray, table: np.ndarray) -> np.ndarray:
    """Whole numbers ``i`` in ``values`` replaced by ``table[i]``; other values kept.

    >>> remap(np.array([0.0, 1.0, 2.0, 2.5, 9.0]), np.array([0, 7, 3]))
    array([0. , 7. , 3. , 2.5, 9. ], dtype=float32)
    """
    whole = np.rint(values)
    inside = (whole == values) & (whole >= 0) & (whole < len(table))
    index = np.where(inside, whole, 0).astype(np.int64)
    return np.where(inside, table[index], values).astype(np.float32)


@dataclass
class Delivery:
    """One finished frame as :class:`.engine.ResultEngine` hands it to Blender.

    Attributes
    ----------
    passes : dict str -> (H, W, C) float32, top row first
        Pass name -> pixels; ``"Combined"`` is the finished frame (RGBA).
    stamp : dict str -> str
        Header fields the result carries (Cryptomatte manifests).
    """

    passes: dict[str, np.ndarray]
    stamp: dict[str, str] = field(default_factory=dict)


class FramePasses:
    """The user's passes of each frame, from the pass render's EXRs.

    Parameters
    ----------
    wanted : list of str
        The user's passes (:func:`.user_render.user_passes`), Combined first.
    layer : str
        The view layer's name (the EXR's layer prefix).
    tables : mapping pass name -> (N,) int array
        Index passes to renumber: the add-on's number -> the user's
        (:meth:`.user_render.KeepingPassSetup.index_tables`).
    """

    def __init__(self, wanted: list[str], layer: str, tables: Mapping[str, np.ndarray]) -> None:
        self.wanted = list(wanted)
        self.layer = layer
        self.tables = dict(tables)
        self.layout: list[PassSpec] | None = None

    def specs(self, path: Path) -> list[PassSpec]:
        """The passes delivered (the user's that the pass file holds, and Noisy Image),
        in the user's order; read from the first pass file, the same for every frame."""
        if self.layout is None:
            have = pass_layout(path, self.layer)
            have["Combined"] = "RGBA"
            have.setdefault("Noisy Image", "RGBA")
            self.layout = [PassSpec(name, have[name]) for name in self.wanted if name in have]
        return self.layout

    def delivery(self, path: Path, finished: np.ndarray, noisy: np.ndarray | None) -> Delivery:
        """The passes of one frame.

        Parameters
        ----------
        path : the frame's pass EXR
        finished : (H, W, 4) float32, the finished frame (denoised when the scene denoises)
        noisy : (H, W, 4) float32 or None, the finished frame before its denoise
            (None: not denoised, the Noisy Image is the finished frame)
        """
        passes = layer_passes(path, self.layer)
        out: dict[str, np.ndarray] = {}
        for spec in self.specs(path):
            if spec.name == "Combined":
                out[spec.name] = finished
            elif spec.name == "Noisy Image" and spec.name not in passes:
                out[spec.name] = finished if noisy is None else noisy
            elif spec.name in passes:
                pixels = passes[spec.name]
                table = self.tables.get(spec.name)
                out[spec.name] = pixels if table is None else remap(pixels, table)
        return Delivery(out, read_stamp(path))

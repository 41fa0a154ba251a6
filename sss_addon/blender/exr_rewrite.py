"""Rewriting a multilayer EXR in place, part by part (the pass files after Blender wrote them)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import OpenEXR

from ...core.io.exr import use_threads


def rewrite_exr(
    path: Path, edit: Callable[[str, dict], tuple[str, dict] | None], write: bool = True
) -> None:
    """Rewrite a multilayer EXR in place, part by part, keeping every header.

    ``edit(part name, {channel: pixels})`` returns the part's new name and
    channels, or None to drop the part. With ``write`` False the parts are only
    handed to ``edit`` (to read several before rewriting any).
    """
    use_threads()
    exr = OpenEXR.File(str(path), separate_channels=True)
    skip = ("name", "channels", "chunkCount", "version", "type")
    parts = []
    for part in exr.parts:
        header = {k: v for k, v in part.header.items() if k not in skip}
        channels = {key: channel.pixels for key, channel in part.channels.items()}
        edited = edit(part.name(), channels)
        if edited is not None:
            parts.append(OpenEXR.Part(header, edited[1], edited[0]))
    if write:
        OpenEXR.File(parts).write(str(path))

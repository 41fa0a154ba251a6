"""Rewriting a multilayer EXR in place, part by part (the pass files after Blender wrote them)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import OpenEXR

from ...core.io.atomic import write_files
from ...core.io.exr import use_threads


def rewrite_exr(
    path: Path,
    edit: Callable[[str, dict], tuple[str, dict] | None],
    prepare: Callable[[dict], None] | None = None,
) -> None:
    """Rewrite a multilayer EXR in place, part by part, keeping every header; atomically,
    so a run killed meanwhile leaves the file as it was, never half written.

    ``edit(part name, {channel: pixels})`` returns the part's new name and
    channels, or None to drop the part. ``prepare({part name: {channel:
    pixels}})``, when given, sees every part first (an edit that needs several).
    """
    use_threads()
    exr = OpenEXR.File(str(path), separate_channels=True)
    skip = ("name", "channels", "chunkCount", "version", "type")
    read = [
        (
            part.name(),
            {k: v for k, v in part.header.items() if k not in skip},
            {key: channel.pixels for key, channel in part.channels.items()},
        )
        for part in exr.parts
    ]
    if prepare is not None:
        prepare({name: channels for name, _, channels in read})
    parts = []
    for name, header, channels in read:
        edited = edit(name, channels)
        if edited is not None:
            parts.append(OpenEXR.Part(header, edited[1], edited[0]))
    write_files([(Path(path), OpenEXR.File(parts))], overwrite=True)

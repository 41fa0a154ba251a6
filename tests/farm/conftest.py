"""The farm lane: Dask on 127.0.0.1 only, every cluster shut down by its test."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("distributed", reason="needs the cvsss[farm] extra (make venv installs it)")

from cvsss.core.frame import Frame  # noqa: E402
from cvsss.core.io.exr import write_passes  # noqa: E402
from cvsss.core.synthetic import scene_frame  # noqa: E402


def moving_frame(number: int, width: int, height: int, step=(3, 2)) -> Frame:
    """The synthetic flash scene moving ``step`` pixels per frame, with its motion vectors."""
    base = scene_frame("flash", number, width, height)
    yy, xx = np.mgrid[0:height, 0:width]
    jitter = 0.45 * np.sin(0.7 * xx + 1.3 * yy + number)
    motion = np.stack([-step[0] + jitter, -step[1] - jitter], axis=-1).astype(np.float32)

    def shift(a):
        return np.roll(a, (step[1] * number, step[0] * number), axis=(0, 1))

    return Frame(
        number=number,
        lighting=shift(base.lighting),
        albedo=shift(base.albedo),
        combined=shift(base.combined),
        depth=shift(base.depth),
        material=shift(base.material),
        camera=base.camera,
        materials=base.materials,
        motion=motion,
    )


@pytest.fixture(scope="session")
def moving_passes(tmp_path_factory):
    """Pass EXRs of 4 frames of a 96x64 scene moving across tile borders."""
    folder = tmp_path_factory.mktemp("moving") / "passes"
    for n in range(1, 5):
        write_passes(folder / f"{n:04d}.exr", moving_frame(n, 96, 64))
    return folder

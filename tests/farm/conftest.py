"""The farm lane: Dask on 127.0.0.1 only, every cluster shut down by its test."""

from __future__ import annotations

import pytest

pytest.importorskip("distributed", reason="needs the cvsss[farm] extra (make venv installs it)")

from cvsss.core.io.exr import write_passes  # noqa: E402
from cvsss.core.synthetic import moving_frame  # noqa: E402


@pytest.fixture(scope="session")
def moving_passes(tmp_path_factory):
    """Pass EXRs of 4 frames of a 96x64 scene moving across tile borders."""
    folder = tmp_path_factory.mktemp("moving") / "passes"
    for n in range(1, 5):
        write_passes(folder / f"{n:04d}.exr", moving_frame(n, 96, 64))
    return folder

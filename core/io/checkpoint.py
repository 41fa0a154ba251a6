"""Per-method checkpoints: the state a run needs to continue bit for bit after a kill.

A checkpoint is an uncompressed ``.npz`` (zlib on float buffers is slow and
gains little) holding a JSON ``state`` (method, frames done, metric rows, the
run's signature) and the processor's arrays (the per-pixel history). It is
written atomically after every frame (:mod:`.atomic`).
"""

from __future__ import annotations

import io
import json
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from .atomic import write_bytes
from .errors import CheckpointError

#: Value of the state's ``format`` field.
CHECKPOINT_FORMAT = "cvsss-checkpoint/2"


def save(path: str | os.PathLike, state: Mapping, arrays: Mapping[str, np.ndarray]) -> None:
    """Write ``state`` (JSON-ready) and ``arrays`` to ``path`` atomically."""
    buf = io.BytesIO()
    np.savez(buf, state=np.array(json.dumps({"format": CHECKPOINT_FORMAT, **state})), **arrays)
    write_bytes(path, buf.getvalue())


def load(path: str | os.PathLike) -> tuple[dict, dict[str, np.ndarray]]:
    """State dictionary and arrays of a checkpoint written by :func:`save`.

    Raises
    ------
    CheckpointError
        Unreadable, truncated, or not a checkpoint of this format.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as data:
            state = json.loads(str(data["state"]))
            arrays = {k: np.asarray(data[k]) for k in data.files if k != "state"}
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        raise CheckpointError(
            f"{os.fspath(path)}: unreadable checkpoint ({type(exc).__name__}: {exc}); "
            "pass --overwrite to start over"
        ) from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{os.fspath(path)}: not a {CHECKPOINT_FORMAT} checkpoint; pass --overwrite to "
            "start over"
        )
    return state, arrays

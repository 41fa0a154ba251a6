"""The errors of file input and output, each naming the file and the problem."""

from __future__ import annotations

import os
from pathlib import Path


class PassError(ValueError):
    """An input file cannot be used; the message names the file and the problem."""


class OutputError(OSError):
    """An output file cannot be written; the message names the file and the cause.

    Parameters
    ----------
    path : str or PathLike
        File (or folder) that could not be written.
    cause : BaseException or str
        The underlying error; for an ``OSError`` its ``strerror`` is used and
        its ``errno`` kept.
    """

    def __init__(self, path: str | os.PathLike, cause: BaseException | str) -> None:
        if isinstance(cause, OSError) and cause.strerror:
            reason = cause.strerror
        else:
            reason = str(cause) or type(cause).__name__
        super().__init__(f"cannot write {os.fspath(path)}: {reason}")
        self.path = Path(path)
        if isinstance(cause, OSError):
            self.errno = cause.errno


def exists_error(path: Path) -> FileExistsError:
    return FileExistsError(f"{path} already exists (use --overwrite to replace it)")


class CheckpointError(ValueError):
    """A run cannot resume from its checkpoint; the message names it and why."""

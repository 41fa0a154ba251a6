"""Atomic output: every file appears complete under its final name, or not at all.

All writers of the product go through here. Data is written to a temporary
file in the destination folder, named ``.<name>.tmp-<pid>-<hex>`` (plus the
file's own extension where another program must recognise it, e.g. Blender
rendering a ``.exr``), synced, and renamed into place. A run killed at any
instant therefore leaves complete files and, at worst, temporaries that
:func:`remove_stale_temporaries` deletes once their process is gone.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
from pathlib import Path
from typing import IO

from .errors import OutputError, exists_error

# ".<name>.tmp-<pid>-<hex>[.<ext>]"
_TEMP_NAME = re.compile(r"^\..+\.tmp-(\d+)-[0-9a-f]+(?:\.\w+)?$")


def temp_path(path: Path, keep_suffix: bool = False) -> Path:
    """A fresh temporary name beside ``path`` (see module doc).

    ``keep_suffix`` appends the file's extension, for programs that choose
    the format from it (Blender's render output).
    """
    path = Path(path)
    name = f".{path.name}.tmp-{os.getpid()}-{secrets.token_hex(4)}"
    return path.with_name(name + (path.suffix if keep_suffix else ""))


class _Staged:
    """A temporary file beside ``path`` that becomes ``path`` on commit."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.temp = temp_path(path)
        fd = os.open(
            self.temp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_BINARY", 0), 0o666
        )
        self.stream: IO[bytes] = os.fdopen(fd, "wb")

    def finish(self) -> None:
        """Flush the data to disk and close the temporary file."""
        self.stream.flush()
        os.fsync(self.stream.fileno())
        self.stream.close()

    def commit(self, overwrite: bool) -> None:
        """Move the temporary file to its final name."""
        if overwrite:
            os.replace(self.temp, self.path)
        else:
            try:
                # A hard link fails if the name is taken, unlike rename.
                os.link(self.temp, self.path)
            except FileExistsError:
                raise exists_error(self.path) from None
            except OSError:
                # No hard links on this file system: check, then rename.
                if self.path.exists():
                    raise exists_error(self.path) from None
                os.replace(self.temp, self.path)
            else:
                os.unlink(self.temp)
        fsync_dir(self.path.parent)

    def discard(self) -> None:
        """Remove the temporary file if it is still there."""
        with contextlib.suppress(OSError):
            self.stream.close()
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.temp)


def fsync_dir(directory: Path) -> None:
    # Makes the rename durable; not possible on every platform (Windows).
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_files(files: list[tuple[Path, object]], overwrite: bool) -> None:
    """Write several files so that each appears complete or not at all.

    ``files`` pairs a final path with ``bytes`` or an object that writes itself
    into a binary stream (``content.write(stream)``: an ``OpenEXR.File``, a
    checkpoint's archive). All
    temporary files are written and synced before the first is renamed; on
    failure every temporary file is removed, as is any file this call had
    already put in place.

    Raises
    ------
    FileExistsError
        A final name exists and ``overwrite`` is false.
    OutputError
        The folder or a file cannot be written (the cause is in the message).
    """
    if not overwrite:
        for path, _ in files:
            if path.exists():
                raise exists_error(path)
    for folder in dict.fromkeys(path.parent for path, _ in files):
        make_folder(folder)
    staged: list[_Staged] = []
    created: list[Path] = []
    current = files[0][0]
    try:
        for path, content in files:
            current = path
            stage = _Staged(path)
            staged.append(stage)
            if isinstance(content, bytes):
                stage.stream.write(content)
            else:
                content.write(stage.stream)
            stage.finish()
        for stage in staged:
            current = stage.path
            existed = stage.path.exists()
            stage.commit(overwrite)
            if not existed:
                created.append(stage.path)
    except FileExistsError:
        # Only the no-clobber commit raises this: another writer got there first.
        _undo(created)
        raise
    except (OSError, RuntimeError) as exc:
        _undo(created)
        raise OutputError(current, exc) from exc
    except BaseException:
        _undo(created)
        raise
    finally:
        for stage in staged:
            stage.discard()


def make_folder(folder: Path) -> None:
    """Create ``folder`` and its parents, or raise OutputError naming the culprit."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError) as exc:
        # Some part of the path is a file: name it rather than "File exists".
        for ancestor in (folder, *folder.parents):
            if ancestor.exists():
                if not ancestor.is_dir():
                    raise OutputError(ancestor, "not a folder") from exc
                break
        raise OutputError(folder, exc) from exc
    except OSError as exc:
        raise OutputError(folder, exc) from exc


def _undo(created: list[Path]) -> None:
    for path in created:
        with contextlib.suppress(OSError):
            os.unlink(path)


def write_bytes(path: str | os.PathLike, data: bytes, overwrite: bool = True) -> None:
    """Write ``data`` to ``path`` atomically (replacing it unless ``overwrite`` is false).

    Raises
    ------
    FileExistsError
        ``path`` exists and ``overwrite`` is false.
    OutputError
        The folder or file cannot be written (the message names the file and
        the cause, e.g. "No space left on device").
    """
    write_files([(Path(path), data)], overwrite)


def write_text(path: str | os.PathLike, text: str, overwrite: bool = True) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically; see :func:`write_bytes`."""
    write_bytes(path, text.encode("utf-8"), overwrite)


def commit(temp: Path, path: Path) -> None:
    """Move a finished temporary file (written by another program) to ``path``.

    Raises
    ------
    OutputError
        The rename failed; the temporary file is removed.
    """
    try:
        os.replace(temp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            os.unlink(temp)
        raise OutputError(path, exc) from exc
    fsync_dir(Path(path).parent)


def remove_stale_temporaries(folder: Path) -> None:
    """Delete temporary files that a killed run left in ``folder`` (their process is gone)."""
    folder = Path(folder)
    if not folder.is_dir():
        return
    for entry in folder.iterdir():
        match = _TEMP_NAME.match(entry.name)
        if match is None or not entry.is_file():
            continue
        pid = int(match.group(1))
        if pid != os.getpid():
            try:
                os.kill(pid, 0)
                continue  # that process still runs: not ours to remove
            except ProcessLookupError:
                pass
            except (PermissionError, OSError, OverflowError):
                continue
        with contextlib.suppress(OSError):
            entry.unlink()

"""Blender's console output during the add-on's renders in background mode.

Blender prints a ``Saved: '…'`` line for every file its render writes,
including the add-on's temporary pass files, and the nested renders of the
add-on print their own; in a ``blender -b`` log these drown the add-on's one
line per frame. :class:`StdoutFilter` takes them out and lets everything
else through, in order.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile
from collections.abc import Iterator


class StdoutFilter:
    """Keep Blender's lines about the add-on's temporary files off stdout.

    Standard output (file descriptor 1, where Blender prints ``Fra:`` and
    ``Saved:`` lines) goes to a temporary file while a render runs; the
    handlers forward it line by line, without the lines that name ``hide``
    and, inside :meth:`internal`, without anything but error lines (the
    nested renders' chatter); lines that mention an error always pass.
    """

    def __init__(self, hide: str) -> None:
        self.hide = hide.encode()
        self._quiet = 0
        self._saved: int | None = None
        try:
            self._libc = ctypes.CDLL(None)
        except (OSError, TypeError):  # Windows: no C library handle to flush
            self._libc = None

    def _flush(self) -> None:
        sys.stdout.flush()
        if self._libc is not None:
            with contextlib.suppress(Exception):
                self._libc.fflush(None)

    def start(self) -> None:
        self._flush()
        self._file = tempfile.TemporaryFile()
        self._pos = 0
        self._partial = b""
        self._saved = os.dup(1)
        os.dup2(self._file.fileno(), 1)

    def _keep(self, line: bytes) -> bool:
        if b"rror" in line:
            return True
        return not self._quiet and self.hide not in line

    def forward(self, final: bool = False) -> None:
        """Write what was printed since the last call to the real stdout, filtered."""
        if self._saved is None:
            return
        self._flush()
        self._file.seek(self._pos)
        data = self._file.read()
        self._pos += len(data)
        *lines, self._partial = (self._partial + data).split(b"\n")
        kept = b"".join(line + b"\n" for line in lines if self._keep(line))
        if final and self._partial and self._keep(self._partial):
            kept += self._partial
        if kept:
            os.write(self._saved, kept)

    @contextlib.contextmanager
    def internal(self) -> Iterator[None]:
        """Only error lines of what is printed inside the block reach stdout."""
        self.forward()
        self._quiet += 1
        try:
            yield
        finally:
            self.forward()
            self._quiet -= 1

    def stop(self) -> None:
        if self._saved is None:
            return
        self.forward(final=True)
        os.dup2(self._saved, 1)
        os.close(self._saved)
        self._saved = None
        self._file.close()

"""Running the ``cvsss`` command line in a child process, as a user would."""

from __future__ import annotations

import subprocess
import sys


def run_cli(*args, **kwargs) -> subprocess.CompletedProcess:
    """``python -m cvsss.sss_addon.cli.main *args``; output captured as text, never raises."""
    return subprocess.run(
        [sys.executable, "-m", "cvsss.sss_addon.cli.main", *map(str, args)],
        capture_output=True,
        text=True,
        check=False,
        **kwargs,
    )

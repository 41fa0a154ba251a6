"""The command line keeps freed memory for the next frame (sss_addon.cli.heap)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

# A frame's churn in a fresh process: ten 20 MiB arrays made and freed, five times
# after a first round; the minor page faults of those five rounds.
_CHURN = """
import json, resource, sys
import numpy as np
from cvsss.sss_addon.cli.heap import keep_freed_memory
kept = keep_freed_memory()

def churn():
    arrays = [np.ones(20 << 17) for _ in range(10)]
    del arrays

churn()
r0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(5):
    churn()
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - r0
print(json.dumps({"kept": kept, "faults": faults}))
"""


def _churn(keep: str) -> dict:
    env = {**os.environ, "CVSSS_KEEP_HEAP": keep}
    out = subprocess.run(
        [sys.executable, "-c", _CHURN], capture_output=True, text=True, env=env, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc (Linux)")
def test_freed_memory_is_kept_for_the_next_frame():
    """With the thresholds raised, 200 MiB of arrays made again after being freed touch
    no new pages; with them left as they are (CVSSS_KEEP_HEAP=0) glibc gave the memory
    back and each round faults it in anew (thousands of faults per round)."""
    kept, default = _churn("1"), _churn("0")
    assert kept["kept"] is True and default["kept"] is False
    assert default["faults"] > 5 * 1000
    assert kept["faults"] < default["faults"] / 20


def test_keep_freed_memory_can_be_turned_off():
    from cvsss.sss_addon.cli.heap import keep_freed_memory

    assert keep_freed_memory({"CVSSS_KEEP_HEAP": "0"}) is False

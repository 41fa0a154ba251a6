"""Are two post-process outputs the same? Layer by layer, figure by figure.

Used to show that a distributed run (``cvsss post --workers N``, core.tiling)
reproduces the run without workers bit for bit. Wall-clock timings
(``sampling_ms``, ``frame_ms`` in metrics.csv, ``cvsss.sampling_ms`` / ``update_ms`` / ``total_ms``
in the result headers) are left out: they differ between any two runs.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path

import numpy as np

from ..io.exr import read_result

#: Figures that are wall-clock times (differ between any two runs).
TIMING_COLUMNS = ("sampling_ms", "frame_ms")
TIMING_HEADERS = ("cvsss.sampling_ms", "cvsss.update_ms", "cvsss.total_ms")


def _metrics(path: Path) -> list[dict]:
    with path.open(newline="") as fh:
        return [
            {k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in csv.DictReader(fh)
        ]


def _method_folders(folder: Path) -> list[str]:
    """Method result folders (they hold a checkpoint; passes/ and ground_truth/ do not)."""
    return sorted(p.parent.name for p in folder.glob("*/.checkpoint.npz"))


def output_differences(a: str | os.PathLike, b: str | os.PathLike) -> list[str]:
    """What differs between two output folders of ``cvsss post`` (empty: identical).

    Compares metrics.csv row by row (timings aside), the set of result files
    per method, and per result every layer (exact float32 bits) and header
    figure (timings aside).

    Returns
    -------
    list of str, one line per difference.
    """
    a, b = Path(a), Path(b)
    out: list[str] = []
    ma, mb = a / "metrics.csv", b / "metrics.csv"
    if ma.exists() != mb.exists():
        out.append("metrics.csv: only in one folder")
    elif ma.exists():
        ra, rb = _metrics(ma), _metrics(mb)
        if len(ra) != len(rb):
            out.append(f"metrics.csv: {len(ra)} rows against {len(rb)}")
        for i, (x, y) in enumerate(zip(ra, rb)):
            if x != y:
                keys = sorted(k for k in x.keys() | y.keys() if x.get(k) != y.get(k))
                out.append(f"metrics.csv row {i + 1}: {', '.join(keys)} differ")
    methods = _method_folders(a)
    if methods != _method_folders(b):
        out.append(f"method folders differ: {methods} against {_method_folders(b)}")
    for method in methods:
        fa = sorted(p.name for p in (a / method).glob("[0-9]*.exr"))
        fb = (
            sorted(p.name for p in (b / method).glob("[0-9]*.exr")) if (b / method).is_dir() else []
        )
        if fa != fb:
            out.append(f"{method}: result files differ")
        for name in sorted(set(fa) & set(fb)):
            x, y = read_result(a / method / name), read_result(b / method / name)
            hx, hy = x.pop("header"), y.pop("header")
            for key in sorted(hx.keys() | hy.keys()):
                if key.startswith("cvsss.") and key not in TIMING_HEADERS:
                    if hx.get(key) != hy.get(key):
                        out.append(f"{method}/{name}: header {key} differs")
            for layer in sorted(x.keys() | y.keys()):
                if layer not in x or layer not in y:
                    out.append(f"{method}/{name}: layer {layer} only in one")
                elif x[layer].shape != y[layer].shape or not np.array_equal(
                    x[layer].view(np.uint32), y[layer].view(np.uint32)
                ):
                    out.append(f"{method}/{name}: layer {layer} differs")
    return out

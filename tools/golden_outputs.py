"""Fingerprints of every method's output on a folder of passes, on both backends.

A refactoring that must not change behaviour is checked by running this before and
after it and comparing the two files (they must be equal line for line)::

    .venv/bin/python tools/golden_outputs.py out/demo/flash/passes > before.json
    # ... the change ...
    .venv/bin/python tools/golden_outputs.py out/demo/flash/passes > after.json
    diff before.json after.json

Every array field of every frame's :class:`cvsss.core.FrameResult` (the images,
counts, maps) and the processor's state after the last frame are hashed
(SHA-256 of their bytes, dtype and shape); timings are left out. Default
parameters except the backend; ``--distance`` runs the other distance modes too.
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import sys
from pathlib import Path

import numpy as np

from cvsss.core import METHODS, SSSParams, make_processor
from cvsss.core.io.exr import list_frames, read_frame

TIMINGS = ("sampling_ms", "update_ms", "total_ms")


def digest(value) -> str:
    """A short hash of an array's bytes, dtype and shape (or of a number's repr)."""
    h = hashlib.sha256()
    if isinstance(value, np.ndarray):
        a = np.ascontiguousarray(value)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.view(np.uint8).tobytes())
    else:
        h.update(repr(value).encode())
    return h.hexdigest()[:16]


def fingerprints(passes: Path, backend: str, distance: str) -> dict:
    frames = [read_frame(path, number) for number, path in list_frames(passes)]
    params = dataclasses.replace(SSSParams(), backend=backend, distance=distance)
    out = {}
    for name in METHODS:
        proc = make_processor(name, params)
        rows = []
        for frame in frames:
            result = proc.process(frame)
            rows.append(
                {
                    f.name: digest(getattr(result, f.name))
                    for f in dataclasses.fields(result)
                    if f.name not in TIMINGS
                }
            )
        state = {k: digest(v) for k, v in sorted(proc.state().items())}
        out[name] = {"frames": rows, "state": state}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("passes", type=Path, help="folder of pass EXRs (0001.exr, …)")
    parser.add_argument(
        "--distance",
        action="store_true",
        help="also the 'surface' and 'planar' distance modes (default: the default mode only)",
    )
    args = parser.parse_args(argv)
    distances = [SSSParams().distance]
    if args.distance:
        distances += [d for d in ("surface", "cycles", "planar") if d not in distances]
    report = {
        f"{backend}/{distance}": fingerprints(args.passes, backend, distance)
        for backend in ("numpy", "numba")
        for distance in distances
    }
    json.dump(report, sys.stdout, indent=1, sort_keys=True)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Resuming a run: per-method checkpoints, checked against the run before they are used.

A checkpoint (``out/<method>/.checkpoint.npz``, :mod:`core.io.checkpoint`) holds a
method's history and metric rows after its last finished frame, the run's signature
(:meth:`core.run.spec.RunSpec.signature`) and each finished frame's pass files (size
and modification time). A run resumes from it only when it is intact, written by the
same run (passes, methods, parameters) and its frames' files are unchanged.
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..io import checkpoint
from ..io.errors import CheckpointError
from ..mc.processor import check_state
from ..method import Method
from .spec import signature_difference

#: Per-method checkpoint file (inside ``out/<method>/``).
CHECKPOINT_NAME = ".checkpoint.npz"

#: The arrays a checkpoint keeps for light_change and flicker of the next frame.
LAST_ARRAYS = ("run_last_combined", "run_last_light", "run_last_y")

#: (path, size in bytes, modification time in ns) of each file a frame is read from.
Stamps = Sequence[tuple[str, int, int]]


def file_stamps(paths: Sequence[str | os.PathLike]) -> list[tuple[str, int, int]]:
    """(path, size in bytes, ``st_mtime_ns``) of each of ``paths``: what tells a
    changed pass file from the one a checkpoint's frame was computed from
    (``stat`` only: hashing 4K passes would cost more than reading them)."""
    stamps = []
    for path in paths:
        st = os.stat(path)
        stamps.append((os.fspath(path), int(st.st_size), int(st.st_mtime_ns)))
    return stamps


def _is_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_stamps(value: Any) -> bool:
    """Whether ``value`` is a checkpoint's record of a frame's files."""
    return isinstance(value, list) and all(
        isinstance(v, list)
        and len(v) == 3
        and isinstance(v[0], str)
        and _is_int(v[1])
        and _is_int(v[2])
        for v in value
    )


def metric_methods(path: Path) -> set[str]:
    """The methods that have rows in the metrics file ``path``.

    Raises
    ------
    CheckpointError
        The file cannot be read as CSV text.
    """
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            return {row.get("method") or "" for row in csv.DictReader(fh)}
    except (OSError, UnicodeDecodeError, csv.Error) as exc:
        raise CheckpointError(
            f"{os.fspath(path)}: cannot be read ({exc}); pass --overwrite to start over"
        ) from None


def format_frame_ranges(numbers: Sequence[int], limit: int = 12) -> str:
    """``[3, 5, 6, 7, 10]`` -> ``"3, 5-7, 10"`` (at most ``limit`` ranges shown)."""
    ranges: list[str] = []
    nums = sorted(numbers)
    i = 0
    while i < len(nums):
        j = i
        while j + 1 < len(nums) and nums[j + 1] == nums[j] + 1:
            j += 1
        ranges.append(str(nums[i]) if i == j else f"{nums[i]}-{nums[j]}")
        i = j + 1
    if len(ranges) > limit:
        return ", ".join(ranges[:limit]) + f", … ({len(ranges) - limit} more ranges)"
    return ", ".join(ranges)


@dataclass
class Checkpoint:
    """A method's checkpoint, checked against the run (:func:`read_checkpoint`).

    Attributes
    ----------
    done : the frame numbers it covers, in order
    rows : their metric rows
    inputs : per frame of ``done``, its files as [name, size, mtime_ns] lists (None: unknown)
    arrays : the processor's state and the last frame's arrays (:data:`LAST_ARRAYS`)
    shape : (H, W) of its per-pixel arrays, None without
    """

    done: list[int]
    rows: list[dict]
    inputs: list[list | None]
    arrays: dict[str, np.ndarray]
    shape: tuple[int, int] | None


def read_checkpoint(
    path: Path,
    name: str,
    method: Method,
    signature: dict,
    numbers: Sequence[int],
    inputs: Mapping[int, list] | None,
) -> Checkpoint:
    """The checkpoint ``path`` of method ``name``, once it is known to be this run's and
    intact.

    Parameters
    ----------
    path : the checkpoint file; name : the method's name; method : its registry entry
    signature : the run's signature (:meth:`core.run.spec.RunSpec.signature`)
    numbers : the run's frame numbers, in order
    inputs : frame number -> [(path, size, mtime_ns), …] of its files now
        (:func:`file_stamps`), or None (not checked)

    Raises
    ------
    CheckpointError
        Unreadable or damaged (a state field of the wrong type, an array
        missing or of the wrong shape or dtype), written by another run,
        covering frames no longer in their place, or a pass file of a
        frame it covers changed since.
    """
    state, arrays = checkpoint.load(path)
    where = os.fspath(path)

    def damaged(what: str) -> CheckpointError:
        return CheckpointError(
            f"{where}: damaged checkpoint ({what}); pass --overwrite to start over"
        )

    written_by, written = state.get("method"), state.get("signature")
    if not isinstance(written_by, str) or not isinstance(written, dict):
        raise damaged("no method name or run signature")
    if written_by != name or written != signature:
        what = (
            f"method {written_by}"
            if written_by != name
            else signature_difference(written, signature)
        )
        raise CheckpointError(
            f"{where}: written by a different run ({what}); resume with the same "
            "passes, methods and parameters, or pass --overwrite to start over"
        )
    done = state.get("frames_done", [])
    if not isinstance(done, list) or not all(_is_int(n) for n in done):
        raise damaged(f"frames_done is not a list of frame numbers: {done!r:.60}")
    if list(numbers[: len(done)]) != done:
        raise CheckpointError(
            f"{where}: covers frames {format_frame_ranges(done)} but the sequence now holds "
            f"{format_frame_ranges(numbers[: len(done)]) or 'fewer frames'} in their "
            "place; pass --overwrite to start over"
        )
    rows = state.get("rows", [])
    if not isinstance(rows, list):
        raise damaged(f"rows is not a list of metric rows: {rows!r:.60}")
    covered = set(done)
    for row in rows:
        if not (
            isinstance(row, dict)
            and row.get("method") == name
            and _is_int(row.get("frame"))
            and row["frame"] in covered
            and all(
                isinstance(k, str) and (v is None or isinstance(v, str | int | float))
                for k, v in row.items()
            )
        ):
            raise damaged(f"metric row {row!r:.80}")
    recorded = state.get("inputs")
    if recorded is None:
        # Written before the pass files were recorded: they cannot be checked.
        recorded = [None] * len(done)
    elif not (
        isinstance(recorded, list)
        and len(recorded) == len(done)
        and all(v is None or _is_stamps(v) for v in recorded)
    ):
        raise damaged("inputs does not list the files of each frame done")
    check_inputs(where, done, recorded, inputs)
    try:
        shape = check_state(method, arrays)
    except ValueError as exc:
        raise damaged(str(exc)) from None
    if done and method.adaptive and shape is None:
        raise CheckpointError(
            f"{where}: has no history for frame {done[-1]}; pass --overwrite to start over"
        )
    last = [k for k in LAST_ARRAYS if k in arrays]
    if last:
        if len(last) != len(LAST_ARRAYS):
            missing = sorted(set(LAST_ARRAYS) - set(last))
            raise damaged(f"no array {', '.join(missing)}")
        light = arrays["run_last_light"]
        if light.shape != () or light.dtype.kind != "f" or not np.isfinite(light):
            raise damaged(f"run_last_light must be a finite float, got {light!r:.60}")
        want = shape or np.shape(arrays["run_last_y"])
        for key in ("run_last_combined", "run_last_y"):
            value = arrays[key]
            if len(want) != 2 or value.shape != want or value.dtype != np.float32:
                raise damaged(
                    f"{key} must be a {'x'.join(map(str, want))} float32 image, got shape "
                    f"{value.shape} dtype {value.dtype}"
                )
        shape = shape or (int(want[0]), int(want[1]))
    return Checkpoint(list(done), list(rows), list(recorded), arrays, shape)


def check_inputs(
    where: str,
    done: list[int],
    recorded: list[list | None],
    inputs: Mapping[int, list] | None,
) -> None:
    """Refuse a checkpoint (``where``) whose frames ``done`` were computed from files
    that changed since: ``recorded`` per frame against ``inputs`` now."""
    if inputs is None:
        return
    for number, old in zip(done, recorded, strict=True):
        new = inputs.get(number)
        if old is None or new is None:
            continue
        for k in range(max(len(old), len(new))):
            was = old[k] if k < len(old) else None
            now = new[k] if k < len(new) else None
            if now is not None and was == [Path(now[0]).name, now[1], now[2]]:
                continue
            path = now[0] if now is not None else was[0]
            raise CheckpointError(
                f"{where}: pass file {os.fspath(path)} changed since frame {number} was "
                "processed (size or modification time); resuming would mix results of "
                "the old and new passes: pass --overwrite to start over"
            )


def recorded_stamps(inputs: Mapping[int, list] | None, number: int) -> list | None:
    """What a checkpoint records of frame ``number``'s files (None: not known)."""
    if inputs is None or number not in inputs:
        return None
    return [[Path(path).name, int(size), int(mtime)] for path, size, mtime in inputs[number]]

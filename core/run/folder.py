"""Post-processing a folder of pass EXRs (the ``cvsss post`` job)."""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from ..frame import Frame
from ..io.errors import PassError
from ..io.exr import list_frames, quiet_native_stderr, read_combined, read_frame
from ..io.sidecar import read_sidecar
from ..method import MethodOptions, Processor
from ..methods import make_processor
from ..params import SSSParams
from .driver import Log, SequenceRun
from .resume import file_stamps, format_frame_ranges
from .spec import RunSpec


def check_sequence(
    passes: Path, frames: Sequence[tuple[int, Path]], allow_gaps: bool = False
) -> list[int]:
    """Refuse a sequence the history cannot run through, before any work.

    Parameters
    ----------
    passes : the pass folder (for messages)
    frames : (number, path) pairs from :func:`core.io.exr.list_frames`
    allow_gaps : accept missing frame numbers

    Returns
    -------
    list of int, the missing frame numbers (empty unless ``allow_gaps``).

    Raises
    ------
    PassError
        Missing frame numbers (listed; unless ``allow_gaps``), a missing or
        invalid sidecar, or frames whose sizes differ (both files named).
    """
    numbers = [n for n, _ in frames]
    have = set(numbers)
    missing = [n for n in range(numbers[0], numbers[-1] + 1) if n not in have]
    if missing and not allow_gaps:
        noun = "frame" if len(missing) == 1 else "frames"
        raise PassError(
            f"{os.fspath(passes)}: {noun} {format_frame_ranges(missing)} missing from the "
            f"sequence {numbers[0]}-{numbers[-1]} (the history runs frame to frame); "
            "render them or pass --allow-gaps"
        )
    first_size = first_path = None
    for _, path in frames:
        cam = read_sidecar(path.with_suffix(".json"), exr_path=path).camera
        if first_size is None:
            first_size, first_path = (cam.width, cam.height), path
        elif (cam.width, cam.height) != first_size:
            raise PassError(
                f"{os.fspath(path)}: frame is {cam.width}x{cam.height} but the sequence "
                f"starts at {first_size[0]}x{first_size[1]} ({first_path.name}); every frame "
                "of a sequence must have the same size"
            )
    return missing


def run_folder(
    passes: str | os.PathLike,
    out: str | os.PathLike,
    spec: RunSpec,
    *,
    existing: str = "error",
    allow_gaps: bool = False,
    log: Log = None,
    warn: Log = None,
    ground_truth: str | os.PathLike | None = None,
    processors: Callable[[str, SSSParams, MethodOptions], Processor] = make_processor,
    lookahead: bool = False,
    submit: Callable[[Callable[[], None]], Any] | None = None,
    before_first: Callable[[Frame], None] | None = None,
) -> list[dict]:
    """Post-process every frame of a folder of pass EXRs (the ``cvsss post`` job).

    Parameters
    ----------
    passes : folder of ``<digits>.exr`` pass files with JSON sidecars
    out : output folder
    spec : RunSpec (its ``source`` is set to the resolved pass folder)
    existing : see the module doc
    allow_gaps : accept missing frame numbers (the history runs across the gap)
    log : receiver of :class:`core.run.driver.Progress` events, or None
    warn : printer of ``warning:`` lines (repaired values, gaps), or None
    ground_truth : folder of ground-truth EXRs (``####.exr``, Cycles' Combined with
        subsurface on), optional; frames that have one get the ground-truth columns
    processors : as :class:`core.run.driver.SequenceRun` (tiled processors: ``cvsss post --workers``)
    lookahead : read each next frame early and start it before the results of the
        current one are written (:meth:`core.run.driver.SequenceRun.step`; for processors that run
        elsewhere: their work then overlaps the writing)
    submit : as :class:`core.run.driver.SequenceRun`: write each frame's files while the next is
        read (``cvsss post`` does)
    before_first : called with the first frame to be processed, before it is (the
        front-ends compile the numba passes there, saying so); not called when
        every frame is done already

    Returns
    -------
    list of metric rows (dicts with METRICS_FIELDS keys), frame by frame in
    method order, including rows restored from checkpoints.

    Raises
    ------
    PassError
        Unusable input: no frames, gaps, a missing or invalid sidecar, frames
        of different sizes, a frame that is not a readable EXR or lacks a pass
        (finished frames and their checkpoints are kept).
    FileExistsError, CheckpointError, OutputError
        As :class:`core.run.driver.SequenceRun`.
    """
    passes = Path(passes)
    frames = list_frames(passes)
    missing = check_sequence(passes, frames, allow_gaps)
    if missing and warn:
        warn(
            f"warning: {os.fspath(passes)}: frames {format_frame_ranges(missing)} are missing; "
            "the history is carried across the gaps as if the frames were consecutive"
        )
    # The folder and its first frame's file: frames rendered again (other size,
    # other scene) make another source, so "continue" starts over; frames
    # added at the end keep it, so a run resumes into them.
    head = frames[0][1].stat()
    source = f"{os.fspath(passes.resolve())} ({frames[0][1].name}: {head.st_size} bytes, "
    source += f"mtime {head.st_mtime_ns})"
    spec = dataclasses.replace(spec, source=source)
    # Every file a frame is read from: a resume refuses a checkpoint whose frames'
    # files changed since (frames rendered again), but not frames added at the end.
    try:
        inputs = {n: file_stamps((path, path.with_suffix(".json"))) for n, path in frames}
    except OSError as exc:
        raise PassError(f"{exc.filename}: cannot be read ({exc.strerror})") from None
    run = SequenceRun(
        out,
        spec,
        [n for n, _ in frames],
        existing=existing,
        log=log,
        processors=processors,
        submit=submit,
        inputs=inputs,
    )
    first: list = []

    def load(number: int, path: Path) -> Frame:
        with quiet_native_stderr():
            frame = read_frame(path, number=number)
        if not first:
            first.append((frame.shape, path))
        elif frame.shape != first[0][0]:
            shape, name = first[0][0], first[0][1].name
            raise PassError(
                f"{os.fspath(path)}: frame is {frame.shape[1]}x{frame.shape[0]} but the sequence "
                f"starts at {shape[1]}x{shape[0]} ({name}); every frame of a "
                "sequence must have the same size"
            )
        if frame.repaired and warn:
            warn(
                f"warning: {os.fspath(path)}: repaired {frame.repaired} non-finite or negative "
                "pass value(s) (colours -> 0, depth -> background, motion -> off screen)"
            )
        return frame

    todo = [(number, path) for number, path in frames if run.pending(number)]
    following = None
    try:
        for k, (number, path) in enumerate(todo):
            frame = following if following is not None else load(number, path)
            if k == 0 and before_first is not None:
                before_first(frame)
            following = load(*todo[k + 1]) if lookahead and k + 1 < len(todo) else None
            gt = None
            if ground_truth is not None:
                gt_path = Path(ground_truth) / f"{number:04d}.exr"
                if gt_path.exists():
                    with quiet_native_stderr():
                        gt = read_combined(gt_path)
            run.step(frame, source=path.name, ground_truth=gt, lookahead=following)
    except BaseException:
        # The frames before this one are kept: their files are finished first. If
        # those fail too, this error still stops the run (theirs is printed).
        try:
            run.wait()
        except Exception as exc:
            if warn:
                warn(f"warning: {exc}")
        raise
    return run.finish()

"""Post-process a directory of pass EXRs frame by frame (no Blender needed).

Layout written under ``out``::

    out/<method>/0001.exr       result layers (see core.exr.write_result)
    out/<method>/.history.npz   checkpoint: history + metric rows after the last finished frame
    out/metrics.csv             frame,method,spp,pass_ms,psnr_db

History is carried from frame to frame per method, so frames are processed in
order. PSNR is luminance PSNR over SSS pixels of the composite against the
``reference`` method, display-referred (see core.metrics.psnr); it is empty
when no reference was computed.

Input checks (each a one-line error naming the file and the problem)
----------------------------------------------------------------------
Before any frame is processed: the folder holds ``<digits>.exr`` frames, the
frame numbers are contiguous (missing numbers are listed; ``allow_gaps``
carries the history across the gap as if the frames were consecutive), every
frame has a sidecar and all frames have the same size. While processing, a
frame that is not a readable EXR, is truncated or lacks a pass stops the run
(finished frames and their checkpoint are kept). Non-finite or negative pass
values are *repaired*, not refused (see core.frame.Frame.repaired): a
``warning:`` line per frame counts them, the result header records the count
(``cvsss.repaired``) and the run goes on.

Nothing lost
------------
Every file (results, checkpoints, metrics) is written to a temporary name in
the same folder, synced and renamed, so a run killed at any instant leaves
complete files only. After each frame, each method's history and metric rows
are checkpointed in ``<method>/.history.npz``. ``resume`` continues each
method after its checkpoint and gives bit-identical results to an
uninterrupted run (timings aside); it only replaces result files of frames
after the checkpoint, which the interrupted run wrote. Without ``overwrite``
or ``resume``, existing results, checkpoints or ``metrics.csv`` are an error:
nothing that exists is ever replaced unasked.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import os
import re
import sys
import tempfile
import time
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.eval.metrics import psnr
from ...core.io.exr import (
    OutputError,
    PassError,
    list_frames,
    make_folder,
    read_frame,
    read_sidecar,
    write_result,
)
from ...core.mc.history import History
from ...core.mc.processor import SequenceProcessor
from ...core.params import SSSParams

METRICS_FIELDS = ("frame", "method", "spp", "pass_ms", "psnr_db")

#: Per-method checkpoint file (inside ``out/<method>/``).
CHECKPOINT_NAME = ".history.npz"
CHECKPOINT_FORMAT = "cvsss-post-checkpoint/1"

# Temporary files of the atomic writers: ".<name>.tmp-<pid>[-<hex>]".
_TEMP_NAME = re.compile(r"^\..+\.tmp-(\d+)(?:-[0-9a-f]+)?$")


class CheckpointError(ValueError):
    """A run cannot resume from its checkpoint; the message names it and why."""


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a synced temporary file and rename.

    ``path`` holds either its previous content or ``data``, never a part;
    the temporary file is removed on failure.

    Raises
    ------
    OutputError
        The folder or file cannot be written (the message names the file and
        the cause, e.g. "No space left on device").
    """
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}-{os.urandom(4).hex()}")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise OutputError(path, exc) from exc


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically; see :func:`write_bytes_atomic`."""
    write_bytes_atomic(path, text.encode("utf-8"))


def format_clock(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``) of a duration in seconds, for progress lines."""
    minutes, sec = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{sec:02d}" if hours else f"{minutes}:{sec:02d}"


def format_metrics(rows: Sequence[dict]) -> str:
    """CSV text of metric rows (``METRICS_FIELDS`` columns)."""
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=METRICS_FIELDS, lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: row.get(k, "") for k in METRICS_FIELDS})
    return buf.getvalue()


def _fmt(value: float | None, digits: int = 4) -> str:
    if value is None or value != value:  # None or NaN
        return ""
    return f"{value:.{digits}f}"


def _warn_stderr(message: str) -> None:
    print(message, file=sys.stderr)


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


def check_sequence(
    passes: Path, frames: Sequence[tuple[int, Path]], allow_gaps: bool = False
) -> list[int]:
    """Refuse a sequence the history cannot run through, before any work.

    Parameters
    ----------
    passes : the pass folder (for messages)
    frames : (number, path) pairs from :func:`core.exr.list_frames`
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


@dataclass
class _MethodRun:
    """One method's processor and what it has finished (a prefix of the frames)."""

    name: str
    processor: SequenceProcessor
    folder: Path
    done: list[int] = field(default_factory=list)
    rows: list[dict] = field(default_factory=list)
    resumed: bool = False

    @property
    def checkpoint(self) -> Path:
        return self.folder / CHECKPOINT_NAME


def _signature(passes: Path, order: Sequence[str], params: SSSParams) -> dict:
    """What a checkpoint must share with the run that resumes it."""
    return {
        "passes": os.fspath(Path(passes).resolve()),
        "methods": list(order),
        "params": params.to_dict(),
    }


def save_checkpoint(run: _MethodRun, signature: dict) -> None:
    """Write ``run``'s history and metric rows to its checkpoint, atomically."""
    state = {
        "format": CHECKPOINT_FORMAT,
        "method": run.name,
        "frames_done": run.done,
        "rows": run.rows,
        "signature": signature,
    }
    arrays = {"state": np.array(json.dumps(state))}
    history = run.processor.history
    if history is not None:
        arrays.update(history.to_arrays("h_"))
    buf = io.BytesIO()
    # Uncompressed: zlib on float buffers is slow and gains little.
    np.savez(buf, **arrays)
    write_bytes_atomic(run.checkpoint, buf.getvalue())


def load_checkpoint(path: Path) -> tuple[dict, History | None]:
    """State dictionary and history (None for stateless methods) of a checkpoint."""
    try:
        with np.load(path, allow_pickle=False) as data:
            state = json.loads(str(data["state"]))
            history = History.from_arrays(data, "h_") if "h_meta" in data.files else None
    except (OSError, ValueError, KeyError, TypeError, EOFError, zipfile.BadZipFile) as exc:
        raise CheckpointError(
            f"{os.fspath(path)}: unreadable checkpoint ({type(exc).__name__}: {exc}); "
            "pass --overwrite to start over"
        ) from None
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise CheckpointError(
            f"{os.fspath(path)}: not a {CHECKPOINT_FORMAT} checkpoint; pass --overwrite to start over"
        )
    return state, history


def _signature_difference(old: dict, new: dict) -> str:
    if old.get("passes") != new["passes"]:
        return f"passes from {old.get('passes')}, now {new['passes']}"
    if old.get("methods") != new["methods"]:
        return f"methods {','.join(old.get('methods') or [])}, now {','.join(new['methods'])}"
    if old.get("reference_every", 1) != new.get("reference_every", 1):
        return f"reference every {old.get('reference_every', 1)} frames, now {new.get('reference_every', 1)}"
    p_old, p_new = old.get("params") or {}, new["params"]
    diffs = [f"{k} {p_old.get(k)!r} -> {p_new[k]!r}" for k in p_new if p_old.get(k) != p_new[k]]
    return "parameters " + ", ".join(diffs)


def _resume(run: _MethodRun, numbers: list[int], signature: dict) -> None:
    state, history = load_checkpoint(run.checkpoint)
    name = os.fspath(run.checkpoint)
    if state.get("method") != run.name or state.get("signature") != signature:
        what = (
            "method " + str(state.get("method"))
            if state.get("method") != run.name
            else _signature_difference(state.get("signature") or {}, signature)
        )
        raise CheckpointError(
            f"{name}: written by a different run ({what}); resume with the same "
            "passes, methods and parameters, or pass --overwrite to start over"
        )
    done = [int(n) for n in state.get("frames_done", [])]
    if numbers[: len(done)] != done:
        raise CheckpointError(
            f"{name}: covers frames {format_frame_ranges(done)} but the pass folder now holds "
            f"{format_frame_ranges(numbers[: len(done)]) or 'fewer frames'} in their place; "
            "pass --overwrite to start over"
        )
    if done and run.processor.method.adaptive:
        if history is None or history.frame != done[-1]:
            raise CheckpointError(
                f"{name}: has no history for frame {done[-1]}; pass --overwrite to start over"
            )
        run.processor.history = history
    run.done = done
    run.rows = list(state.get("rows", []))
    run.resumed = True


@contextlib.contextmanager
def quiet_native_stderr():
    """Hold back what native code prints on file descriptor 2 inside the block.

    The OpenEXR C library prints one diagnostic line per damaged chunk of a
    truncated file before the Python bindings raise; the PassError raised
    for it already says what is wrong, so on error the lines are dropped
    (one clear message). When the block succeeds they are passed on.
    """
    fd = 2  # where C's stderr writes, whatever sys.stderr is
    try:
        sys.stderr.flush()
        saved = os.dup(fd)
    except (AttributeError, OSError, ValueError):  # no file descriptor 2 (some GUI hosts)
        yield
        return
    failed = False
    try:
        with tempfile.TemporaryFile() as sink:
            os.dup2(sink.fileno(), fd)
            try:
                yield
            except BaseException:
                failed = True
                raise
            finally:
                os.dup2(saved, fd)
                if not failed:
                    sink.seek(0)
                    held = sink.read().decode("utf-8", "replace")
                    if held:
                        sys.stderr.write(held)
    finally:
        os.close(saved)


def _remove_stale_temporaries(folder: Path) -> None:
    """Delete temporary files that a killed run left (their process is gone)."""
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


def post_process(
    passes: Path,
    out: Path,
    methods: Sequence[str],
    params: SSSParams,
    *,
    reference: bool = False,
    overwrite: bool = False,
    resume: bool = False,
    allow_gaps: bool = False,
    log: Callable[[str], None] | None = print,
    warn: Callable[[str], None] | None = _warn_stderr,
    processor_options: dict | None = None,
    reference_every: int = 1,
) -> list[dict]:
    """Post-process every frame of ``passes`` with each method.

    Parameters
    ----------
    passes : directory of ``<digits>.exr`` pass files with JSON sidecars
    out : output directory
    methods : method names (core.methods)
    params : SSSParams
    reference : compute the reference (for PSNR) even if not in ``methods``
    overwrite : replace existing results, checkpoints and metrics
    resume : continue each method after its checkpoint (see module doc)
    allow_gaps : accept missing frame numbers
    log : progress printer, or None
    warn : printer of ``warning:`` lines (repaired values, gaps), or None
    processor_options : extra SequenceProcessor keywords (``profile_factory``,
        ``separable``); part of the resume signature
    reference_every : compute the reference (and PSNR) on the 1st, (k+1)-th, …
        frame of the sequence only; the reference keeps no history, so a
        subset is exact and the other methods are unaffected

    Returns
    -------
    list of metric rows (dicts with METRICS_FIELDS keys), frame by frame in
    method order, including rows restored from checkpoints.

    Raises
    ------
    PassError
        Unusable input (see module doc); the message names the file.
    FileExistsError
        Results exist and neither ``overwrite`` nor ``resume`` was given.
    CheckpointError
        ``resume`` with a checkpoint of a different run, or results without one.
    OutputError
        An output cannot be written (permissions, full disk); nothing
        partial is left under a final name and finished frames are kept.
    """
    if overwrite and resume:
        raise CheckpointError("--resume and --overwrite exclude each other; choose one")
    if (
        isinstance(reference_every, bool)
        or not isinstance(reference_every, int)
        or reference_every < 1
    ):
        raise ValueError(f"reference_every must be an integer >= 1, got {reference_every!r}")
    passes = Path(passes)
    out = Path(out)
    frames = list_frames(passes)
    missing = check_sequence(passes, frames, allow_gaps)
    if missing and warn:
        warn(
            f"warning: {os.fspath(passes)}: frames {format_frame_ranges(missing)} are missing; "
            "the history is carried across the gaps as if the frames were consecutive"
        )
    numbers = [n for n, _ in frames]
    names = list(dict.fromkeys(methods))
    need_ref = reference or "reference" in names
    if need_ref and "reference" not in names:
        names.append("reference")
    # Process the reference first each frame so PSNR is available at once.
    order = (["reference"] if need_ref else []) + [m for m in names if m != "reference"]
    signature = _signature(passes, order, params)
    if reference_every != 1:
        signature["reference_every"] = reference_every
    options = dict(processor_options or {})
    signature["params"].update({k: repr(v) for k, v in sorted(options.items())})

    runs = {
        name: _MethodRun(name, SequenceProcessor(name, params, **options), out / name)
        for name in order
    }
    for run in runs.values():
        existing = [run.folder / p.name for _, p in frames if (run.folder / p.name).exists()]
        has_checkpoint = run.checkpoint.exists()
        if overwrite:
            continue
        if resume and has_checkpoint:
            _resume(run, numbers, signature)
        elif resume and existing:
            raise CheckpointError(
                f"{os.fspath(run.folder)}: {len(existing)} result(s) but no checkpoint "
                f"{CHECKPOINT_NAME} to resume from; pass --overwrite to replace them"
            )
        elif existing or has_checkpoint:
            first = existing[0] if existing else run.checkpoint
            hint = (
                "pass --resume to continue the interrupted run or --overwrite to start over"
                if has_checkpoint
                else "pass --overwrite to replace them"
            )
            raise FileExistsError(
                f"{os.fspath(first)} already exists ({len(existing)} result(s) in "
                f"{os.fspath(run.folder)}); {hint}"
            )
    metrics_path = out / "metrics.csv"
    any_resumed = any(run.resumed for run in runs.values())
    if metrics_path.exists() and not overwrite and not any_resumed:
        raise FileExistsError(
            f"{os.fspath(metrics_path)} already exists (from another run); pass --overwrite "
            "to replace it or choose another --out"
        )

    # Fresh methods get an empty checkpoint first: it marks every result file
    # written after it as this run's (for resume) and fails early if the
    # output folder cannot be written.
    for folder in (out, *(run.folder for run in runs.values())):
        make_folder(folder)
        _remove_stale_temporaries(folder)
    if overwrite:
        # Results this run will not write (frames no longer in the sequence, the
        # reference's skipped frames) must not pass for this run's.
        for run in runs.values():
            planned = {
                p.name
                for i, (_, p) in enumerate(frames)
                if run.name != "reference" or i % reference_every == 0
            }
            for old in run.folder.glob("*.exr"):
                if old.stem.isdigit() and old.name not in planned:
                    old.unlink()
    for run in runs.values():
        if not run.resumed:
            save_checkpoint(run, signature)
        elif log:
            left = len(numbers) - len(run.done)
            where = f"after frame {run.done[-1]}" if run.done else "at the first frame"
            log(f"{run.name}: resuming {where} ({len(run.done)} done, {left} to go)")

    index = {n: i for i, n in enumerate(numbers)}
    rank = {name: i for i, name in enumerate(order)}

    def merged() -> list[dict]:
        rows = [row for run in runs.values() for row in run.rows]
        return sorted(rows, key=lambda r: (index.get(int(r["frame"]), -1), rank[r["method"]]))

    start = time.perf_counter()
    processed = 0
    todo_frames = sum(
        1 for i in range(len(numbers)) if any(i >= len(run.done) for run in runs.values())
    )
    shape = None
    for i, (number, path) in enumerate(frames):
        todo = [run for run in runs.values() if i >= len(run.done)]
        if not todo:
            continue
        with quiet_native_stderr():
            frame = read_frame(path, number=number)
        if shape is None:
            shape, first_path = frame.shape, path
        elif frame.shape != shape:
            raise PassError(
                f"{os.fspath(path)}: frame is {frame.shape[1]}x{frame.shape[0]} but the sequence "
                f"starts at {shape[1]}x{shape[0]} ({first_path.name}); every frame of a "
                "sequence must have the same size"
            )
        if frame.repaired and warn:
            warn(
                f"warning: {os.fspath(path)}: repaired {frame.repaired} non-finite or negative "
                "pass value(s) (colours -> 0, depth -> background, motion -> 0)"
            )
        processed += 1
        ref = None
        if need_ref and i % reference_every == 0:
            # The reference keeps no history, so recomputing it for a method
            # that lags behind after a resume gives the same image.
            ref = runs["reference"].processor.process(frame)
        for run in todo:
            if run.name == "reference" and ref is None:
                run.done.append(number)  # not due on this frame: no result, no row
                save_checkpoint(run, signature)
                continue
            result = ref if run.name == "reference" else run.processor.process(frame)
            value = (
                psnr(result.composite, ref.composite, result.mask, params.exposure) if ref else None
            )
            write_result(
                run.folder / path.name,
                result,
                overwrite=overwrite or run.resumed,
                metadata={"source": path.name},
            )
            run.rows.append(
                {
                    "frame": number,
                    "method": run.name,
                    "spp": _fmt(result.spp),
                    "pass_ms": _fmt(result.pass_ms, 3),
                    "psnr_db": _fmt(value, 3),
                }
            )
            run.done.append(number)
            save_checkpoint(run, signature)
            if log:
                elapsed = time.perf_counter() - start
                eta = elapsed / processed * (todo_frames - processed)
                log(
                    f"frame {i + 1}/{len(frames)} ({number}) {run.name:>9}: spp {result.spp:7.2f}  "
                    f"pass {result.pass_ms:8.2f} ms  psnr {_fmt(value, 2) or '-':>6} dB  "
                    f"[elapsed {elapsed:5.1f} s, eta {eta:5.1f} s]"
                )
        write_text_atomic(metrics_path, format_metrics(merged()))
    rows = merged()
    if not processed:
        write_text_atomic(metrics_path, format_metrics(rows))
        if log:
            log(f"all {len(frames)} frames were already done; nothing to do")
    return rows

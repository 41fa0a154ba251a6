"""The one sequence driver: frame in → results, metric rows, checkpoint.

``cvsss post``, ``cvsss render``, ``cvsss demo`` and the Blender operators all
drive a :class:`SequenceRun`: they hand it frames in order (read from pass
EXRs, rendered on the way, or made in memory) and it runs every method of the
run on each, writes the results, the metric rows and a checkpoint per method,
and resumes from those checkpoints.

Layout written under ``out``::

    out/<method>/0001.exr           result layers (core.io.exr.write_result)
    out/<method>/.checkpoint.npz    history + metric rows after the last finished frame,
                                    with each finished frame's pass files (size, mtime)
    out/metrics.csv                 one row per frame and method (METRICS_FIELDS)

History is carried from frame to frame per method, so frames are processed in
order. ``pass_ms`` is the wall time of the sampling step, ``frame_ms`` of the
method's whole post-process of the frame (ms, this machine). Two quality figures per frame and method (core.eval.metrics):

``psnr_db``
    *self-referenced*: luminance PSNR over SSS pixels of the composite against
    the ``reference`` method, display-referred; empty on frames without a
    reference (``reference_every``: the reference keeps no history, so
    computing it on every k-th frame only is exact).
``light_change``, ``flicker``
    Temporal behaviour: the relative change of the mean lighting B over the
    SSS pixels since the previous frame of the run (same for every method;
    marks flashes and switches), and the method's *flicker*: the mean
    absolute frame-to-frame change of the composite's luminance over the SSS
    pixels whose passes did not change (luminance of Combined within 0.5 %),
    relative to their mean luminance — what animators see as shimmer.
    Empty on the first frame and after a gap (a resumed run keeps them).
``psnr_gt_db``, ``psnr_gt_full_db``, ``ratio_r/g/b``, ``rim_ratio``, ``rim_outer_ratio``, ``rim_contact_ratio``
    *against ground truth* (Cycles' own subsurface, when a ground-truth frame
    is handed to :meth:`SequenceRun.step`): RGB PSNR over SSS pixels and over
    the whole image, the per-channel mean ratio ours/ground truth on SSS
    pixels, and the luminance ratio on silhouette SSS pixels — all of them,
    the outer silhouettes (background or a farther surface across the edge)
    and the contact edges (another material at the same depth), see
    :func:`core.eval.metrics.edge_kinds`; empty without.

Existing results
----------------
``existing`` says what happens to results already in ``out``:

``"error"``
    Refuse (the default of ``cvsss post``): nothing is replaced unasked.
``"resume"``
    Continue each method after its checkpoint; bit-identical to an
    uninterrupted run (timings aside). Refused when the checkpoint belongs
    to another run (other passes, methods or parameters), when a pass file
    of a frame it covers changed since (size or modification time, see
    ``inputs`` of :class:`SequenceRun`), when it is damaged, and when
    ``metrics.csv`` holds rows of a method that is not resumed from its
    checkpoint (rewriting it would drop them).
``"overwrite"``
    Start over, replacing results, checkpoints and metrics.
``"continue"``
    Resume where the checkpoint belongs to the same run, start over
    otherwise (``cvsss render``, ``cvsss demo`` and the Blender operators:
    their results are derived from the pass files they keep).

Every file is written atomically (core.io.atomic), so a run killed at any
instant leaves complete files only; temporaries of dead runs are removed.

Writing in the background
-------------------------
Given ``submit`` (``cvsss post`` passes a one-thread executor's: the core
starts no threads itself), a frame's files — its results, then the
checkpoints, then ``metrics.csv``, in the order an inline run writes them —
are handed over as one job and written while the next frame is read:
encoding a result EXR takes about as long as the frame's subsurface
scattering at 1920×1080, and reading and checking the next frame's passes
leaves a core free. :meth:`SequenceRun.step` waits for the previous frame's
files before any method runs, so the writing never slows the timed steps
(``pass_ms``, ``frame_ms``), and raises their error (OutputError) there;
:meth:`SequenceRun.finish` and :meth:`SequenceRun.wait` wait for the last. A
checkpoint is still written only after its frame's result, so a resumed run
never skips a frame whose file is missing. The files are the same as an
inline run's (timing figures aside).
"""

from __future__ import annotations

import csv
import dataclasses
import io
import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from .eval.color import luminance
from .eval.metrics import channel_ratio, edge_kinds, psnr, psnr_gt
from .frame import Frame
from .io import checkpoint
from .io.atomic import make_folder, remove_stale_temporaries, write_text
from .io.errors import CheckpointError, PassError
from .io.exr import list_frames, quiet_native_stderr, read_combined, read_frame, write_result
from .io.sidecar import read_sidecar
from .mc.processor import check_state
from .methods import MethodOptions, Processor, get_method, make_processor
from .params import SSSParams
from .result import FrameResult

METRICS_FIELDS = (
    "frame",
    "method",
    "spp",
    "pass_ms",
    "frame_ms",
    "psnr_db",
    "psnr_gt_db",
    "psnr_gt_full_db",
    "ratio_r",
    "ratio_g",
    "ratio_b",
    "rim_ratio",
    "rim_outer_ratio",
    "rim_contact_ratio",
    "light_change",
    "flicker",
)

#: Per-method checkpoint file (inside ``out/<method>/``).
CHECKPOINT_NAME = ".checkpoint.npz"

EXISTING = ("error", "resume", "overwrite", "continue")

#: The arrays a checkpoint keeps for light_change and flicker of the next frame.
LAST_ARRAYS = ("run_last_combined", "run_last_light", "run_last_y")

Log = Callable[[str], None] | None

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


def _metric_methods(path: Path) -> set[str]:
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


def format_clock(seconds: float) -> str:
    """``m:ss`` (or ``h:mm:ss``) of a duration in seconds, for progress lines."""
    minutes, sec = divmod(int(round(seconds)), 60)
    hours, minutes = divmod(minutes, 60)
    return f"{hours}:{minutes:02d}:{sec:02d}" if hours else f"{minutes}:{sec:02d}"


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


@dataclass(frozen=True)
class RunSpec:
    """What a run computes; a checkpoint resumes only a run with the same spec.

    Attributes
    ----------
    methods : method names, in the order given (the reference is added when
        ``reference`` is set, and always processed first)
    params : SSSParams
    options : MethodOptions
    reference : compute the reference (for PSNR) even if not in ``methods``
    reference_every : the reference (and PSNR) on the 1st, (k+1)-th, … frame only
    source : identity of the input (the resolved pass folder), part of the signature
    warmup_frames : frames processed before the first one to fill the history
        (:meth:`SequenceRun.warm_up`); part of the signature when > 0
    """

    methods: tuple[str, ...]
    params: SSSParams = field(default_factory=SSSParams)
    options: MethodOptions = field(default_factory=MethodOptions)
    reference: bool = False
    reference_every: int = 1
    source: str = ""
    warmup_frames: int = 0

    def __post_init__(self) -> None:
        names = list(dict.fromkeys(self.methods))
        if not names:
            raise ValueError("at least one method is needed")
        for name in names:
            get_method(name)
        if (
            isinstance(self.reference_every, bool)
            or not isinstance(self.reference_every, int)
            or self.reference_every < 1
        ):
            raise ValueError(
                f"reference_every must be an integer >= 1, got {self.reference_every!r}"
            )
        if (
            isinstance(self.warmup_frames, bool)
            or not isinstance(self.warmup_frames, int)
            or self.warmup_frames < 0
        ):
            raise ValueError(f"warmup_frames must be an integer >= 0, got {self.warmup_frames!r}")
        object.__setattr__(self, "methods", tuple(names))

    @property
    def order(self) -> list[str]:
        """Processing order: the reference first (PSNR is then available at once)."""
        names = list(self.methods)
        need_ref = self.reference or "reference" in names
        return (["reference"] if need_ref else []) + [m for m in names if m != "reference"]

    def signature(self) -> dict:
        """What a checkpoint must share with the run that resumes it."""
        signature = {
            "source": self.source,
            "methods": self.order,
            "params": self.params.to_dict(),
            "options": self.options.to_dict(),
            "reference_every": self.reference_every,
        }
        if self.warmup_frames:
            # Only when used, so checkpoints of runs without warm-up still resume.
            signature["warmup_frames"] = self.warmup_frames
        return signature


def _signature_difference(old: dict, new: dict) -> str:
    if old.get("source") != new["source"]:
        return f"passes from {old.get('source')}, now {new['source']}"
    if old.get("methods") != new["methods"]:
        methods = old.get("methods")
        methods = ",".join(map(str, methods)) if isinstance(methods, list) else repr(methods)
        return f"methods {methods}, now {','.join(new['methods'])}"
    if old.get("reference_every") != new["reference_every"]:
        return f"reference every {old.get('reference_every')} frames, now {new['reference_every']}"
    if old.get("warmup_frames", 0) != new.get("warmup_frames", 0):
        return f"warm-up {old.get('warmup_frames', 0)} frames, now {new.get('warmup_frames', 0)}"
    diffs = []
    for group in ("params", "options"):
        a, b = old.get(group), new[group]
        a = a if isinstance(a, dict) else {}
        diffs += [f"{k} {a.get(k)!r} -> {b[k]!r}" for k in b if a.get(k) != b[k]]
    return "parameters " + ", ".join(diffs)


@dataclass
class _MethodRun:
    """One method's processor and what it has finished (a prefix of the frames)."""

    name: str
    processor: Processor
    folder: Path
    done: list[int] = field(default_factory=list)
    rows: list[dict] = field(default_factory=list)
    #: Per frame of ``done``, its files as [name, size, mtime_ns] lists (None: unknown).
    inputs: list[list | None] = field(default_factory=list)
    resumed: bool = False

    @property
    def checkpoint(self) -> Path:
        return self.folder / CHECKPOINT_NAME


@dataclass
class _Checkpoint:
    """A method's checkpoint, checked against the run (:meth:`SequenceRun._checked`)."""

    done: list[int]
    rows: list[dict]
    inputs: list[list | None]
    arrays: dict[str, np.ndarray]
    shape: tuple[int, int] | None  # (H, W) of its per-pixel arrays, None without


@dataclass
class Step:
    """What one frame of a run produced.

    Attributes
    ----------
    index : int, 1-based position of the frame in the run
    total : int, frames in the run
    frame : int, frame number
    results : dict method -> FrameResult (methods already done before a resume absent)
    rows : list of this frame's metric rows, in processing order
    seconds : float, wall time of the step
    """

    index: int
    total: int
    frame: int
    results: dict[str, FrameResult] = field(default_factory=dict)
    rows: list[dict] = field(default_factory=list)
    seconds: float = 0.0


class SequenceRun:
    """Every method of a run over a sequence of frames, one frame per :meth:`step`.

    Parameters
    ----------
    out : output folder (see module doc); unused when ``write`` is false
    spec : RunSpec
    frames : the frame numbers of the sequence, in order
    existing : {"error", "resume", "overwrite", "continue"}, see module doc
    write : write results, checkpoints and metrics (False: compute only)
    log : progress printer (one line per frame and method), or None
    processors : callable (name, params, options) -> Processor, default
        :func:`core.methods.make_processor`; e.g. tiled processors that run
        elsewhere (core.tiling). A processor with a ``start(frame)`` method is
        started for every method of a frame before the first result is awaited.
    submit : callable, optional
        ``submit(job)`` runs the no-argument callable ``job`` elsewhere and returns
        an object whose ``result()`` waits for it and raises its error (a
        one-thread ``concurrent.futures`` executor's ``submit``): each frame's
        files are written through it while the next frame is read (module doc,
        *Writing in the background*); call :meth:`finish` or :meth:`wait`
        at the end. The arrays of a processor's ``state()`` must then stay
        unchanged by later frames, as the project's processors' do (a History
        is reprojected into new arrays every frame). None: written inline.
    inputs : mapping frame number -> (path, size in bytes, mtime in ns) of each
        file the frame is read from (:func:`file_stamps`), optional. The
        checkpoints record them (by file name) for the frames they cover, and
        a checkpoint whose frames' files changed since is not resumed
        (``"resume"``: CheckpointError naming the first changed file;
        ``"continue"``: the method starts over). Frames added after the last
        one done are not affected. None (or a frame missing): not checked.

    Raises
    ------
    FileExistsError
        Results exist and ``existing`` is ``"error"``.
    CheckpointError
        ``"resume"`` with a checkpoint of a different run, of changed input
        files or damaged, results without one, or ``metrics.csv`` rows of a
        method that is not resumed.
    OutputError
        The output folder cannot be written.
    """

    def __init__(
        self,
        out: str | os.PathLike,
        spec: RunSpec,
        frames: Sequence[int],
        *,
        existing: str = "error",
        write: bool = True,
        log: Log = None,
        processors: Callable[[str, SSSParams, MethodOptions], Processor] = make_processor,
        submit: Callable[[Callable[[], None]], Any] | None = None,
        inputs: Mapping[int, Stamps] | None = None,
    ) -> None:
        if existing not in EXISTING:
            raise ValueError(f"existing must be one of {', '.join(EXISTING)}, got {existing!r}")
        self.out = Path(out)
        self.spec = spec
        self.numbers = [int(n) for n in frames]
        if not self.numbers:
            raise ValueError("a run needs at least one frame")
        self.write = write
        self.log = log
        self._submit = submit if write else None
        self._writing: Any = None  # the last stepped frame's files (submit's handle)
        self._position = {n: i for i, n in enumerate(self.numbers)}
        self._inputs = None if inputs is None else {int(n): list(v) for n, v in inputs.items()}
        # Per resumed method, the (H, W) of its checkpoint's arrays, checked against
        # the first frame it processes (the compiled kernels index them unchecked).
        self._shapes: dict[str, tuple[int, int]] = {}
        self._signature = spec.signature()
        order = spec.order
        self._rank = {name: i for i, name in enumerate(order)}
        self.runs = {
            name: _MethodRun(name, processors(name, spec.params, spec.options), self.out / name)
            for name in order
        }
        self._started = time.perf_counter()
        self._processed = 0
        # Per method, its last frame: (number, luminance of Combined, mean B over
        # SSS pixels, luminance of its composite) for light_change and flicker;
        # float32 so that a resumed run (which reads them from the checkpoint)
        # computes the same figures.
        self._last: dict[str, tuple[int, np.ndarray, float, np.ndarray]] = {}
        if write:
            self._open(existing)
        self._todo_frames = sum(1 for n in self.numbers if self.pending(n))

    # -- opening: existing results, resume -----------------------------------------------
    def _open(self, existing: str) -> None:
        metrics = self.out / "metrics.csv"
        fresh = existing == "overwrite"
        for run in self.runs.values():
            results = sorted(run.folder.glob("[0-9]*.exr")) if run.folder.is_dir() else []
            has_checkpoint = run.checkpoint.exists()
            if fresh:
                continue
            if existing == "continue":
                if has_checkpoint:
                    try:
                        found = self._checked(run)
                    except CheckpointError:
                        continue  # another run's, or damaged: start over
                    self._restore(run, found)
                continue
            if existing == "resume" and has_checkpoint:
                self._restore(run, self._checked(run))
            elif existing == "resume" and results:
                raise CheckpointError(
                    f"{os.fspath(run.folder)}: {len(results)} result(s) but no checkpoint "
                    f"{CHECKPOINT_NAME} to resume from; pass --overwrite to replace them"
                )
            elif results or has_checkpoint:
                first = results[0] if results else run.checkpoint
                hint = (
                    "pass --resume to continue the interrupted run or --overwrite to start over"
                    if has_checkpoint
                    else "pass --overwrite to replace them"
                )
                raise FileExistsError(
                    f"{os.fspath(first)} already exists ({len(results)} result(s) in "
                    f"{os.fspath(run.folder)}); {hint}"
                )
        resumed = any(run.resumed for run in self.runs.values())
        if existing == "error" and metrics.exists() and not resumed:
            raise FileExistsError(
                f"{os.fspath(metrics)} already exists (from another run); pass --overwrite "
                "to replace it or choose another --out"
            )
        if existing == "resume" and metrics.exists():
            # metrics.csv is rewritten from the rows of this run's methods: the rows of
            # a method that is not resumed (another run's, or one whose checkpoint is
            # gone) would be lost.
            kept = {run.name for run in self.runs.values() if run.resumed}
            lost = sorted(_metric_methods(metrics) - kept)
            if lost:
                noun = "method" if len(lost) == 1 else "methods"
                raise CheckpointError(
                    f"{os.fspath(metrics)}: holds the rows of {noun} {', '.join(lost)}, which "
                    f"this run ({', '.join(self.runs)}) does not resume from a checkpoint; "
                    "resume with the methods of the run that wrote it, pass --overwrite to "
                    "start over, or choose another --out"
                )
        for folder in (self.out, *(run.folder for run in self.runs.values())):
            make_folder(folder)
            remove_stale_temporaries(folder)
        for run in self.runs.values():
            if run.resumed:
                if self.log:
                    left = len(self.numbers) - len(run.done)
                    where = f"after frame {run.done[-1]}" if run.done else "at the first frame"
                    self.log(f"{run.name}: resuming {where} ({len(run.done)} done, {left} to go)")
                continue
            # A method that starts over (--overwrite, or "continue" with another run's
            # checkpoint) drops every earlier result first: a run that then stops at
            # frame k must not leave the old run's frames after k beside its own.
            for old in run.folder.glob("[0-9]*.exr"):
                if old.stem.isdigit():
                    old.unlink()
            # A fresh checkpoint marks every result file written after it as this
            # run's (for resume) and fails early if the folder cannot be written.
            self._save(run)()
        if not any(run.resumed for run in self.runs.values()) or fresh:
            write_text(metrics, format_metrics([]))

    def _checked(self, run: _MethodRun) -> _Checkpoint:
        """``run``'s checkpoint, once it is known to be this run's and intact.

        Raises
        ------
        CheckpointError
            Unreadable or damaged (a state field of the wrong type, an array
            missing or of the wrong shape or dtype), written by another run,
            covering frames no longer in their place, or a pass file of a
            frame it covers changed since.
        """
        state, arrays = checkpoint.load(run.checkpoint)
        name = os.fspath(run.checkpoint)

        def damaged(what: str) -> CheckpointError:
            return CheckpointError(
                f"{name}: damaged checkpoint ({what}); pass --overwrite to start over"
            )

        method, signature = state.get("method"), state.get("signature")
        if not isinstance(method, str) or not isinstance(signature, dict):
            raise damaged("no method name or run signature")
        if method != run.name or signature != self._signature:
            what = (
                f"method {method}"
                if method != run.name
                else _signature_difference(signature, self._signature)
            )
            raise CheckpointError(
                f"{name}: written by a different run ({what}); resume with the same "
                "passes, methods and parameters, or pass --overwrite to start over"
            )
        done = state.get("frames_done", [])
        if not isinstance(done, list) or not all(_is_int(n) for n in done):
            raise damaged(f"frames_done is not a list of frame numbers: {done!r:.60}")
        if self.numbers[: len(done)] != done:
            raise CheckpointError(
                f"{name}: covers frames {format_frame_ranges(done)} but the sequence now holds "
                f"{format_frame_ranges(self.numbers[: len(done)]) or 'fewer frames'} in their "
                "place; pass --overwrite to start over"
            )
        rows = state.get("rows", [])
        if not isinstance(rows, list):
            raise damaged(f"rows is not a list of metric rows: {rows!r:.60}")
        covered = set(done)
        for row in rows:
            if not (
                isinstance(row, dict)
                and row.get("method") == run.name
                and _is_int(row.get("frame"))
                and row["frame"] in covered
                and all(
                    isinstance(k, str) and (v is None or isinstance(v, str | int | float))
                    for k, v in row.items()
                )
            ):
                raise damaged(f"metric row {row!r:.80}")
        inputs = state.get("inputs")
        if inputs is None:
            # Written before the pass files were recorded: they cannot be checked.
            inputs = [None] * len(done)
        elif not (
            isinstance(inputs, list)
            and len(inputs) == len(done)
            and all(v is None or _is_stamps(v) for v in inputs)
        ):
            raise damaged("inputs does not list the files of each frame done")
        self._check_inputs(name, done, inputs)
        try:
            shape = check_state(run.processor.method, arrays)
        except ValueError as exc:
            raise damaged(str(exc)) from None
        if done and run.processor.method.adaptive and shape is None:
            raise CheckpointError(
                f"{name}: has no history for frame {done[-1]}; pass --overwrite to start over"
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
        return _Checkpoint(list(done), list(rows), list(inputs), arrays, shape)

    def _check_inputs(self, name: str, done: list[int], inputs: list[list | None]) -> None:
        """Refuse a checkpoint whose frames were computed from files that changed since."""
        if self._inputs is None:
            return
        for number, old in zip(done, inputs, strict=True):
            new = self._inputs.get(number)
            if old is None or new is None:
                continue
            for k in range(max(len(old), len(new))):
                was = old[k] if k < len(old) else None
                now = new[k] if k < len(new) else None
                if now is not None and was == [Path(now[0]).name, now[1], now[2]]:
                    continue
                path = now[0] if now is not None else was[0]
                raise CheckpointError(
                    f"{name}: pass file {os.fspath(path)} changed since frame {number} was "
                    "processed (size or modification time); resuming would mix results of "
                    "the old and new passes: pass --overwrite to start over"
                )

    def _restore(self, run: _MethodRun, found: _Checkpoint) -> None:
        """Continue ``run`` from its checked checkpoint."""
        arrays, done = found.arrays, found.done
        run.processor.restore(arrays)
        if "run_last_y" in arrays and done:
            # What light_change and flicker compare the next frame with.
            self._last[run.name] = (
                done[-1],
                np.asarray(arrays["run_last_combined"]),
                float(arrays["run_last_light"]),
                np.asarray(arrays["run_last_y"]),
            )
        if found.shape is not None:
            self._shapes[run.name] = found.shape
        run.done = done
        run.rows = found.rows
        run.inputs = found.inputs
        run.resumed = True

    def _stamps(self, number: int) -> list | None:
        """What a checkpoint records of frame ``number``'s files (None: not known)."""
        if self._inputs is None or number not in self._inputs:
            return None
        return [
            [Path(path).name, int(size), int(mtime)] for path, size, mtime in self._inputs[number]
        ]

    def _save(self, run: _MethodRun) -> Callable[[], None]:
        """Writes ``run``'s checkpoint as it is now (when called, even if later)."""
        state = {
            "method": run.name,
            "frames_done": list(run.done),
            "rows": list(run.rows),
            "inputs": list(run.inputs),
            "signature": self._signature,
        }
        arrays = dict(run.processor.state())
        last = self._last.get(run.name)
        if last is not None and run.done and last[0] == run.done[-1]:
            arrays["run_last_combined"] = last[1]
            arrays["run_last_light"] = np.array(last[2])
            arrays["run_last_y"] = last[3]
        return partial(checkpoint.save, run.checkpoint, state, arrays)

    def wait(self) -> None:
        """Return once the files of every frame stepped so far are written.

        Raises
        ------
        OutputError
            (or any error of writing) A frame's files could not be written; its
            checkpoint was not, so a resumed run processes that frame again.
        """
        if self._writing is None:
            return
        try:
            self._writing.result()
        except Exception:
            self._writing = None  # its error is raised once
            raise
        # Interrupted (KeyboardInterrupt), the files are still pending: the next
        # call waits for them again.
        self._writing = None

    # -- stepping ----------------------------------------------------------------------------
    def pending(self, number: int) -> bool:
        """Whether some method still has to process frame ``number``."""
        i = self._position[number]
        return any(i >= len(run.done) for run in self.runs.values())

    def reference_due(self, number: int) -> bool:
        """Whether the reference is computed on frame ``number``."""
        return "reference" in self.runs and self._position[number] % self.spec.reference_every == 0

    @property
    def rows(self) -> list[dict]:
        """Metric rows of every method, frame by frame in processing order."""
        rows = [row for run in self.runs.values() for row in run.rows]
        return sorted(
            rows,
            key=lambda r: (self._position.get(int(r["frame"]), -1), self._rank[r["method"]]),
        )

    @property
    def fresh(self) -> bool:
        """No frame processed by any method yet (nor restored from a checkpoint)."""
        return not any(run.done for run in self.runs.values())

    def warm_up(self, frame: Frame) -> None:
        """Process ``frame``, which precedes the sequence, only to fill the history.

        Nothing is written or recorded: no result, metric row or checkpoint.
        Allowed only while the run is :attr:`fresh` (a resumed run has its
        history); warm-up frames come in order, before the first frame. The
        reference keeps no history and skips them.

        Raises
        ------
        ValueError
            The run has processed (or resumed) frames already.
        """
        if not self.fresh:
            raise ValueError("warm-up frames come before the first frame of a run")
        _feed_history((r.processor for r in self.runs.values() if r.name != "reference"), frame)
        if self.log:
            self.log(f"warm-up frame {int(frame.number)} processed (not written)")

    def start(self, frame: Frame) -> None:
        """Start every processor that can (``start(frame)``) on the pending ``frame``."""
        number = int(frame.number)
        j = self._position[number]
        due = self.reference_due(number)
        for run in self.runs.values():
            start = getattr(run.processor, "start", None)
            if start is not None and j >= len(run.done) and (run.name != "reference" or due):
                start(frame)

    def step(
        self,
        frame: Frame,
        source: str | None = None,
        ground_truth: np.ndarray | None = None,
        lookahead: Frame | None = None,
    ) -> Step:
        """Process ``frame`` (the next pending frame of the sequence) with every method.

        Parameters
        ----------
        frame : Frame, its number one of the run's frames, in order
        source : name recorded in the result headers (the pass file)
        ground_truth : (H, W, 3) float, optional
            The frame path-traced by Cycles with subsurface on (linear); fills
            the ground-truth columns of the metric rows.
        lookahead : Frame, optional
            The next pending frame: every method's result of ``frame`` is
            computed first, then processors that run elsewhere are started on
            ``lookahead`` (:meth:`start`), and only then are the results written,
            so their writing overlaps the next frame's work.

        Returns
        -------
        Step
        """
        number = int(frame.number)
        if number not in self._position:
            raise ValueError(f"frame {number} is not part of this run")
        i = self._position[number]
        began = time.perf_counter()
        step = Step(i + 1, len(self.numbers), number)
        todo = [run for run in self.runs.values() if i >= len(run.done)]
        for run in todo:
            if len(run.done) != i:
                raise ValueError(
                    f"{run.name}: frame {number} comes before frame "
                    f"{self.numbers[len(run.done)]}, which is not done yet"
                )
        if not todo:
            return step
        for run in todo:
            shape = self._shapes.get(run.name)
            if shape is not None and shape != tuple(frame.shape):
                raise CheckpointError(
                    f"{os.fspath(run.checkpoint)}: holds the state of {shape[1]}x{shape[0]} "
                    f"frames but frame {number} is {frame.shape[1]}x{frame.shape[0]}; pass "
                    "--overwrite to start over"
                )
        for run in todo:
            self._shapes.pop(run.name, None)
        if ground_truth is not None and np.shape(ground_truth) != (*frame.shape, 3):
            raise PassError(
                f"frame {number}: the ground truth is {np.shape(ground_truth)[1]}x"
                f"{np.shape(ground_truth)[0]} but the passes are {frame.shape[1]}x{frame.shape[0]}"
            )
        rims = None
        self._processed += 1
        combined_y = luminance(frame.combined.astype(np.float64)).astype(np.float32)
        light_y = luminance(frame.lighting.astype(np.float64))
        previous = self._previous(number)
        light_mean = None
        ref = None
        due = self.reference_due(number)
        # The previous frame's files (``submit``) were written while this frame was
        # read; they are finished before any method runs, so that their encoding
        # does not slow the sampling steps timed below (pass_ms, frame_ms).
        self.wait()
        self.start(frame)
        if due:
            # The reference keeps no history, so recomputing it for a method that
            # lags behind after a resume gives the same image.
            ref = self.runs["reference"].processor.process(frame)
        early: dict[str, FrameResult] = {}
        if lookahead is not None:
            for run in todo:
                if run.name != "reference":
                    early[run.name] = run.processor.process(frame)
            self.start(lookahead)
        # The frame's files, in the order they are written: each at once, or all
        # through ``submit`` once the frame is done.
        files: list[Callable[[], None]] = []
        emit = files.append if self._submit else (lambda write: write())
        for run in todo:
            if run.name == "reference" and ref is None:
                run.done.append(number)  # not due on this frame: no result, no row
                run.inputs.append(self._stamps(number))
                if self.write:
                    emit(self._save(run))
                continue
            if run.name == "reference":
                result = ref
            else:
                result = early.pop(run.name, None) or run.processor.process(frame)
            value = (
                psnr(result.composite, ref.composite, result.mask, self.spec.params.exposure)
                if ref is not None
                else None
            )
            row = {
                "frame": number,
                "method": run.name,
                "spp": _fmt(result.spp),
                "pass_ms": _fmt(result.pass_ms, 3),
                "frame_ms": _fmt(result.total_ms, 3),
                "psnr_db": _fmt(value, 3),
            }
            if ground_truth is not None:
                if rims is None:
                    rims = edge_kinds(result.mask, frame.material, frame.depth)
                row.update(ground_truth_columns(result, ground_truth, rims))
            if light_mean is None:
                light_mean = float(light_y[result.mask].mean()) if result.mask.any() else 0.0
            ours_y = luminance(result.composite.astype(np.float64)).astype(np.float32)
            last = self._last.get(run.name)
            if last is not None and last[0] == previous:
                _, last_combined, last_light, last_y = last
                if last_light > 0:
                    row["light_change"] = _fmt(abs(light_mean - last_light) / last_light)
                with np.errstate(invalid="ignore", divide="ignore"):
                    stable = result.mask & (
                        np.abs(combined_y - last_combined) <= np.float32(0.005) * combined_y
                    )
                if stable.any():
                    level = float(ours_y[stable].astype(np.float64).mean())
                    if level > 0:
                        change = np.abs(ours_y[stable].astype(np.float64) - last_y[stable])
                        row["flicker"] = _fmt(float(change.mean()) / level, 6)
            self._last[run.name] = (number, combined_y, light_mean, ours_y)
            if self.write:
                emit(
                    partial(
                        write_result,
                        run.folder / f"{number:04d}.exr",
                        result,
                        overwrite=True,
                        metadata={"source": source or f"{number:04d}.exr"},
                    )
                )
            run.rows.append(row)
            run.done.append(number)
            run.inputs.append(self._stamps(number))
            if self.write:
                emit(self._save(run))
            step.results[run.name] = result
            step.rows.append(row)
            if self.log:
                elapsed = time.perf_counter() - self._started
                eta = elapsed / self._processed * (self._todo_frames - self._processed)
                self.log(
                    f"frame {i + 1}/{len(self.numbers)} ({number}) {run.name:>9}: "
                    f"spp {result.spp:7.2f}  pass {result.pass_ms:8.2f} ms  "
                    f"psnr {_fmt(value, 2) or '-':>6} dB  "
                    f"[elapsed {format_clock(elapsed)}, eta {format_clock(eta)}]"
                )
        if self.write:
            emit(partial(write_text, self.out / "metrics.csv", format_metrics(self.rows)))
            if self._submit:  # the previous frame's were finished before processing
                self._writing = self._submit(partial(_write_all, files))
        step.seconds = time.perf_counter() - began
        return step

    def _previous(self, number: int) -> int | None:
        """The frame before ``number`` in the run (None for the first)."""
        i = self._position[number]
        return self.numbers[i - 1] if i > 0 else None

    def finish(self) -> list[dict]:
        """Wait for the files in flight (:meth:`wait`), write the metrics when no frame
        needed work (all done before), and return the rows."""
        self.wait()
        if self.write and not self._processed:
            write_text(self.out / "metrics.csv", format_metrics(self.rows))
            if self.log:
                self.log(f"all {len(self.numbers)} frames were already done; nothing to do")
        return self.rows


def _write_all(files: Sequence[Callable[[], None]]) -> None:
    """Write a frame's files in order, stopping at the first that fails."""
    for write in files:
        write()


def _feed_history(processors, frame: Frame) -> None:
    """Feed ``frame`` to ``processors`` and drop the results: only the history changes."""
    for processor in processors:
        processor.process(frame)


class FrameStream:
    """Every method of a run over frames handed over one at a time, with no fixed range.

    The ordered worker of Blender's own render (Apply on Render): frames
    arrive in increasing order — after warm-up frames, possibly over several
    renders (``blender -b -f 1..3`` renders one frame per call) — and the
    processors carry the history from one to the next. Nothing is written;
    the caller keeps what it needs of each :class:`FrameResult`.

    Parameters
    ----------
    spec : RunSpec (``source``, ``reference_every`` and ``warmup_frames`` are not used here)
    """

    def __init__(self, spec: RunSpec) -> None:
        self.spec = spec
        self.processors = {
            name: make_processor(name, spec.params, spec.options) for name in spec.order
        }
        #: Number of the last frame processed (warm-up included), or None.
        self.last: int | None = None
        #: Frames processed (warm-up included).
        self.count = 0

    def _check_order(self, number: int) -> None:
        if self.last is not None and number <= self.last:
            raise ValueError(
                f"frame {number} comes after frame {self.last}: frames are processed in order"
            )

    def warm_up(self, frame: Frame) -> None:
        """Process ``frame`` for the history only (the reference skips it)."""
        number = int(frame.number)
        self._check_order(number)
        _feed_history((p for n, p in self.processors.items() if n != "reference"), frame)
        self.last, self.count = number, self.count + 1

    def step(self, frame: Frame) -> dict[str, FrameResult]:
        """Process ``frame`` with every method; results by method name."""
        number = int(frame.number)
        self._check_order(number)
        results = {name: p.process(frame) for name, p in self.processors.items()}
        self.last, self.count = number, self.count + 1
        return results


def ground_truth_columns(
    result: FrameResult, ground_truth: np.ndarray, rims: dict[str, np.ndarray]
) -> dict:
    """The ground-truth columns of a metric row (see the module doc).

    ``rims`` holds the silhouette pixels by kind (:func:`core.eval.metrics.edge_kinds`).
    """
    ratio = channel_ratio(result.composite, ground_truth, result.mask)
    gt_y = luminance(np.asarray(ground_truth, np.float64))
    ours_y = luminance(np.asarray(result.composite, np.float64))

    def rim(where: np.ndarray) -> float:
        if not where.any():
            return float("nan")
        gt_rim = float(gt_y[where].mean())
        return float(ours_y[where].mean()) / gt_rim if gt_rim > 0 else float("nan")

    every = rims["outer"] | rims["occluded"] | rims["contact"]
    return {
        "psnr_gt_db": _fmt(psnr_gt(result.composite, ground_truth, result.mask), 3),
        "psnr_gt_full_db": _fmt(psnr_gt(result.composite, ground_truth), 3),
        "ratio_r": _fmt(float(ratio[0])),
        "ratio_g": _fmt(float(ratio[1])),
        "ratio_b": _fmt(float(ratio[2])),
        "rim_ratio": _fmt(rim(every)),
        "rim_outer_ratio": _fmt(rim(rims["outer"])),
        "rim_contact_ratio": _fmt(rim(rims["contact"])),
    }


# -- a folder of pass EXRs ------------------------------------------------------------------
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
    prepare: Callable[[Frame], None] | None = None,
) -> list[dict]:
    """Post-process every frame of a folder of pass EXRs (the ``cvsss post`` job).

    Parameters
    ----------
    passes : folder of ``<digits>.exr`` pass files with JSON sidecars
    out : output folder
    spec : RunSpec (its ``source`` is set to the resolved pass folder)
    existing : see the module doc
    allow_gaps : accept missing frame numbers (the history runs across the gap)
    log : progress printer, or None
    warn : printer of ``warning:`` lines (repaired values, gaps), or None
    ground_truth : folder of ground-truth EXRs (``####.exr``, Cycles' Combined with
        subsurface on), optional; frames that have one get the ground-truth columns
    processors : as :class:`SequenceRun` (tiled processors: ``cvsss post --workers``)
    lookahead : read each next frame early and start it before the results of the
        current one are written (:meth:`SequenceRun.step`; for processors that run
        elsewhere: their work then overlaps the writing)
    submit : as :class:`SequenceRun`: write each frame's files while the next is
        read (``cvsss post`` does)
    prepare : called with the first frame to be processed, before it is (the
        front-ends compile the numba kernels there, saying so); not called when
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
        As :class:`SequenceRun`.
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
            if k == 0 and prepare is not None:
                prepare(frame)
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

"""The one sequence driver: frame in → results, metric rows, checkpoint.

:class:`SequenceRun` runs every method of a run over a sequence of frames handed
to it in order, writes each method's results, the metric rows
(:mod:`core.eval.rows`) and a checkpoint per method (:mod:`core.run.resume`), and
resumes from those checkpoints; :class:`FrameStream` is the same without files or a
fixed range, for Blender's own render. What a run reports as it goes are
:class:`Progress` events; the front-ends turn them into text.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np

from ..color import luminance
from ..eval.metrics import edge_kinds
from ..eval.rows import format_metrics, ground_truth_columns, method_row, temporal_columns
from ..frame import Frame
from ..io import checkpoint
from ..io.atomic import make_folder, remove_stale_temporaries, write_text
from ..io.errors import CheckpointError, PassError
from ..io.exr import write_result
from ..method import MethodOptions, Processor
from ..methods import make_processor
from ..params import SSSParams
from ..result import FrameResult
from .resume import (
    CHECKPOINT_NAME,
    Checkpoint,
    Stamps,
    metric_methods,
    read_checkpoint,
    recorded_stamps,
)
from .spec import EXISTING, RunSpec


@dataclass(frozen=True)
class Progress:
    """What a run reports as it goes (:class:`SequenceRun`'s ``log``).

    Attributes
    ----------
    kind : {"frame", "resumed", "warm-up", "nothing to do"}
        ``frame``: a method finished a frame; ``resumed``: a method continues after
        its checkpoint; ``warm-up``: a warm-up frame was processed (not written);
        ``nothing to do``: every frame was done already.
    method : str, the method ("" for run-wide events)
    frame : int or None, the frame number (``resumed``: the last one done)
    index, total : int, 1-based position of the frame in the run, frames in the run
        (``resumed``: frames done and frames in the run)
    result : FrameResult or None (``frame``)
    psnr : float or None, self-referenced PSNR (dB) of the result (``frame``)
    elapsed, eta : float, seconds since the run started and estimated to its end
    """

    kind: str
    method: str = ""
    frame: int | None = None
    index: int = 0
    total: int = 0
    result: FrameResult | None = None
    psnr: float | None = None
    elapsed: float = 0.0
    eta: float = 0.0


#: A receiver of :class:`Progress` events, or None.
Log = Callable[[Progress], None] | None


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
    log : receiver of :class:`Progress` events (a front-end prints them), or None
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
                        found = self._read_checkpoint(run)
                    except CheckpointError:
                        continue  # another run's, or damaged: start over
                    self._restore(run, found)
                continue
            if existing == "resume" and has_checkpoint:
                self._restore(run, self._read_checkpoint(run))
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
            lost = sorted(metric_methods(metrics) - kept)
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
                    last = run.done[-1] if run.done else None
                    self.log(Progress("resumed", run.name, last, len(run.done), len(self.numbers)))
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

    def _read_checkpoint(self, run: _MethodRun) -> Checkpoint:
        """``run``'s checkpoint, checked against this run (:func:`read_checkpoint`)."""
        return read_checkpoint(
            run.checkpoint,
            run.name,
            run.processor.method,
            self._signature,
            self.numbers,
            self._inputs,
        )

    def _restore(self, run: _MethodRun, found: Checkpoint) -> None:
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
            self.log(Progress("warm-up", frame=int(frame.number)))

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
        # does not slow the sampling steps timed below (sampling_ms, frame_ms).
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
                run.inputs.append(recorded_stamps(self._inputs, number))
                if self.write:
                    emit(self._save(run))
                continue
            if run.name == "reference":
                result = ref
            else:
                result = early.pop(run.name, None) or run.processor.process(frame)
            row, value = method_row(number, run.name, result, ref, self.spec.params.exposure)
            if ground_truth is not None:
                if rims is None:
                    rims = edge_kinds(result.mask, frame.material, frame.depth)
                row.update(ground_truth_columns(result, ground_truth, rims))
            if light_mean is None:
                light_mean = float(light_y[result.mask].mean()) if result.mask.any() else 0.0
            ours_y = luminance(result.composite.astype(np.float64)).astype(np.float32)
            last = self._last.get(run.name)
            if last is not None and last[0] == previous:
                row.update(temporal_columns(result.mask, ours_y, combined_y, light_mean, last[1:]))
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
            run.inputs.append(recorded_stamps(self._inputs, number))
            if self.write:
                emit(self._save(run))
            step.results[run.name] = result
            step.rows.append(row)
            if self.log:
                elapsed = time.perf_counter() - self._started
                eta = elapsed / self._processed * (self._todo_frames - self._processed)
                self.log(
                    Progress(
                        "frame",
                        run.name,
                        number,
                        i + 1,
                        len(self.numbers),
                        result,
                        value,
                        elapsed,
                        eta,
                    )  # fmt: skip
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
                self.log(Progress("nothing to do", total=len(self.numbers)))
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

"""core.run: warm-up frames, the open-ended FrameStream of Blender's own render,
writing a frame's files in the background, and what a resume refuses (metric rows it
would drop, changed pass files, damaged checkpoints)."""

import csv
import os
import shutil
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest

from cvsss.core.io import checkpoint
from cvsss.core.io.errors import CheckpointError, OutputError, PassError
from cvsss.core.io.exr import read_result, write_passes
from cvsss.core.methods import make_processor
from cvsss.core.params import SSSParams
from cvsss.core.run import CHECKPOINT_NAME, FrameStream, RunSpec, SequenceRun, run_folder
from cvsss.core.run import driver as run_mod
from cvsss.core.synthetic import scene_frame, sequence

PARAMS = SSSParams(target_variance=1e-6)
SPEC = RunSpec(("as_ocv",), PARAMS)


def _frames(start, count):
    return list(sequence("flash", count, 32, 24, start=start))


def _run(tmp_path, warm, frames):
    spec = RunSpec(("as_ocv",), PARAMS, warmup_frames=len(warm))
    run = SequenceRun(tmp_path, spec, [f.number for f in frames], write=False)
    for frame in warm:
        run.warm_up(frame)
    return [run.step(frame).results["as_ocv"] for frame in frames]


def test_stream_equals_sequence_run_bit_for_bit(tmp_path):
    frames = _frames(1, 4)
    stream = FrameStream(SPEC)
    got = [stream.step(frame)["as_ocv"] for frame in frames]
    want = _run(tmp_path, [], frames)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a.composite, b.composite)
        np.testing.assert_array_equal(a.counts, b.counts)
    assert stream.last == 4 and stream.count == 4


def test_warm_up_fills_the_history_and_writes_nothing(tmp_path):
    warm, frames = _frames(-1, 2), _frames(1, 3)
    stream = FrameStream(SPEC)
    for frame in warm:
        stream.warm_up(frame)
    got = [stream.step(frame)["as_ocv"] for frame in frames]
    want = _run(tmp_path / "warm", warm, frames)
    cold = _run(tmp_path / "cold", [], frames)
    for a, b in zip(got, want, strict=True):
        np.testing.assert_array_equal(a.composite, b.composite)
    # With a history the first frame starts from tracked variances, not the cold start.
    assert not np.array_equal(want[0].counts, cold[0].counts)
    assert not list(tmp_path.rglob("*"))  # write=False: nothing on disk


def test_frames_go_in_order():
    stream = FrameStream(SPEC)
    stream.step(_frames(2, 1)[0])
    for number in (2, 1):
        with pytest.raises(ValueError, match="frames are processed in order"):
            stream.warm_up(_frames(number, 1)[0])


def test_warm_up_only_before_the_first_frame(tmp_path):
    run = SequenceRun(tmp_path, SPEC, [1, 2], write=False)
    run.step(_frames(1, 1)[0])
    with pytest.raises(ValueError, match="before the first frame"):
        run.warm_up(_frames(0, 1)[0])


def test_warm_up_is_part_of_the_signature_only_when_used():
    assert "warmup_frames" not in RunSpec(("as",)).signature()
    assert RunSpec(("as",), warmup_frames=8).signature()["warmup_frames"] == 8
    for bad in (-1, 1.5, True):
        with pytest.raises(ValueError, match="warmup_frames must be an integer >= 0"):
            RunSpec(("as",), warmup_frames=bad)


# -- writing in the background ------------------------------------------------------------------
TIMING = {"sampling_ms", "frame_ms"}
BACKGROUND_SPEC = RunSpec(("as_ccv", "as_ocv_t", "fixed", "reference"), PARAMS, reference_every=2)


def _untimed(rows):
    return [{k: v for k, v in row.items() if k not in TIMING} for row in rows]


def _same_files(a, b):
    """Results (pixels and untimed headers), checkpoints and metrics of two runs."""
    names = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    assert names == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file())
    for name in names:
        if name.suffix == ".exr":
            x, y = read_result(a / name), read_result(b / name)
            for layer in set(x) - {"header"}:
                np.testing.assert_array_equal(x[layer], y[layer])
            untimed = {f"cvsss.{k}" for k in ("sampling_ms", "update_ms", "total_ms")}
            assert {k: v for k, v in x["header"].items() if k not in untimed} == {
                k: v for k, v in y["header"].items() if k not in untimed
            }
        elif name.suffix == ".npz":
            (sx, ax), (sy, ay) = checkpoint.load(a / name), checkpoint.load(b / name)
            assert sx["frames_done"] == sy["frames_done"]
            assert _untimed(sx["rows"]) == _untimed(sy["rows"])
            assert ax.keys() == ay.keys()
            for k in ax:
                np.testing.assert_array_equal(ax[k], ay[k])
        else:
            with open(a / name) as fx, open(b / name) as fy:
                assert _untimed(csv.DictReader(fx)) == _untimed(csv.DictReader(fy))


def test_background_writing_writes_the_files_of_an_inline_run(tmp_path):
    frames = _frames(1, 5)
    numbers = [f.number for f in frames]
    inline = SequenceRun(tmp_path / "inline", BACKGROUND_SPEC, numbers)
    with ThreadPoolExecutor(1) as pool:
        background = SequenceRun(
            tmp_path / "background", BACKGROUND_SPEC, numbers, submit=pool.submit
        )
        for frame in frames:
            inline.step(frame)
            background.step(frame)
        inline.finish()
        background.finish()
    _same_files(tmp_path / "inline", tmp_path / "background")


def test_a_checkpoint_is_the_state_when_its_frame_finished(tmp_path):
    # The writer thread saves frame n's checkpoint while frame n + 1 is processed:
    # what it writes must not change with that frame (the histories of the online
    # and constant CV and of temporal reuse, the metric rows, the frames done).
    frames = _frames(1, 4)
    numbers = [f.number for f in frames]
    inline = SequenceRun(tmp_path / "inline", BACKGROUND_SPEC, numbers)
    late = SequenceRun(tmp_path / "late", BACKGROUND_SPEC, numbers)
    for frame in frames[:3]:
        inline.step(frame)
        late.step(frame)
    saves = [late._save(run) for run in late.runs.values()]
    late.step(frames[3])
    for save in saves:
        save()  # frame 3's checkpoints, written after frame 4
    for run in late.runs.values():
        assert checkpoint.load(run.checkpoint)[0]["frames_done"] == numbers[:3]
    (tmp_path / "late" / "metrics.csv").write_bytes(
        (tmp_path / "inline" / "metrics.csv").read_bytes()
    )
    for name in BACKGROUND_SPEC.order:
        (tmp_path / "late" / name / "0004.exr").unlink(missing_ok=True)
    _same_files(tmp_path / "inline", tmp_path / "late")


def _passes(folder, frames):
    for frame in frames:
        write_passes(folder / f"{frame.number:04d}.exr", frame)
    return folder


def test_a_failed_write_stops_the_run_and_resume_redoes_its_frame(tmp_path, monkeypatch):
    passes = _passes(tmp_path / "passes", _frames(1, 5))
    spec = RunSpec(("as_ccv",), PARAMS)
    run_folder(passes, tmp_path / "whole", spec)

    real = run_mod.write_result

    def full_disk(path, *args, **kwargs):
        if path.name == "0003.exr":
            raise OutputError(path, "No space left on device")
        real(path, *args, **kwargs)

    monkeypatch.setattr(run_mod, "write_result", full_disk)
    out = tmp_path / "out"
    with ThreadPoolExecutor(1) as pool, pytest.raises(OutputError, match="No space left"):
        run_folder(passes, out, spec, submit=pool.submit)
    monkeypatch.undo()
    # Frames 1 and 2 are kept with their checkpoint; frame 3 has neither.
    assert sorted(p.name for p in (out / "as_ccv").glob("*.exr")) == ["0001.exr", "0002.exr"]
    assert checkpoint.load(out / "as_ccv" / ".checkpoint.npz")[0]["frames_done"] == [1, 2]
    run_folder(passes, out, spec, existing="resume")
    _same_files(tmp_path / "whole", out)


def test_a_bad_frame_keeps_the_frames_written_before_it(tmp_path):
    passes = _passes(tmp_path / "passes", _frames(1, 4))
    (passes / "0003.exr").write_bytes(b"not an exr")
    out = tmp_path / "out"
    # Frame 2's files are written only when waited for (_Deferred): run_folder
    # must finish them on its way out of the error.
    with pytest.raises(PassError, match="0003.exr"):
        run_folder(passes, out, RunSpec(("as_ccv",), PARAMS), submit=_Deferred())
    # Frame 2 was pending when frame 3 failed to load: it is finished.
    assert sorted(p.name for p in (out / "as_ccv").glob("*.exr")) == ["0001.exr", "0002.exr"]
    for path in (out / "as_ccv").glob("*.exr"):
        read_result(path)
    assert checkpoint.load(out / "as_ccv" / ".checkpoint.npz")[0]["frames_done"] == [1, 2]


class _Deferred:
    """A ``submit`` whose job runs only when its result is asked for."""

    def __init__(self):
        self.jobs = []

    def __call__(self, job):
        self.jobs.append(job)
        return self

    def result(self):
        while self.jobs:
            self.jobs.pop(0)()


def test_a_frames_files_are_finished_before_the_next_frame_is_processed(tmp_path):
    # Their encoding must not slow the next frame's timed sampling steps.
    frames = _frames(1, 3)
    out = tmp_path / "out"
    seen = []

    def processors(name, params, options):
        processor = make_processor(name, params, options)
        process = processor.process

        def checked(frame):
            before = [p.name for p in sorted((out / name).glob("*.exr"))]
            seen.append((name, frame.number, before))
            return process(frame)

        processor.process = checked
        return processor

    submit = _Deferred()
    run = SequenceRun(out, SPEC, [f.number for f in frames], processors=processors, submit=submit)
    for frame in frames:
        run.step(frame)
        assert not (out / "as_ocv" / f"{frame.number:04d}.exr").exists()  # not yet written
    run.finish()
    want = [[f"{n:04d}.exr" for n in range(1, k)] for k in (1, 2, 3)]
    assert seen == [("as_ocv", k, w) for k, w in zip((1, 2, 3), want, strict=True)]
    assert (out / "as_ocv" / "0003.exr").exists()


class _InterruptedOnce(_Deferred):
    """A Ctrl-C lands while the first wait for a frame's files is under way."""

    interrupted = False

    def result(self):
        if not self.interrupted:
            self.interrupted = True
            raise KeyboardInterrupt
        super().result()


def test_an_interrupted_wait_still_finishes_the_files(tmp_path):
    frames = _frames(1, 2)
    out = tmp_path / "out"
    run = SequenceRun(out, SPEC, [1, 2], submit=_InterruptedOnce())
    run.step(frames[0])
    with pytest.raises(KeyboardInterrupt):
        run.step(frames[1])  # waits for frame 1's files first
    run.wait()  # as run_folder does on the way out
    assert (out / "as_ocv" / "0001.exr").is_file()
    assert checkpoint.load(out / "as_ocv" / ".checkpoint.npz")[0]["frames_done"] == [1]


# -- what a resume refuses ---------------------------------------------------------------------
def _checkpoint_of(out, method="as_ccv"):
    return out / method / CHECKPOINT_NAME


def _edit_checkpoint(path, edit):
    """Rewrite the checkpoint at ``path`` after ``edit(state, arrays)`` (a valid archive)."""
    state, arrays = checkpoint.load(path)
    state.pop("format")
    edit(state, arrays)
    checkpoint.save(path, state, arrays)


def _files(folder):
    return {p: p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_resume_refuses_to_drop_the_metric_rows_of_a_method_it_does_not_resume(tmp_path):
    passes = _passes(tmp_path / "passes", _frames(1, 3))
    out = tmp_path / "out"
    run_folder(passes, out, RunSpec(("as_ccv",), PARAMS))
    before = _files(out)
    # Another method, which has no checkpoint: it would start over and rewrite
    # metrics.csv with its own rows only.
    with pytest.raises(CheckpointError, match=r"metrics\.csv: holds the rows of method as_ccv"):
        run_folder(passes, out, RunSpec(("as",), PARAMS), existing="resume")
    assert _files(out) == before
    assert not (out / "as").exists()

    # The same methods, one of which lost its folder (and checkpoint): its rows are
    # refused too, the others' resume as before.
    both = RunSpec(("as_ccv", "as"), PARAMS)
    out = tmp_path / "both"
    run_folder(passes, out, both)
    run_folder(passes, out, both, existing="resume")  # nothing to do: accepted
    shutil.rmtree(out / "as")
    before = _files(out)
    with pytest.raises(CheckpointError, match="rows of method as, which this run"):
        run_folder(passes, out, both, existing="resume")
    assert _files(out) == before


@pytest.fixture(scope="module")
def _early(tmp_path_factory):
    """Pass files of frames 1-3 and, apart, of frames 4-6."""
    root = tmp_path_factory.mktemp("early")
    return _passes(root / "passes", _frames(1, 3)), _passes(root / "later", _frames(4, 3))


def _copy_early(early, tmp_path):
    """An as_ccv run over frames 1-3, then frames 4-6 added to its passes."""
    passes, later = early
    # copy2 keeps the modification times (the copies are the same pass files).
    shutil.copytree(passes, tmp_path / "passes", copy_function=shutil.copy2)
    run_folder(tmp_path / "passes", tmp_path / "out", RunSpec(("as_ccv",), PARAMS))
    for path in later.iterdir():
        shutil.copy2(path, tmp_path / "passes" / path.name)
    return tmp_path / "passes", tmp_path / "out"


def test_resume_refuses_pass_files_changed_since_their_frame_was_done(_early, tmp_path):
    spec = RunSpec(("as_ccv",), PARAMS)
    whole = tmp_path / "whole"
    run_folder(_copy_early(_early, tmp_path / "w")[0], whole, spec)

    # Frames added after the last one done are taken: the whole run's results.
    passes, out = _copy_early(_early, tmp_path / "added")
    run_folder(passes, out, spec, existing="resume")
    _same_files(whole, out)

    # Frame 2 rendered again (another scene): its result and the history carried
    # from it are stale, so the resume is refused, naming the file; nothing changes.
    passes, out = _copy_early(_early, tmp_path / "changed")
    write_passes(passes / "0002.exr", scene_frame("regular", 2, 32, 24), overwrite=True)
    before = _files(out)
    with pytest.raises(CheckpointError, match=r"pass file \S*0002\.exr changed .*--overwrite"):
        run_folder(passes, out, spec, existing="resume")
    assert _files(out) == before
    # "continue" starts that method over instead: frame 2 from the new passes.
    run_folder(passes, out, spec, existing="continue")
    fresh = tmp_path / "fresh"
    run_folder(passes, fresh, spec)
    _same_files(fresh, out)

    # A sidecar counts too: stat only, so a touch is a change.
    passes, out = _copy_early(_early, tmp_path / "touched")
    sidecar = passes / "0003.json"
    st = sidecar.stat()
    os.utime(sidecar, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    with pytest.raises(CheckpointError, match=r"pass file \S*0003\.json changed"):
        run_folder(passes, out, spec, existing="resume")


def test_a_checkpoint_without_the_pass_files_still_resumes(_early, tmp_path):
    # Checkpoints written before the pass files were recorded cannot be checked
    # against them, but they still resume.
    spec = RunSpec(("as_ccv",), PARAMS)
    whole = tmp_path / "whole"
    run_folder(_copy_early(_early, tmp_path / "w")[0], whole, spec)
    passes, out = _copy_early(_early, tmp_path / "old")
    _edit_checkpoint(_checkpoint_of(out), lambda state, arrays: state.pop("inputs"))
    run_folder(passes, out, spec, existing="resume")
    _same_files(whole, out)


def _set(mapping, key, value):
    mapping[key] = value


DAMAGE = {
    # The numba passes index the history with the frame's pixel indices: a buffer
    # of another shape crashed the process (segfault) before it was checked.
    "history buffer of another shape": (
        lambda s, a: _set(a, "h_buf_mu", np.zeros((5, 5), np.float32)),
        "h_buf_mu must be 24x32 float32",
    ),
    "history buffer missing": (lambda s, a: a.pop("h_buf_mu"), "no array h_buf_mu"),
    "history depth of another dtype": (
        lambda s, a: _set(a, "h_depth", a["h_depth"].astype(np.float64)),
        "h_depth must be 24x32 float32",
    ),
    "last luminance of another shape": (
        lambda s, a: _set(a, "run_last_y", np.zeros((3, 3), np.float32)),
        "run_last_y must be a 24x32 float32 image",
    ),
    "frames_done not numbers": (
        lambda s, a: _set(s, "frames_done", [1, "x", 3]),
        "frames_done is not a list of frame numbers",
    ),
    "frames_done null": (lambda s, a: _set(s, "frames_done", None), "frames_done is not a list"),
    "rows null": (lambda s, a: _set(s, "rows", None), "rows is not a list"),
    "row of another method": (
        lambda s, a: s["rows"][0].update(method="reference"),
        "metric row",
    ),
    "signature not a mapping": (lambda s, a: _set(s, "signature", [1]), "run signature"),
}


@pytest.mark.parametrize("damage", DAMAGE)
def test_a_damaged_checkpoint_is_refused_with_one_clear_error(_early, tmp_path, damage):
    edit, what = DAMAGE[damage]
    passes, out = _copy_early(_early, tmp_path)
    path = _checkpoint_of(out)
    _edit_checkpoint(path, edit)
    before = _files(out)
    spec = RunSpec(("as_ccv",), PARAMS)
    with pytest.raises(CheckpointError) as caught:
        run_folder(passes, out, spec, existing="resume")
    message = str(caught.value)
    assert message.startswith(f"{path}: damaged checkpoint (")
    assert what in message and message.endswith("pass --overwrite to start over")
    assert _files(out) == before
    # "continue" starts over from a damaged checkpoint, as from an unreadable one.
    run_folder(passes, out, spec, existing="continue")
    assert checkpoint.load(path)[0]["frames_done"] == list(range(1, 7))


def test_a_checkpoint_of_other_sized_frames_is_refused_before_it_is_used(_early, tmp_path):
    # Every array cropped alike: consistent, but not the frames' size.
    passes, out = _copy_early(_early, tmp_path)
    path = _checkpoint_of(out)

    def crop(state, arrays):
        for key, value in arrays.items():
            if value.ndim == 2:
                arrays[key] = np.ascontiguousarray(value[:12, :16])

    _edit_checkpoint(path, crop)
    with pytest.raises(CheckpointError, match=r"16x12 frames but frame 4 is 32x24.*--overwrite"):
        run_folder(passes, out, RunSpec(("as_ccv",), PARAMS), existing="resume")

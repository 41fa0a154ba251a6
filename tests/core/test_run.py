"""core.run: warm-up frames and the open-ended FrameStream of Blender's own render."""

import numpy as np
import pytest

from cvsss.core.params import SSSParams
from cvsss.core.run import FrameStream, RunSpec, SequenceRun
from cvsss.core.synthetic import sequence

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

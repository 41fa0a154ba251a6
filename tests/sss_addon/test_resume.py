"""Nothing lost: atomic outputs, per-frame checkpoints and `cvsss post --resume`.

A sequence killed at frame k (SIGKILL of the real command, or a crash in the
middle of writing an EXR) and rerun with ``--resume`` continues after each
method's checkpoint (``<out>/<method>/.checkpoint.npz``) and ends bit-identical
to an uninterrupted run: every EXR layer and header entry and every metrics
row, except the wall-clock timings (``sampling_ms``, ``update_ms``, ``total_ms``).
Existing outputs are never replaced without ``--overwrite``.
"""

from __future__ import annotations

import csv
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from cli_helpers import run_cli

from cvsss.core.io import atomic, checkpoint
from cvsss.core.io.exr import read_result, write_passes
from cvsss.core.mc.history import History
from cvsss.core.run import CHECKPOINT_NAME
from cvsss.core.synthetic import sequence
from cvsss.sss_addon.cli import main as cli

TIMINGS = ("cvsss.sampling_ms", "cvsss.update_ms", "cvsss.total_ms")
FRAMES = 24
ARGS = ("--method", "as_ocv,as_ccv", "--reference", "--reference-spp", "64", "--quiet")


@pytest.fixture(scope="module")
def passes(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("passes")
    for frame in sequence("flash", FRAMES, 64, 36):
        write_passes(folder / f"{frame.number:04d}.exr", frame)
    return folder


@pytest.fixture(scope="module")
def full(passes, tmp_path_factory) -> Path:
    """An uninterrupted run (the expected result)."""
    out = tmp_path_factory.mktemp("full") / "out"
    assert cli.main(["post", str(passes), "--out", str(out), *ARGS]) == 0
    return out


def post_argv(passes: Path, out: Path, *extra: str, args=ARGS) -> list[str]:
    return ["post", str(passes), "--out", str(out), *args, *extra]


def metric_rows(out: Path) -> list[dict]:
    with open(out / "metrics.csv", newline="") as fh:
        return [
            {k: v for k, v in row.items() if k not in ("sampling_ms", "frame_ms")}
            for row in csv.DictReader(fh)
        ]


def assert_same_run(a: Path, b: Path) -> None:
    """Every result layer and header entry equal (timings aside), same metric rows."""
    names = sorted(p.relative_to(a) for p in a.rglob("*.exr"))
    assert names and names == sorted(p.relative_to(b) for p in b.rglob("*.exr"))
    for name in names:
        ra, rb = read_result(a / name), read_result(b / name)
        assert ra.keys() == rb.keys()
        for layer in ra:
            if layer == "header":
                ha = {k: v for k, v in ra[layer].items() if k not in TIMINGS}
                hb = {k: v for k, v in rb[layer].items() if k not in TIMINGS}
                assert ha == hb, name
            else:
                assert ra[layer].dtype == rb[layer].dtype
                assert np.array_equal(ra[layer], rb[layer]), (name, layer)
    assert metric_rows(a) == metric_rows(b)


def temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".tmp-" in p.name]


def stamps(folder: Path) -> dict[Path, tuple[int, int]]:
    return {p: (p.stat().st_ino, p.stat().st_mtime_ns) for p in folder.rglob("*") if p.is_file()}


def test_killed_run_resumes_bit_identical(passes, full, tmp_path):
    out = tmp_path / "out"
    k = 6
    proc = subprocess.Popen(
        [sys.executable, "-m", "cvsss.sss_addon.cli.main", *post_argv(passes, out)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
    )
    deadline = time.monotonic() + 60
    while not (out / "as_ccv" / f"{k:04d}.exr").exists():
        assert proc.poll() is None, proc.stderr.read().decode()
        assert time.monotonic() < deadline, "no progress within 60 s"
        time.sleep(0.002)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    proc.stderr.close()
    assert proc.returncode == -signal.SIGKILL
    last = out / "as_ccv" / f"{FRAMES:04d}.exr"
    assert not last.exists(), "the run finished before it could be killed"

    # Whatever was under a final name is complete.
    for path in out.rglob("*.exr"):
        read_result(path)
    # The kill may land between an EXR and its checkpoint: then that frame is redone.
    done = {
        m: checkpoint.load(out / m / CHECKPOINT_NAME)[0]["frames_done"]
        for m in ("reference", "as_ocv", "as_ccv")
    }
    assert all(d == list(range(1, len(d) + 1)) for d in done.values())
    assert k - 1 <= len(done["as_ccv"]) < FRAMES
    safe = min(len(d) for d in done.values())
    kept = {p: s for p, s in stamps(out).items() if p.suffix == ".exr" and int(p.stem) <= safe}

    resumed = run_cli(*post_argv(passes, out, "--resume", args=ARGS[:-1]))
    assert resumed.returncode == 0, resumed.stderr
    assert f"as_ccv: resuming after frame {len(done['as_ccv'])}" in resumed.stdout
    assert_same_run(full, out)
    assert temporaries(out) == []
    # Frames finished before the kill were not written again.
    after = stamps(out)
    assert all(after[p] == s for p, s in kept.items())


class Crash(BaseException):
    """Stands for the process dying (power cut, Ctrl-C) in the middle of a write."""


def crash_during_write(monkeypatch, after_files: int, after_bytes: int = 4096) -> None:
    """The ``after_files``-th EXR staged for writing dies after ``after_bytes`` bytes."""
    real_init = atomic._Staged.__init__
    opened = [0]

    def staged_init(self, path):
        real_init(self, path)
        if path.suffix != ".exr":
            return
        opened[0] += 1
        if opened[0] != after_files:
            return
        fh = self.stream
        budget = [after_bytes]

        class Dying:
            def write(self, data):
                if len(data) > budget[0]:
                    fh.write(bytes(data)[: budget[0]])
                    fh.flush()
                    raise Crash
                budget[0] -= len(data)
                return fh.write(data)

            def __getattr__(self, name):
                return getattr(fh, name)

        self.stream = Dying()

    monkeypatch.setattr(atomic._Staged, "__init__", staged_init)


def test_crash_mid_write_leaves_no_partial_exr_float16(passes, tmp_path, monkeypatch):
    args = ("--method", "as_ocv,as", "--history-precision", "float16", "--quiet")
    full = tmp_path / "full"
    assert cli.main(post_argv(passes, full, args=args)) == 0

    out = tmp_path / "out"
    crash_during_write(monkeypatch, after_files=11)  # 6th frame of "as_ocv"
    with pytest.raises(Crash):
        cli.main(post_argv(passes, out, args=args))
    monkeypatch.undo()
    assert not (out / "as_ocv" / "0006.exr").exists()
    assert (out / "as" / "0005.exr").exists() and not (out / "as" / "0006.exr").exists()
    assert temporaries(out) == []  # the atomic writer removed its temporary file
    for path in out.rglob("*.exr"):
        read_result(path)
    assert cli.main(post_argv(passes, out, "--resume", args=args)) == 0
    assert_same_run(full, out)


def test_overwrite_that_stops_midway_leaves_no_frame_of_the_old_run(passes, full, tmp_path, capsys):
    """``--overwrite`` starts over: when the new run then stops at a damaged frame, the old
    run's later frames are gone, not left beside the new ones as if they were its."""
    out = tmp_path / "out"
    shutil.copytree(full, out)
    damaged = tmp_path / "passes"
    shutil.copytree(passes, damaged)
    (damaged / "0005.exr").write_bytes((damaged / "0005.exr").read_bytes()[:100])
    assert cli.main(post_argv(damaged, out, "--overwrite")) == 2
    assert "0005.exr" in capsys.readouterr().err
    for method in ("as_ocv", "as_ccv", "reference"):
        left = sorted(p.name for p in (out / method).glob("*.exr"))
        assert left == ["0001.exr", "0002.exr", "0003.exr", "0004.exr"], (method, left)


def test_interrupt_exits_130_and_points_to_resume(passes, tmp_path, monkeypatch, capsys):
    def interrupt(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr("cvsss.core.run.driver.write_result", interrupt)
    assert cli.main(post_argv(passes, tmp_path / "out")) == 130
    assert "--resume" in capsys.readouterr().err


def test_interrupt_inside_a_compiled_kernel_is_an_interrupt(passes, tmp_path, monkeypatch, capsys):
    """Ctrl-C while numba runs surfaces as a SystemError raised while the KeyboardInterrupt
    was handled (seen in a real process): the same exit 130, no traceback. Any other
    SystemError stays an error."""

    def interrupt(*_args, **_kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise SystemError("CPUDispatcher returned a result with an exception set") from None

    monkeypatch.setattr("cvsss.core.run.driver.write_result", interrupt)
    assert cli.main(post_argv(passes, tmp_path / "out")) == 130
    assert "--resume" in capsys.readouterr().err

    def broken(*_args, **_kwargs):
        raise SystemError("not an interrupt")

    monkeypatch.setattr("cvsss.core.run.driver.write_result", broken)
    with pytest.raises(SystemError, match="not an interrupt"):
        cli.main(post_argv(passes, tmp_path / "out2"))


def test_existing_outputs_are_never_overwritten_without_flag(passes, full, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(full, out)
    before = stamps(out)
    contents = {p: p.read_bytes() for p in before}
    assert cli.main(post_argv(passes, out)) == 2
    err = capsys.readouterr().err
    assert "already exists" in err and "--resume" in err and "--overwrite" in err
    assert stamps(out) == before
    assert all(p.read_bytes() == c for p, c in contents.items())
    # --resume on a finished run has nothing to do and touches no result.
    assert cli.main(post_argv(passes, out, "--resume", args=ARGS[:-1])) == 0
    assert "nothing to do" in capsys.readouterr().out
    assert {p: s for p, s in stamps(out).items() if p.suffix == ".exr"} == {
        p: s for p, s in before.items() if p.suffix == ".exr"
    }
    # --overwrite replaces.
    assert cli.main(post_argv(passes, out, "--overwrite")) == 0
    assert stamps(out)[out / "as_ocv" / "0001.exr"] != before[out / "as_ocv" / "0001.exr"]
    assert_same_run(full, out)


def test_metrics_of_another_run_are_not_replaced(passes, tmp_path, capsys):
    out = tmp_path / "out"
    quick = ("--method", "fixed", "--fixed-spp", "2", "--quiet")
    assert cli.main(post_argv(passes, out, args=quick)) == 0
    metrics = (out / "metrics.csv").read_bytes()
    assert cli.main(post_argv(passes, out, args=("--method", "none", "--quiet"))) == 2
    err = capsys.readouterr().err
    assert "metrics.csv already exists" in err
    assert (out / "metrics.csv").read_bytes() == metrics
    assert not (out / "none").exists()


def test_resume_refuses_a_different_run(passes, full, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(full, out)
    assert cli.main(post_argv(passes, out, "--resume", "--seed", "3")) == 2
    err = capsys.readouterr().err
    assert CHECKPOINT_NAME in err and "seed 0 -> 3" in err and "--overwrite" in err

    (out / "as_ocv" / CHECKPOINT_NAME).write_bytes(b"garbage")
    assert cli.main(post_argv(passes, out, "--resume")) == 2
    assert "unreadable checkpoint" in capsys.readouterr().err

    (out / "as_ocv" / CHECKPOINT_NAME).unlink()
    assert cli.main(post_argv(passes, out, "--resume")) == 2
    err = capsys.readouterr().err
    assert "no checkpoint" in err and str(out / "as_ocv") in err


def test_resume_picks_up_frames_added_later(passes, full, tmp_path):
    # A render farm delivers passes in batches: resume processes the new ones.
    partial = tmp_path / "passes"
    partial.mkdir()
    for n in range(1, 9):
        for ext in (".exr", ".json"):
            shutil.copy(passes / f"{n:04d}{ext}", partial / f"{n:04d}{ext}")
    out = tmp_path / "out"
    assert cli.main(post_argv(partial, out)) == 0
    for n in range(9, FRAMES + 1):
        for ext in (".exr", ".json"):
            shutil.copy(passes / f"{n:04d}{ext}", partial / f"{n:04d}{ext}")
    # The checkpoint names the pass folder, so resume from the same one.
    assert cli.main(post_argv(partial, out, "--resume")) == 0
    assert_same_run(full, out)


def test_checkpoint_holds_history_and_rows(full):
    state, arrays = checkpoint.load(full / "as_ocv" / CHECKPOINT_NAME)
    history = History.from_arrays(arrays, "h_")
    assert state["frames_done"] == list(range(1, FRAMES + 1))
    assert [r["frame"] for r in state["rows"]] == list(range(1, FRAMES + 1))
    assert isinstance(history, History) and history.frame == FRAMES
    ref_state, ref_arrays = checkpoint.load(full / "reference" / CHECKPOINT_NAME)
    assert not [k for k in ref_arrays if k.startswith("h_")] and len(ref_state["rows"]) == FRAMES

"""Bad input gets one clear message, exit status 2 and no traceback (`cvsss post`, `cvsss render`).

Each case checks that the message names the file or the argument and the
problem. Most run ``cli.main`` in-process (an uncaught exception would fail
the test, so exit status 2 also means "no traceback"); a few run the real
command in a subprocess to check stderr is exactly one line.

Decision on non-finite input: NaN/inf (and negative colour) pass values are
*repaired*, not refused: the frame is processed with them replaced (colours
-> 0, depth -> background, material -> 0, motion -> 0), one ``warning:`` line
per frame counts them, and the result header records the count.
"""

from __future__ import annotations

import builtins
import errno
import json
import os
import shutil
from pathlib import Path

import numpy as np
import OpenEXR
import pytest
from cli_helpers import run_cli

from cvsss.core.io.exr import read_result, write_passes
from cvsss.core.synthetic import scene_frame
from cvsss.sss_addon.cli import main as cli

W, H = 32, 18


def write_sequence(folder: Path, numbers, width: int = W, height: int = H) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for n in numbers:
        write_passes(folder / f"{n:04d}.exr", scene_frame("flash", n, width, height))
    return folder


def rewrite_exr(path: Path, *, drop: str | None = None, edit=None) -> None:
    """Rewrite a pass EXR without the part named ``…<drop>`` or with channels edited."""
    exr = OpenEXR.File(str(path), separate_channels=True)
    parts = []
    for part in exr.parts:
        if drop is not None and part.name().endswith("." + drop):
            continue
        channels = {k: np.array(c.pixels) for k, c in part.channels.items()}
        if edit is not None:
            edit(part.name(), channels)
        parts.append(OpenEXR.Part(part.header, channels, part.name()))
    OpenEXR.File(parts).write(str(path))


def post(passes: Path, out: Path, *extra: str) -> list[str]:
    return ["post", str(passes), "--out", str(out), "--method", "as_ocv", "--quiet", *extra]


def run_main(argv, capfd) -> tuple[int, str]:
    code = cli.main(argv)
    return code, capfd.readouterr().err


def assert_one_error(code: int, err: str, *fragments: str) -> None:
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])


@pytest.fixture(scope="module")
def good(tmp_path_factory) -> Path:
    return write_sequence(tmp_path_factory.mktemp("good"), range(1, 4))


@pytest.fixture
def passes(tmp_path, good) -> Path:
    """A private copy of a 3-frame sequence that a test may damage."""
    return Path(shutil.copytree(good, tmp_path / "passes"))


# -- input files ------------------------------------------------------------------------
def test_not_an_exr(passes, tmp_path, capfd):
    (passes / "0002.exr").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0002.exr", "not a readable OpenEXR file")
    # Frame 1 was finished and is kept, with a checkpoint to resume from.
    assert read_result(tmp_path / "out" / "as_ocv" / "0001.exr")["SampleCount"].shape == (H, W)
    assert not (tmp_path / "out" / "as_ocv" / "0002.exr").exists()


@pytest.mark.parametrize("keep", [0.5, 0.05])
def test_truncated_exr(passes, tmp_path, capfd, keep):
    path = passes / "0003.exr"
    data = path.read_bytes()
    path.write_bytes(data[: int(len(data) * keep)])
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0003.exr", "truncated or corrupt")


@pytest.mark.parametrize("missing", ["Diffuse Direct", "Depth"])
def test_missing_lighting_or_depth_pass(passes, tmp_path, capfd, missing):
    rewrite_exr(passes / "0002.exr", drop=missing)
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0002.exr", f"missing pass '{missing}'")


def test_missing_sidecar_is_found_before_any_work(passes, tmp_path, capfd):
    (passes / "0003.json").unlink()
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0003.json", "missing camera sidecar")
    assert not (tmp_path / "out" / "as_ocv" / "0001.exr").exists()


def test_frames_of_mismatched_size(passes, tmp_path, capfd):
    write_passes(passes / "0002.exr", scene_frame("flash", 2, 48, 27), overwrite=True)
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0002.exr", "48x27", f"{W}x{H}", "0001.exr", "same size")
    assert not (tmp_path / "out" / "as_ocv" / "0001.exr").exists()  # refused up front


def test_sidecar_that_lies_about_the_size(passes, tmp_path, capfd):
    # The sidecar says 32x18 but the EXR is 48x27: caught when the frame is read.
    frame = scene_frame("flash", 2, 48, 27)
    big = tmp_path / "big"
    write_passes(big / "0002.exr", frame)
    shutil.copy(big / "0002.exr", passes / "0002.exr")
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0002", "does not match")


@pytest.mark.parametrize("slot", [float("inf"), 1e300, 10**30, 1.5, 40000, 0])
def test_sidecar_material_slot_out_of_range(passes, tmp_path, capfd, slot):
    """A slot is a Material Index (Blender's Pass Index: 1…32767); anything else, however
    large, is one message naming the sidecar, before any frame is written."""
    path = passes / "0002.json"
    data = json.loads(path.read_text())
    data["materials"][0]["slot"] = slot
    path.write_text(json.dumps(data))  # inf as JSON's Infinity, which Python reads back
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "0002.json", "material slot must be an integer in [1, 32767]")
    assert not (tmp_path / "out" / "as_ocv" / "0001.exr").exists()


def test_sidecar_material_that_no_profile_takes_names_its_file(passes, tmp_path, capfd):
    path = passes / "0002.json"
    data = json.loads(path.read_text())
    data["materials"][0]["profile"] = "dipole"  # without a preset: no parameters
    path.write_text(json.dumps(data))
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "the dipole profile needs", f"(the materials of {path})")


def test_gap_in_the_sequence_is_refused_unless_allowed(tmp_path, capfd):
    passes = write_sequence(tmp_path / "passes", [1, 2, 4, 7, 8])
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, str(passes), "frames 3, 5-6 missing", "--allow-gaps")
    assert not (tmp_path / "out").exists()
    code, err = run_main(post(passes, tmp_path / "out", "--allow-gaps"), capfd)
    assert code == 0
    assert "warning:" in err and "3, 5-6" in err
    assert (tmp_path / "out" / "as_ocv" / "0008.exr").exists()


def test_nan_passes_are_repaired_with_a_warning(passes, tmp_path, capfd):
    def poison(part, channels):
        for key in channels:
            if part.endswith("Diffuse Direct"):
                channels[key][:5, :] = np.nan
            if part.endswith("Depth"):
                channels[key][0, :3] = np.nan

    rewrite_exr(passes / "0002.exr", edit=poison)
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert code == 0, err
    expected = 5 * W * 3 + 3  # NaN lighting values + NaN depths
    lines = [line for line in err.splitlines() if line.startswith("warning:")]
    assert len(lines) == 1 and "0002.exr" in lines[0] and f"repaired {expected} " in lines[0]
    res = read_result(tmp_path / "out" / "as_ocv" / "0002.exr")
    assert res["header"]["cvsss.repaired"] == str(expected)
    for layer in ("Composite", "SSS", "Alpha", "Variance"):
        assert np.all(np.isfinite(res[layer]))


def test_extreme_finite_values_give_no_numpy_warning(passes, tmp_path, capfd):
    """Lighting near float32's top (Direct + Indirect overflows) and a denormal depth:
    repaired or handled with the documented warning line only."""

    def edit(name, channels):
        if name.endswith(("Diffuse Direct", "Diffuse Indirect")):
            for c in channels.values():
                c[2:6, 2:6] = 3e38
        if name.endswith("Depth"):
            for c in channels.values():
                c[8:12, 8:12] = 1e-40

    rewrite_exr(passes / "0002.exr", edit=edit)
    code, err = run_main(post(passes, tmp_path / "out", "--method", "separable,as_ccv"), capfd)
    assert code == 0, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: "), err
    assert "0002.exr: repaired 48 non-finite" in lines[0]


def test_empty_or_missing_pass_folder(tmp_path, capfd):
    code, err = run_main(post(tmp_path / "nope", tmp_path / "out"), capfd)
    assert_one_error(code, err, "nope", "no such folder")
    (tmp_path / "empty").mkdir()
    code, err = run_main(post(tmp_path / "empty", tmp_path / "out"), capfd)
    assert_one_error(code, err, "empty", "no frame files")


# -- parameters --------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("flag", "value", "fragment"),
    [
        ("--eta", "0", "eta must be in (0, 1]"),
        ("--eta", "-0.5", "eta must be in (0, 1]"),
        ("--eta", "nan", "eta must be finite"),
        ("--target-variance", "0", "target_variance must be in (0, inf)"),
        ("--target-variance", "-1", "target_variance must be in (0, inf)"),
        ("--eps-u", "-0.1", "eps_u must be in [0, 1]"),
        ("--eps-alpha", "-1", "eps_alpha must be in [0, inf)"),
        ("--kappa", "-0.2", "kappa must be in [0, 1]"),
        ("--beta-min", "0", "beta_min must be in [1, 4096]"),
        ("--beta-max", "0", "beta_max must be in [1, 4096]"),
        ("--eta-cv", "0", "eta_cv must be in (0, 1]"),
        ("--eta-cv", "1.0000001", "eta_cv must be in (0, 1], got 1.0000001"),
        ("--fixed-spp", "0", "fixed_spp must be in [1, 4096]"),
        ("--reference-spp", "-4", "reference_spp must be in [1, 4096]"),
        ("--seed", "-1", "seed must be in [0, 4294967295]"),
        ("--exposure", "0", "exposure must be in (0, inf)"),
        ("--exposure", "-2", "exposure must be in (0, inf)"),
        ("--depth-slope", "-1", "depth_slope must be in [0, inf)"),
        ("--history-precision", "float8", "history_precision must be one of"),
    ],
)
def test_invalid_parameter_names_the_flag(good, tmp_path, capfd, flag, value, fragment):
    code, err = run_main(post(good, tmp_path / "out", flag, value), capfd)
    assert_one_error(code, err, f"{flag}: ", fragment)
    assert not (tmp_path / "out").exists()


def test_flag_that_is_not_a_number(good, tmp_path, capfd):
    with pytest.raises(SystemExit) as exc:
        cli.main(post(good, tmp_path / "out", "--eta", "fast"))
    assert exc.value.code == 2
    err = capfd.readouterr().err
    assert "argument --eta: invalid float value: 'fast'" in err and "Traceback" not in err
    # One line, as every other error (the usage is a --help away).
    assert err.strip().splitlines() == [
        "error: cvsss post: argument --eta: invalid float value: 'fast' (see cvsss post --help)"
    ]


def test_resume_and_overwrite_exclude_each_other(good, tmp_path, capfd):
    with pytest.raises(SystemExit) as exc:
        cli.main(post(good, tmp_path / "out", "--resume", "--overwrite"))
    assert exc.value.code == 2
    assert "not allowed with argument" in capfd.readouterr().err


def test_one_line_without_traceback_in_a_real_process(passes, tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "0001.exr").write_text("not an exr")
    # OpenEXR's C library prints a line per damaged chunk of a truncated file;
    # the command holds them back so the error stays one line.
    data = (passes / "0002.exr").read_bytes()
    (passes / "0002.exr").write_bytes(data[: len(data) // 2])
    for args in ([str(bad)], [str(bad), "--eta-cv", "0"], [str(passes)]):
        proc = run_cli("post", *args, "--out", str(tmp_path / "o"))
        assert proc.returncode == 2
        assert "Traceback" not in proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1, proc.stderr


# -- outputs --------------------------------------------------------------------------------
def test_output_folder_under_a_file(good, tmp_path, capfd):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code, err = run_main(post(good, blocker / "out"), capfd)
    assert_one_error(code, err, str(blocker), "not a folder")


def _deny(root: Path, original):
    def guarded(path, *args, **kwargs):
        if Path(os.fspath(path)).resolve().is_relative_to(root.resolve()):
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(path))
        return original(path, *args, **kwargs)

    return guarded


def test_unwritable_output_folder(good, tmp_path, capfd, monkeypatch):
    # Simulated (tests may run as root, where chmod does not stop writes):
    # the folder exists but creating anything inside it is refused.
    out = tmp_path / "locked"
    out.mkdir()
    monkeypatch.setattr(os, "mkdir", _deny(out, os.mkdir))
    monkeypatch.setattr(os, "open", _deny(out, os.open))
    real_open = builtins.open

    def guarded_open(file, mode="r", *args, **kwargs):
        if any(c in mode for c in "wax+"):
            return _deny(out, real_open)(file, mode, *args, **kwargs)
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded_open)
    code, err = run_main(post(good, out), capfd)
    monkeypatch.undo()
    assert_one_error(code, err, str(out), "Permission denied")
    assert list(out.iterdir()) == []


def test_pass_folder_listed_but_not_entered(passes, tmp_path, capfd, monkeypatch):
    # A folder with read but no execute permission (simulated: tests may run as root):
    # its names list, but looking at an entry is refused.
    real = Path.is_file

    def refused(self):
        if self.parent == passes:
            raise PermissionError(errno.EACCES, os.strerror(errno.EACCES), os.fspath(self))
        return real(self)

    monkeypatch.setattr(Path, "is_file", refused)
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    monkeypatch.undo()
    assert_one_error(code, err, str(passes), "cannot open 0001.exr", "Permission denied")


class DiskFull:
    """Byte budget shared by every file opened for writing (a simulated full disk)."""

    def __init__(self, budget: float) -> None:
        self.left = budget
        self.written = 0

    def wrap(self, fh):
        disk = self

        class Limited:
            def write(self, data):
                n = len(data)
                if n > disk.left:
                    fh.write(bytes(data)[: int(disk.left)])  # what fits, like a real disk
                    disk.left = 0
                    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
                disk.left -= n
                disk.written += n
                return fh.write(data)

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                fh.close()

            def __getattr__(self, name):
                return getattr(fh, name)

        return Limited()

    def install(self, monkeypatch) -> None:
        real_open, real_fdopen = builtins.open, os.fdopen

        def fake_open(file, mode="r", *args, **kwargs):
            fh = real_open(file, mode, *args, **kwargs)
            return self.wrap(fh) if "b" in mode and any(c in mode for c in "wax") else fh

        def fake_fdopen(fd, mode="r", *args, **kwargs):
            fh = real_fdopen(fd, mode, *args, **kwargs)
            return self.wrap(fh) if "w" in mode else fh

        monkeypatch.setattr(builtins, "open", fake_open)
        monkeypatch.setattr(os, "fdopen", fake_fdopen)


def _temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if ".tmp-" in p.name]


def _same_results(a: Path, b: Path) -> None:
    names = sorted(p.relative_to(a) for p in a.rglob("*.exr"))
    assert names == sorted(p.relative_to(b) for p in b.rglob("*.exr"))
    for name in names:
        ra, rb = read_result(a / name), read_result(b / name)
        for layer in ra:
            if layer != "header":
                assert np.array_equal(ra[layer], rb[layer]), (name, layer)


# A file half written when the disk fills must be closed then: closed later, by the garbage
# collector, it prints "Exception ignored in ..." to stderr (seen from a checkpoint's zip).
@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
def test_full_disk_at_the_start(good, tmp_path, capfd, monkeypatch):
    DiskFull(0).install(monkeypatch)
    code, err = run_main(post(good, tmp_path / "out"), capfd)
    monkeypatch.undo()
    assert_one_error(code, err, str(tmp_path / "out"), "No space left on device")
    assert _temporaries(tmp_path / "out") == []


@pytest.mark.filterwarnings("error::pytest.PytestUnraisableExceptionWarning")
def test_full_disk_mid_run_then_resume(good, tmp_path, capfd, monkeypatch):
    args = ("--method", "as_ocv,fixed", "--fixed-spp", "4")
    full = tmp_path / "full"
    counter = DiskFull(float("inf"))
    counter.install(monkeypatch)
    assert cli.main(post(good, full, *args)) == 0
    monkeypatch.undo()
    total = counter.written

    out = tmp_path / "out"
    DiskFull(total * 0.6).install(monkeypatch)
    code, err = run_main(post(good, out, *args), capfd)
    monkeypatch.undo()
    assert_one_error(code, err, str(out), "cannot write", "No space left on device")
    # No partial file under a final name, no temporary left behind.
    assert _temporaries(out) == []
    written = list(out.rglob("*.exr"))
    assert 0 < len(written) < 6
    for path in written:
        read_result(path)
    # Space freed: --resume finishes the run exactly as if nothing happened.
    code, err = run_main(post(good, out, *args, "--resume"), capfd)
    assert code == 0, err
    _same_results(full, out)


# -- cvsss render ------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("args", "fragments"),
    [
        (["--eta", "0"], ["--eta: ", "eta must be in (0, 1]"]),
        (["--beta-min", "9", "--beta-max", "8"], ["beta_min must be <= beta_max"]),
        (["--frames", "5-2"], ["--frames must be A-B", "'5-2'"]),
        (["--frames", "2147483648"], ["B <= 1048574 (Blender's last frame)", "'2147483648'"]),
        (["{missing}"], ["missing.blend", "no such .blend file"]),
        (["--ground-truth", "--ground-truth-spp", "0"], ["--ground-truth-spp must be in [1, "]),
        (["--ground-truth-every", "0"], ["--ground-truth-every must be >= 1, got 0"]),
        (["--denoise-passes", "--engine", "EEVEE"], ["--denoise-passes needs Cycles passes"]),
    ],
)
def test_render_bad_input(tmp_path, capfd, args, fragments):
    args = [a.replace("{missing}", str(tmp_path / "missing.blend")) for a in args]
    code, err = run_main(["render", *args, "--out", str(tmp_path / "out")], capfd)
    assert_one_error(code, err, *fragments)


@pytest.mark.parametrize("res", ["99999999x99999999", "65537x10", "0x10"])
def test_demo_resolution_out_of_range(tmp_path, capfd, res):
    argv = ["demo", "--source", "synthetic", "--out", str(tmp_path / "o"), "--res", res]
    code, err = run_main(argv, capfd)
    assert_one_error(code, err, "--res must be WIDTHxHEIGHT in pixels, 1 to 65536 each", res)
    assert not (tmp_path / "o").exists()  # refused before anything is made


def test_out_of_memory_is_one_message(passes, tmp_path, capfd, monkeypatch):
    def exhausted(*_args, **_kwargs):
        raise MemoryError("Unable to allocate 142. PiB")

    monkeypatch.setattr("cvsss.core.run.driver.write_result", exhausted)
    code, err = run_main(post(passes, tmp_path / "out"), capfd)
    assert_one_error(code, err, "not enough memory (Unable to allocate 142. PiB)")


@pytest.mark.bpy
def test_render_not_a_blend_file(tmp_path):
    fake = tmp_path / "scene.blend"
    fake.write_text("not a blend file")
    proc = run_cli("render", str(fake), "--out", str(tmp_path / "out"), "--frames", "1")
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "scene.blend" in proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "not a readable .blend file" in lines[0], proc.stderr

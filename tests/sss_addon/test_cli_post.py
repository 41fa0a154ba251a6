"""`cvsss post` on a directory of real EXR files written by core.exr (no bpy)."""

import csv
import subprocess
import sys

import numpy as np
import pytest

from cvsss.core.exr import read_result, write_passes
from cvsss.core.synthetic import sequence
from cvsss.sss_addon import cli


@pytest.fixture(scope="module")
def passes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("passes")
    for frame in sequence("flash", 4, 48, 27):
        write_passes(folder / f"{frame.number:04d}.exr", frame)
    return folder


def test_post_writes_results_and_metrics(passes, tmp_path):
    out = tmp_path / "out"
    code = cli.main(["post", str(passes), "--out", str(out), "--method", "as_ccv,fixed",
                     "--reference", "--reference-spp", "128", "--fixed-spp", "16", "--quiet"])
    assert code == 0
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert [r["method"] for r in rows[:3]] == ["reference", "as_ccv", "fixed"]
    assert len(rows) == 12
    for r in rows:
        assert float(r["spp"]) >= 0 and float(r["pass_ms"]) >= 0
        if r["method"] == "reference":
            assert float(r["psnr_db"]) == 100.0
        else:
            assert 20.0 < float(r["psnr_db"]) < 100.0
    res = read_result(out / "as_ccv" / "0004.exr")
    assert res["SampleCount"].shape == (27, 48)
    counts = res["SampleCount"][res["Mask"] > 0]
    assert np.all((counts == 0) | ((counts >= 8) & (counts <= 64)))
    assert np.all(np.isfinite(res["Composite"]))
    # Rerun refuses to overwrite without --overwrite, and succeeds with it.
    assert cli.main(["post", str(passes), "--out", str(out), "--method", "fixed", "--quiet"]) == 2
    assert cli.main(["post", str(passes), "--out", str(out), "--method", "fixed", "--quiet",
                     "--overwrite"]) == 0


def test_post_is_deterministic(passes, tmp_path):
    for name in ("a", "b"):
        assert cli.main(["post", str(passes), "--out", str(tmp_path / name), "--method",
                         "as_ocv", "--seed", "5", "--quiet"]) == 0
    a = read_result(tmp_path / "a" / "as_ocv" / "0003.exr")
    b = read_result(tmp_path / "b" / "as_ocv" / "0003.exr")
    for layer in ("Composite", "SampleCount", "Alpha"):
        assert np.array_equal(a[layer], b[layer])


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--eta", "0"], "eta must be in (0, 1]"),
        (["--beta-min", "80"], "beta_min must be <= beta_max"),
        (["--method", "magic"], "--method must be a comma-separated list"),
        (["--target-variance", "-1"], "target_variance must be in (0, inf)"),
    ],
)
def test_bad_parameters_exit_2_with_one_line(passes, tmp_path, args, fragment):
    proc = subprocess.run(
        [sys.executable, "-m", "cvsss.sss_addon.cli", "post", str(passes), "--out",
         str(tmp_path / "o"), *args],
        capture_output=True, text=True, check=False,
    )
    assert proc.returncode == 2
    assert fragment in proc.stderr
    assert "Traceback" not in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1


def test_missing_directory_and_corrupt_file(tmp_path, capsys):
    assert cli.main(["post", str(tmp_path / "nope"), "--out", str(tmp_path / "o")]) == 2
    assert "nope" in capsys.readouterr().err
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "0001.exr").write_text("not an exr")
    assert cli.main(["post", str(bad), "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err
    assert "0001.exr" in err and "Traceback" not in err

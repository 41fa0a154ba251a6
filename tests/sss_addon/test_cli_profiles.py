"""`cvsss post` with every method, every profile of Table 2, presets and separable kernels."""

import csv

import numpy as np
import pytest
from cli_helpers import run_cli

from cvsss.core.io.exr import read_result, write_passes
from cvsss.core.methods import METHODS
from cvsss.core.synthetic import sequence
from cvsss.sss_addon.cli import main as cli


@pytest.fixture(scope="module")
def passes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("passes")
    for frame in sequence("flash", 2, 48, 27):
        write_passes(folder / f"{frame.number:04d}.exr", frame)
    return folder


def _post(passes, out, *args):
    return cli.main(
        [
            "post",
            str(passes),
            "--out",
            str(out),
            "--quiet",
            "--reference-spp",
            "32",
            "--fixed-spp",
            "8",
            *args,
        ]
    )


def test_every_method_of_the_table_runs(passes, tmp_path):
    out = tmp_path / "all"
    assert _post(passes, out, "--method", ",".join(METHODS), "--reference") == 0
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert {r["method"] for r in rows} == set(METHODS)
    for name in METHODS:
        res = read_result(out / name / "0002.exr")
        assert np.all(np.isfinite(res["Composite"])), name
    sep = read_result(out / "separable" / "0002.exr")
    # Reads per pixel: 2 passes x 1 term (pre-integrated) x 17 taps.
    assert set(np.unique(sep["SampleCount"][sep["Mask"] > 0])) == {34}


@pytest.mark.parametrize(
    "args",
    [
        ["--method", "separable", "--kernel", "svd2", "--taps", "11", "--jitter"],
        [
            "--method",
            "separable",
            "--kernel",
            "gaussians",
            "--gaussians",
            "2",
            "--taps",
            "25",
            "--follow",
            "exponential",
            "--filter",
            "linear",
        ],
        [
            "--method",
            "separable,fixed",
            "--kernel",
            "artist",
            "--profile",
            "artist",
            "--material",
            "skin1",
            "--preset-scale",
            "20",
        ],
        [
            "--method",
            "as_ccv,separable",
            "--profile",
            "dipole",
            "--material",
            "skin1",
            "--preset-scale",
            "20",
        ],
        ["--method", "fixed", "--profile", "burley", "--material", "1=skin1,2=marble"],
    ],
)
def test_profiles_presets_and_kernels(passes, tmp_path, args):
    out = tmp_path / "o"
    assert _post(passes, out, *args, "--reference") == 0
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    for r in rows:
        assert r["psnr_db"] and float(r["psnr_db"]) > 15.0, r


def test_profile_changes_the_result(passes, tmp_path):
    results = {}
    for profile in ("burley", "dipole", "artist"):
        out = tmp_path / profile
        assert (
            _post(
                passes,
                out,
                "--method",
                "fixed",
                "--profile",
                profile,
                "--material",
                "skin1",
                "--preset-scale",
                "20",
            )
            == 0
        )
        results[profile] = read_result(out / "fixed" / "0001.exr")["SSS"]
    assert not np.array_equal(results["burley"], results["dipole"])
    assert not np.array_equal(results["dipole"], results["artist"])


@pytest.mark.parametrize(
    ("args", "fragment"),
    [
        (["--profile", "dipole"], "the dipole profile needs a measured preset"),
        (["--material", "jelly"], "valid presets: apple"),
        (["--material", "x=skin1"], "SLOT=PRESET"),
        (["--material", "1=skin1,1=marble"], "slot 1 is given twice"),
        (["--material", "99=skin1"], "slot 99 is not a material of the passes (their slots: 1, 2"),
        (
            ["--method", "separable", "--kernel", "gaussians", "--gaussians", "9"],
            "gaussians must be in [1, 6]",
        ),
        (["--mm-per-unit", "0", "--material", "skin1"], "mm_per_unit must be"),
    ],
)
def test_user_errors_exit_2_with_one_line(passes, tmp_path, args, fragment, capsys):
    assert cli.main(["post", str(passes), "--out", str(tmp_path / "o"), "--quiet", *args]) == 2
    err = capsys.readouterr().err
    assert fragment in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1


def test_missing_preset_from_the_command_line_process(passes, tmp_path):
    proc = run_cli(
        "post", str(passes), "--out", str(tmp_path / "o"), "--quiet", "--profile", "dipole"
    )
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith("error: material 'skin' (slot 1): the dipole profile needs")
    assert not (tmp_path / "o").exists()  # refused before any output

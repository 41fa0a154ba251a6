"""`cvsss post` on a directory of real EXR files written by core.exr (no bpy)."""

import csv

import numpy as np
import pytest
from cli_helpers import run_cli

from cvsss.core.io.exr import read_result, write_passes
from cvsss.core.synthetic import sequence
from cvsss.sss_addon.cli import main as cli
from cvsss.sss_addon.cli.parser import build_parser


@pytest.fixture(scope="module")
def passes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("passes")
    for frame in sequence("flash", 4, 48, 27):
        write_passes(folder / f"{frame.number:04d}.exr", frame)
    return folder


def test_post_writes_results_and_metrics(passes, tmp_path):
    out = tmp_path / "out"
    code = cli.main(
        [
            "post",
            str(passes),
            "--out",
            str(out),
            "--method",
            "as_ccv,fixed",
            "--reference",
            "--reference-spp",
            "128",
            "--fixed-spp",
            "16",
            "--quiet",
        ]
    )
    assert code == 0
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert [r["method"] for r in rows[:3]] == ["reference", "as_ccv", "fixed"]
    assert len(rows) == 12
    for r in rows:
        assert float(r["spp"]) >= 0 and float(r["sampling_ms"]) >= 0
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
    assert (
        cli.main(
            ["post", str(passes), "--out", str(out), "--method", "fixed", "--quiet", "--overwrite"]
        )
        == 0
    )


def test_post_is_deterministic(passes, tmp_path):
    for name in ("a", "b"):
        assert (
            cli.main(
                [
                    "post",
                    str(passes),
                    "--out",
                    str(tmp_path / name),
                    "--method",
                    "as_ocv",
                    "--seed",
                    "5",
                    "--quiet",
                ]
            )
            == 0
        )
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
    proc = run_cli("post", str(passes), "--out", str(tmp_path / "o"), *args)
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


def test_reference_every_k_frames_leaves_other_methods_unchanged(passes, tmp_path):
    common = ["--method", "as_ccv", "--reference", "--reference-spp", "64", "--quiet"]
    assert cli.main(["post", str(passes), "--out", str(tmp_path / "all"), *common]) == 0
    assert (
        cli.main(
            ["post", str(passes), "--out", str(tmp_path / "k3"), *common, "--reference-every", "3"]
        )
        == 0
    )
    every = list(csv.DictReader(open(tmp_path / "all" / "metrics.csv")))
    some = list(csv.DictReader(open(tmp_path / "k3" / "metrics.csv")))
    # The reference on frames 1 and 4 only (the 1st and the (k+1)-th); PSNR only there.
    assert [int(r["frame"]) for r in some if r["method"] == "reference"] == [1, 4]
    assert sorted(p.name for p in (tmp_path / "k3" / "reference").glob("*.exr")) == [
        "0001.exr",
        "0004.exr",
    ]
    ccv_all = {int(r["frame"]): r for r in every if r["method"] == "as_ccv"}
    ccv_some = {int(r["frame"]): r for r in some if r["method"] == "as_ccv"}
    assert sorted(ccv_some) == [1, 2, 3, 4]
    for n, r in ccv_some.items():
        assert r["spp"] == ccv_all[n]["spp"]  # the reference never feeds the history
        assert (r["psnr_db"] == ccv_all[n]["psnr_db"]) if n in (1, 4) else r["psnr_db"] == ""
    np.testing.assert_array_equal(
        read_result(tmp_path / "k3" / "as_ccv" / "0003.exr")["SSS"],
        read_result(tmp_path / "all" / "as_ccv" / "0003.exr")["SSS"],
    )


def test_reference_every_below_one_is_refused(passes, tmp_path, capsys):
    code = cli.main(
        ["post", str(passes), "--out", str(tmp_path / "o"), "--reference", "--reference-every", "0"]
    )
    assert code == 2
    assert "--reference-every must be >= 1, got 0" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_overwrite_removes_results_the_new_run_does_not_make(passes, tmp_path):
    out = tmp_path / "out"
    common = [
        "post",
        str(passes),
        "--out",
        str(out),
        "--method",
        "as",
        "--reference",
        "--reference-spp",
        "32",
        "--quiet",
    ]
    assert cli.main(common) == 0
    assert len(list((out / "reference").glob("*.exr"))) == 4
    assert cli.main([*common, "--overwrite", "--reference-every", "2"]) == 0
    assert sorted(p.name for p in (out / "reference").glob("*.exr")) == ["0001.exr", "0003.exr"]
    assert len(list((out / "as").glob("*.exr"))) == 4


def _subcommands(parser, path=()):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield (*path, name), sub
                yield from _subcommands(sub, (*path, name))


def test_every_help_prints(capsys):
    """`cvsss <command> --help` works for every command: help texts pass through
    argparse's %-formatting (a parameter's "7 %" once broke `post --help`)."""
    commands = list(_subcommands(build_parser()))
    assert {("post",), ("render",), ("demo",)} <= {c for c, _ in commands}
    for command, _ in commands:
        with pytest.raises(SystemExit) as stop:
            cli.main([*command, "--help"])
        assert stop.value.code == 0, command
        out = capsys.readouterr().out
        assert "usage:" in out, command


def test_thin_parts_help_states_the_sizes_cycles_renders_whole(capsys):
    """`cvsss render --help` states the sizes the thin-parts rule uses (50 mean free
    paths for Random Walk, 8 to 50 d or under 8 every way for Christensen-Burley;
    accuracy §2.3), without Blender: the parser reads them from the rule's own bpy-free
    constants."""
    with pytest.raises(SystemExit):
        cli.main(["render", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert (
        "objects thinner than 50 mean free paths of their Random Walk material, or 8 to 50 "
        "d across or under 8 d every way for their Christensen-Burley one" in out
    )


def test_post_prepares_the_kernels_before_the_first_frame(
    passes, tmp_path, capsys, monkeypatch, no_compile, slow_compile
):
    """A compile longer than NOTICE is announced and reported before the first frame's
    line; a run with every frame done already compiles nothing."""
    from cvsss.sss_addon import precompile

    monkeypatch.setattr(precompile, "NOTICE", 0.1)
    calls = slow_compile(0.4)
    argv = ["post", str(passes), "--out", str(tmp_path / "out"), "--method", "none,as_ccv"]
    assert cli.main([*argv, "--backend", "numba"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert calls == [(27 * 48, "cvsss-compile")]
    first = next(i for i, line in enumerate(lines) if line.startswith("frame 1/"))
    assert lines[first - 2].startswith("compiling the numba passes (first use")
    assert lines[first - 1].startswith("compiled the numba passes in 0.")
    no_compile.clear()
    assert cli.main([*argv, "--backend", "numba", "--resume"]) == 0
    assert calls == [(27 * 48, "cvsss-compile")]  # all done: not prepared again
    assert not no_compile

"""``cvsss compare``: what it refuses, each with one line and status 2, before Blender starts."""

import pytest

from cvsss.sss_addon.cli import main as cli
from cvsss.sss_addon.cli.compare import settings_from_args
from cvsss.sss_addon.cli.parser import build_parser


def _error(capfd, *argv) -> str:
    code = cli.main(["compare", *map(str, argv)])
    err = capfd.readouterr().err
    assert code == 2, err
    assert err.startswith("error: ") and err.count("\n") == 1, err
    assert "Traceback" not in err
    return err


@pytest.fixture
def blend(tmp_path):
    path = tmp_path / "scene.blend"
    path.write_bytes(b"BLENDER")  # refused before it is opened
    return path


@pytest.mark.parametrize(
    "extra, fragment",
    [
        (["--frames", "3-1"], "--frames must be A-B"),
        (["--frames", "1", "--engine", "WORKBENCH"], "--engine must be a comma-separated list"),
        (["--frames", "1", "--samples", "16,x"], "--samples must be comma-separated whole"),
        (["--frames", "1", "--samples", "0"], "--samples must be in [1, 16777216], got 0"),
        (["--frames", "1", "--eevee-samples", "0"], "--eevee-samples must be in"),
        (["--frames", "1", "--method-variants", "skin"], "--method-variants must be"),
        (["--frames", "1", "--ground-truth-spp", "0"], "--ground-truth-spp must be in"),
    ],
)
def test_bad_values(blend, tmp_path, capfd, extra, fragment):
    err = _error(capfd, blend, "--out", tmp_path / "out", *extra)
    assert fragment in err
    assert not (tmp_path / "out").exists()


def test_missing_blend(tmp_path, capfd):
    err = _error(capfd, tmp_path / "none.blend", "--frames", "1", "--out", tmp_path / "out")
    assert "none.blend: no such .blend file" in err


def test_settings_one_per_cycles_sample_count_and_case_is_ignored():
    args = build_parser().parse_args(
        [
            "compare",
            "x.blend",
            "--frames",
            "1",
            "--out",
            "o",
            "--engine",
            "eevee,cycles",
            "--samples",
            "16,64,16",
            "--no-denoise",
        ]  # fmt: skip
    )
    assert settings_from_args(args) == [("EEVEE", None, False), ("CYCLES", 16, False),
                                        ("CYCLES", 64, False)]  # fmt: skip
    args = build_parser().parse_args(["compare", "x.blend", "--frames", "1", "--out", "o"])
    assert settings_from_args(args) == [("CYCLES", None, True), ("EEVEE", None, False)]

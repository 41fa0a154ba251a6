"""``openjd run`` runs farm/openjd on a tiny scene: pass chunks, then ``cvsss post --workers``.

The job's post equals ``cvsss post`` of the same passes bit for bit.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
pytest.importorskip("openjd.cli", reason="needs the cvsss[farm] extra (openjd-cli)")
pytest.importorskip("distributed", reason="needs the cvsss[farm] extra")

from cvsss.core.eval.compare import output_differences  # noqa: E402
from cvsss.sss_addon.cli import main as cli  # noqa: E402

pytestmark = pytest.mark.bpy

BUNDLE = Path(__file__).resolve().parents[2] / "farm" / "openjd"


@pytest.mark.timeout(400)
def test_openjd_run_renders_chunks_then_posts(demo, tmp_path):
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "job"
    run = subprocess.run(
        [
            sys.executable,
            "-m",
            "openjd",
            "run",
            str(BUNDLE / "template.yaml"),
            "-p",
            f"file://{BUNDLE / 'parameter_values.yaml'}",
            "-p",
            f"BlendFile={blend}",
            "-p",
            f"OutputDir={out}",
            "-p",
            "FrameEnd=3",
            "-p",
            "ChunkSize=2",
            "-p",
            "Tile=16",
            "-p",
            f"Python={sys.executable}",
            "--step",
            "Post",
            "--run-dependencies",
        ],
        capture_output=True,
        text=True,
        timeout=380,
        check=False,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    assert "Session ended successfully" in run.stdout
    assert sorted(p.name for p in (out / "passes").glob("*.exr")) == [
        "0001.exr",
        "0002.exr",
        "0003.exr",
    ]
    plain = tmp_path / "plain"
    argv = ["post", str(out / "passes"), "--out", str(plain), "--method", "as_ccv", "--quiet"]
    assert cli.main(argv) == 0
    assert output_differences(plain, out) == []

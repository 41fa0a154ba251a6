"""``cvsss render --workers``: pass chunks on a local Dask cluster, one Blender process each.

Loopback only; the cluster is shut down by the command. The distributed
render writes the same results as the plain command posting the same passes.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

bpy = pytest.importorskip("bpy")
pytest.importorskip("distributed", reason="needs the cvsss[farm] extra")

from cvsss.core.eval.compare import output_differences  # noqa: E402
from cvsss.sss_addon.cli import main as cli  # noqa: E402
from cvsss.sss_addon.cli.parser import build_parser  # noqa: E402

pytestmark = pytest.mark.bpy


def _mtimes(folder: Path) -> dict[str, int]:
    return {p.name: p.stat().st_mtime_ns for p in sorted(folder.glob("*.exr"))}


@pytest.mark.timeout(400)
def test_render_with_workers_in_chunks_then_tiled_post(demo_blend, tmp_path, no_compile):
    out = tmp_path / "dist"
    argv = ["render", str(demo_blend), "--frames", "1-4", "--out", str(out), "--quiet"]
    assert cli.main([*argv, "--workers", "2", "--chunk", "2", "--tile", "16"]) == 0
    assert not no_compile  # the workers process the tiles: no kernels prepared here
    assert sorted(_mtimes(out / "passes")) == [f"{n:04d}.exr" for n in (1, 2, 3, 4)]
    assert (out / "metrics.csv").exists()
    # The plain command on the same passes writes the same results, bit for bit.
    plain = tmp_path / "plain"
    shutil.copytree(out / "passes", plain / "passes")
    before = _mtimes(plain / "passes")
    assert (
        cli.main(["render", str(demo_blend), "--frames", "1-4", "--out", str(plain), "--quiet"])
        == 0
    )
    assert _mtimes(plain / "passes") == before  # reused, not rendered again
    assert "ended" in no_compile  # processed here: prepared first
    assert output_differences(plain, out) == []

    # Resumable: only the missing pass file is rendered again.
    (out / "passes" / "0003.exr").unlink()
    kept = _mtimes(out / "passes")
    argv_passes = [*argv, "--passes-only", "--workers", "2", "--chunk", "3"]
    assert cli.main(argv_passes) == 0
    now = _mtimes(out / "passes")
    assert "0003.exr" in now and all(now[k] == v for k, v in kept.items())


@pytest.mark.timeout(300)
def test_passes_only_writes_no_results(demo_blend, tmp_path):
    out = tmp_path / "o"
    argv = ["render", str(demo_blend), "--frames", "2-3", "--out", str(out), "--quiet"]
    assert cli.main([*argv, "--passes-only"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["passes"]
    assert sorted(_mtimes(out / "passes")) == ["0002.exr", "0003.exr"]


def test_ground_truth_of_a_chunk_falls_on_the_whole_range(addon):
    from cvsss.core.params import SSSParams
    from cvsss.sss_addon.blender.render import Job

    job = Job(None, None, list(range(9, 17)), Path("."), [], SSSParams(), ground_truth=True)
    job.ground_truth_every, job.range_start = 5, 1
    assert [f for i, f in enumerate(job.frames) if job.ground_truth_due(i)] == [11, 16]
    job.range_start = None
    assert [f for i, f in enumerate(job.frames) if job.ground_truth_due(i)] == [9, 14]


def test_chunks_run_the_files_python_as_the_whole_render_does(addon):
    """--enable-autoexec / --disable-autoexec, and who renders thin parts,
    reach the chunks' Blender processes."""
    from cvsss.core.params import SSSParams
    from cvsss.sss_addon.blender.render import Job
    from cvsss.sss_addon.farm.passes import chunk_argv

    job = Job(None, None, [1, 2], Path("."), [], SSSParams())
    parser = build_parser()
    for choice in (None, True, False):
        job.autoexec = choice
        argv = chunk_argv(Path("scene.blend"), Path("out"), 1, 2, job, 1)
        assert argv[3] == "render" and parser.parse_args(argv[3:]).autoexec is choice
    for who in ("CYCLES", "POST"):
        job.thin_walks = who
        argv = chunk_argv(Path("scene.blend"), Path("out"), 1, 2, job, 1)
        assert parser.parse_args(argv[3:]).thin_walks == who.lower()


def test_chunks_are_consecutive_runs():
    from cvsss.sss_addon.farm.passes import chunks

    assert chunks(list(range(1, 8)), 3) == [(1, 3), (4, 6), (7, 7)]
    with pytest.raises(ValueError):
        chunks([1], 0)

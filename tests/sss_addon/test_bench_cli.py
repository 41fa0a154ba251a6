"""``cvsss bench`` and the study subcommands: flags, files, plots, printed tables, memory.

The parser is built the way ``sss_addon.cli.main`` builds it (``add_parser`` /
``add_parsers`` on the ``cvsss`` subparsers); the measuring functions behind
them are tested in tests/core/test_bench.py and tests/core/test_studies.py.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time

import numpy as np
import pytest

from cvsss.core.bench import config, results
from cvsss.core.eval import quality
from cvsss.core.mc.history import History
from cvsss.core.studies import fig2
from cvsss.core.synthetic import scene_frame
from cvsss.sss_addon.cli import bench, studies
from cvsss.sss_addon.cli import main as cli_main
from cvsss.sss_addon.cli.params import UserError

PNG = b"\x89PNG\r\n\x1a\n"


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="cvsss")
    sub = parser.add_subparsers(dest="command", required=True)
    bench.add_parser(sub)
    studies.add_parsers(sub)
    return parser


def _args(*argv: str) -> argparse.Namespace:
    return _parser().parse_args(list(argv))


def _is_png(path) -> bool:
    return path.read_bytes()[: len(PNG)] == PNG and path.stat().st_size > 1000


# -- bench: flags ------------------------------------------------------------------------
def test_bench_flags_select_the_configuration():
    args = _args("bench", "--quick", "--sections", "pareto, cost", "--no-plots")
    cfg = bench.config_from_args(args)
    assert cfg.sections == ("pareto", "cost")
    assert cfg.cost_sizes == config.QUICK.cost_sizes
    assert args.no_plots and not args.write_calibration and args.rss_worker is None
    full = bench.config_from_args(_args("bench"))
    assert full == config.BenchConfig()


@pytest.mark.parametrize("sections", ["speed", "cost,speed", ","])
def test_bench_refuses_unknown_sections(sections):
    with pytest.raises(ValueError, match="--sections must be a subset of cost,frames,fit"):
        bench.run(_args("bench", "--sections", sections))


def test_bench_help_hides_the_worker_flag(capsys):
    with pytest.raises(SystemExit):
        _args("bench", "--help")
    out = capsys.readouterr().out
    assert "--write-calibration" in out and "--rss-worker" not in out


# -- bench: memory -----------------------------------------------------------------------
def test_rss_worker_reports_inputs_and_history_exactly():
    spec = {"size": [32, 18], "method": "as_ocv", "precision": "float16", "frames": 2}
    spec.update(scene="flash", seed=0)
    res = bench.rss_worker(spec)
    frame = scene_frame("flash", 2, 32, 18)
    passes = (frame.lighting, frame.albedo, frame.combined, frame.depth, frame.material)
    assert res["input_mb"] == sum(a.nbytes for a in passes) / 2**20
    assert res["history_mb"] == History.empty((18, 32), "float16").nbytes() / 2**20
    assert 10 < res["peak_rss_mb"] < 4096
    if res["source"] == "VmHWM":
        assert res["peak_rss_mb"] >= res["baseline_mb"]


def test_rss_worker_runs_as_a_module():
    spec = {"size": [16, 9], "method": "fixed", "precision": "float32", "frames": 1}
    spec.update(scene="flash", seed=0)
    proc = subprocess.run(
        [sys.executable, "-m", "cvsss.sss_addon.cli.bench", "--rss-worker", json.dumps(spec)],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    res = json.loads(proc.stdout.strip().splitlines()[-1])
    assert res["history_mb"] == 0.0  # fixed keeps no history
    assert 10 < res["peak_rss_mb"] < 4096


# -- bench: the numba cache -------------------------------------------------------------
_TOY = "import numba\n\n\n@numba.njit(cache=True)\ndef add_one(x):\n    return x + {}\n"


def _toy_stats(src, env) -> list[str]:
    """Call the toy kernel on 1 in a fresh process: its value and numba's cache hits and
    misses (compiles) of that call."""
    code = "import toy_kernel as t; v = t.add_one(1); s = t.add_one.stats; "
    code += "print(v, sum(s.cache_hits.values()), sum(s.cache_misses.values()))"
    proc = subprocess.run(
        [sys.executable, "-c", code],
        cwd=src,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    return proc.stdout.split()


def test_adopted_kernels_load_where_they_would_compile(tmp_path, monkeypatch):
    # A kernel compiled under one NUMBA_CACHE_DIR (as measure_jit's processes do),
    # copied into the source's own __pycache__, is loaded from there: no second compile.
    src = tmp_path / "src"
    src.mkdir()
    (src / "toy_kernel.py").write_text(_TOY.format(1), encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    cache = tmp_path / "cache1"
    assert _toy_stats(src, {**env, "NUMBA_CACHE_DIR": str(cache)}) == ["2", "0", "1"]  # compiled
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    assert bench.adopt_compiled(cache, src) == 2  # its index and its one compiled overload
    assert _toy_stats(src, env) == ["2", "1", "0"]  # loaded, not compiled
    # An index as new as its source is never replaced.
    before = {p.name: p.stat().st_mtime_ns for p in (src / "__pycache__").glob("*.nb*")}
    assert bench.adopt_compiled(cache, src) == 0
    after = {p.name: p.stat().st_mtime_ns for p in (src / "__pycache__").glob("*.nb*")}
    assert after == before
    # The source changes: the index there is out of date and the new compile replaces it.
    time.sleep(0.05)  # past the file system's clock tick
    (src / "toy_kernel.py").write_text(_TOY.format(2), encoding="utf-8")
    cache = tmp_path / "cache2"
    assert _toy_stats(src, {**env, "NUMBA_CACHE_DIR": str(cache)}) == ["3", "0", "1"]
    assert bench.adopt_compiled(cache, src) == 2
    assert _toy_stats(src, env) == ["3", "1", "0"]


def test_adopt_compiled_leaves_no_partial_file_when_a_copy_fails(tmp_path, monkeypatch):
    src, cache, target = tmp_path / "src", tmp_path / "cache", tmp_path / "target"
    src.mkdir()
    (src / "toy_kernel.py").write_text(_TOY.format(1), encoding="utf-8")
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    assert _toy_stats(src, {**env, "NUMBA_CACHE_DIR": str(cache)}) == ["2", "0", "1"]

    def full(a, b):  # the disk fills up as the first file is moved into place
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(bench.os, "replace", full)
    assert bench.adopt_compiled(cache, src, target) == 0
    assert target.is_dir() and list(target.iterdir()) == []


def test_adopt_compiled_finds_nothing_to_copy_for_another_folder(tmp_path):
    (tmp_path / "cache").mkdir()
    assert bench.adopt_compiled(tmp_path / "cache", tmp_path / "elsewhere") == 0
    assert not (tmp_path / "elsewhere" / "__pycache__").exists()


# -- bench: the whole quick run ----------------------------------------------------------
@pytest.fixture(scope="module")
def quick_run(tmp_path_factory):
    pytest.importorskip("matplotlib")
    tmp = tmp_path_factory.mktemp("bench")
    shipped = tmp / "shipped" / "quality_calibration.json"
    shipped.parent.mkdir()
    shutil.copy(quality.CALIBRATION_PATH, shipped)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(quality, "CALIBRATION_PATH", shipped)
        lines: list[str] = []
        result = bench.run_bench(
            tmp / "out", config.QUICK, write_calibration=True, log=lines.append
        )
    return tmp / "out", shipped, result, lines


@pytest.mark.slow  # the smoke run times a cold compile (about a minute): not in test-fast
def test_quick_run_writes_bench_json(quick_run):
    out, _, result, _ = quick_run
    text = (out / "bench.json").read_text(encoding="utf-8")
    assert text == results.to_json(result)
    data = json.loads(text)
    assert list(data) == [
        "version",
        "command",
        "config",
        "environment",
        "jit",
        "section_s",
        "cpu_share",
        "cost",
        "frame_time_ms",
        "samples_time_r2",
        "coverage_scaling",
        "resolution_scaling",
        "pareto",
        "workers",
        "peak_rss_mb",  # runs last (core.bench.config.SECTIONS)
        "backend_default",
        "cost_method",
        "ns_per_sample",
        "gather_ns_per_sample",
        "overhead_fraction",
        "wall_s",
        "targets",
        "plots",
    ]
    assert data["command"] == bench.REGENERATE
    assert data["config"] == json.loads(json.dumps(config.QUICK.to_dict()))
    assert data["environment"]["cpus"] == data["targets"]["bench_wall_s"]["cpus"]
    assert set(data["targets"]) == {
        "ns_per_sample_vs_gather_numba",  # NumPy, the fallback, has none (issue 46)
        "overhead_fraction_as_ocv",
        "samples_time_r2",
        "peak_rss_mb_largest",
        "as_ccv_time_vs_fixed_at_equal_psnr",
        "quality_45db_error_db",
        "bench_wall_s",
    }
    assert sorted(p.name for p in out.iterdir()) == [
        "bench.json",
        "pareto.png",
        "pareto_backends.png",
        "quality.png",
        "quality_calibration.json",
        "scaling.png",
    ]


@pytest.mark.slow  # the smoke run times a cold compile (about a minute): not in test-fast
def test_quick_run_reports_both_backends_and_the_jit(quick_run):
    _, _, result, lines = quick_run
    assert result["backend_default"] == "numba"
    assert (
        set(result["ns_per_sample"])
        == set(result["gather_ns_per_sample"])
        == {
            "numpy",
            "numba",
        }
    )
    for sizes in result["ns_per_sample"].values():
        assert set(sizes) == {"32x18"} and sizes["32x18"] > 0
    target = result["targets"]["ns_per_sample_vs_gather_numba"]
    # Judged on the median of the per-run ratios: inside their spread.
    lo, hi = target["spread"]["32x18"]
    assert lo <= target["value"] <= hi
    assert target["runs"] == config.QUICK.cost_frames - 1
    assert target["target"] == "<= 4" and target["size"] == "32x18"
    # Compiling (empty cache) is slower than loading what it wrote.
    jit = result["jit"]
    assert jit["numba"].startswith("numba ")
    assert jit["compile_s"] > jit["cache_load_s"] > 0
    # ... and every kernel was ready in the bench's own process before any timing.
    assert jit["in_process_s"] > 0
    summary = bench.format_summary(result)
    assert "numba (default) 32x18:" in summary and "numpy 32x18:" in summary
    assert f"numba JIT: compile {jit['compile_s']:.1f} s" in summary
    assert "frame ms numba 48x27: fixed" in summary


@pytest.mark.slow  # the smoke run times a cold compile (about a minute): not in test-fast
def test_quick_run_measures_the_tiled_post_on_workers(quick_run):
    w = quick_run[2]["workers"]
    if "skipped" in w:
        pytest.skip(w["skipped"])
    assert w["identical"] and set(w["runs"]) == {"1", "2"}
    assert w["speedup_2_vs_1"] > 0 and w["runs"]["2"]["work_ms_per_tile"] > 0
    assert 0 < w["runs"]["1"]["halo_overhead"] < 10


@pytest.mark.slow  # the smoke run times a cold compile (about a minute): not in test-fast
def test_quick_run_measures_memory_in_subprocesses(quick_run):
    rss = quick_run[2]["peak_rss_mb"]
    assert [(r["method"], r["precision"]) for r in rss["rows"]] == [
        ("as_ocv", "float32"),
        ("as_ocv", "float16"),
    ]
    for row in rss["rows"]:
        assert "error" not in row, row
        assert 10 < row["peak_rss_mb"] < 4096
    # The float16 history holds half the bytes of the float32 one.
    f32, f16 = rss["rows"]
    assert f16["history_mb"] == pytest.approx(f32["history_mb"] / 2)
    assert rss["second_frame_check"]["two_frames_mb"] is not None


@pytest.mark.slow  # the smoke run times a cold compile (about a minute): not in test-fast
def test_quick_run_writes_the_calibration_and_plots(quick_run):
    out, shipped, result, _ = quick_run
    cal = quality.load_calibration(out / "quality_calibration.json")
    assert {f.fixed["beta_min"] for f in cal.methods["as_ccv"]} == {8, 4}
    assert shipped.read_text(encoding="utf-8") == (out / "quality_calibration.json").read_text(
        encoding="utf-8"
    )
    assert result["plots"] == ["pareto.png", "pareto_backends.png", "quality.png", "scaling.png"]
    assert all(_is_png(out / name) for name in result["plots"])


@pytest.mark.slow  # the smoke run times a cold compile (about a minute): not in test-fast
def test_quick_run_logs_progress_and_the_targets(quick_run):
    _, _, result, lines = quick_run
    assert any(line.startswith("[") and "pareto fixed N=1" in line for line in lines)
    summary = lines[-2]
    assert summary == bench.format_summary(result)
    for name in result["targets"]:
        assert f"{name} " in summary
    assert summary.count("yes") == sum(t["met"] for t in result["targets"].values())
    assert lines[-1].startswith("wrote ") and lines[-1].endswith(" s")


# -- studies -------------------------------------------------------------------------------
def test_cv1d_writes_summary_curves_and_figure(tmp_path, capsys):
    """The coefficient study's files hold what the study is known to give (docs/explanation/design.md §8.5):
    the optimal coefficients of f = h/(1+y) against g = h(1−y), y ~ U[0, 1]
    (Cov(f, g)/Var(g) = 12·(2 ln 2 − 1 − (ln 2)/2) = 18 ln 2 − 12 ≈ 0.4767 for the
    sampled control, 2 ln 2 ≈ 1.386 for the known constant G = h/2), the five
    configurations for both lighting histories, and the ordering the paper shows:
    hat-EMCM best of the online residuals under dynamic lighting."""
    pytest.importorskip("matplotlib")
    assert studies.run(_args("cv1d", "--out", str(tmp_path), "--seeds", "20")) == 0
    summary = json.loads((tmp_path / "cv1d.json").read_text())
    configs = {"no_cv", "sf", "sf_ema", "emcm", "hat_emcm", "gt"}
    assert set(summary["static"]) == set(summary["dynamic"]) == configs
    assert summary["alpha_gt"]["static"] == pytest.approx(18 * np.log(2) - 12, abs=0.005)
    assert summary["alpha_gt"]["constant_control"] == pytest.approx(2 * np.log(2), abs=1e-3)
    dynamic = summary["dynamic"]
    assert dynamic["hat_emcm"] < min(dynamic["no_cv"], dynamic["sf"], dynamic["sf_ema"])
    assert dynamic["hat_emcm"] < 0.5 * dynamic["no_cv"]
    assert summary["settings"]["seeds"] == 20
    curves = json.loads((tmp_path / "cv1d_curves.json").read_text())
    assert curves and all(len(v) for v in curves.values())
    assert _is_png(tmp_path / "cv1d.png")
    out = capsys.readouterr().out
    assert out.endswith(f"wrote {tmp_path / 'cv1d.json'}, cv1d_curves.json, cv1d.png\n")
    assert "hat" in out and "dynamic" in out  # the table is printed


def test_fig2_writes_summary_curves_and_figure(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    assert studies.run(_args("fig2", "--out", str(tmp_path), "--seeds", "1", "--seed", "3")) == 0
    summary = json.loads((tmp_path / "fig2.json").read_text())
    assert summary["settings"]["seeds"] == 1 and summary["settings"]["seed"] == 3
    assert summary["increase_as"] == pytest.approx(fig2.run(seeds=1, seed=3)["increase_as"])
    assert _is_png(tmp_path / "fig2.png")
    assert "AS+OCV" in capsys.readouterr().out


def test_fp16_records_a_command_that_reproduces_it(tmp_path, capsys):
    argv = ["fp16", "--out", str(tmp_path), "--frames", "4", "--res", "24x16"]
    argv += ["--methods", "as_ocv,as", "--long-frames", "3"]
    assert studies.run(_args(*argv)) == 0
    data = json.loads((tmp_path / "fp16.json").read_text())
    assert data["frames"] == 4 and (data["width"], data["height"]) == (24, 16)
    assert set(data["drift"]) == {"as_ocv", "as"}
    assert [r["frame"] for r in data["long_run"]] == [3]
    command = data["command"].split()
    assert command[0] == "cvsss"
    again, first = _args(*command[1:]), _args(*argv)
    assert vars(again) == vars(first)
    assert "float16 vs float32" in capsys.readouterr().out


def test_separable_kernels_writes_json_and_markdown(tmp_path, capsys):
    argv = ["separable-kernels", "--out", str(tmp_path), "--res", "24x14", "--frames", "1"]
    assert studies.run(_args(*argv, "--reference-spp", "8", "--no-presets")) == 0
    data = json.loads((tmp_path / "separable_kernels.json").read_text())
    assert data["resolution"] == [24, 14] and data["preset_errors"] == {}
    assert data["machine"]
    table = (tmp_path / "separable_kernels.md").read_text()
    out = capsys.readouterr().out
    assert out.startswith(table) and "wrote " in out


def test_study_defaults_match_the_old_commands():
    assert _args("cv1d").seeds == 1000 and str(_args("cv1d").out) == "out"
    assert _args("fig2").seeds == 8
    fp = _args("fp16")
    assert (fp.frames, fp.res, fp.long_frames, fp.methods) == (
        300,
        (96, 54),
        6000,
        "as,as_ocv,as_ccv",
    )
    sk = _args("separable-kernels")
    assert (sk.res, sk.frames, sk.gaussians, sk.reference_spp) == ((640, 360), 3, 4, 256)
    assert str(sk.out) == "out/separable_kernels"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["cv1d", "--seeds", "1"], "seeds must be an integer >= 2"),
        (["fp16", "--methods", "fixed"], "--methods must be a subset of as, as_ocv, as_ccv"),
        (["fp16", "--frames", "1", "--long-frames", "0"], "frames must be >= 2"),
    ],
)
def test_studies_refuse_bad_arguments_as_user_errors(tmp_path, argv, message):
    with pytest.raises(UserError, match=message):
        studies.run(_args(*argv, "--out", str(tmp_path)))
    assert list(tmp_path.iterdir()) == []


def test_resolution_flag_is_checked_by_the_parser(capsys):
    with pytest.raises(SystemExit) as exc:
        _args("separable-kernels", "--res", "640by360")
    assert exc.value.code == 2
    assert "WIDTHxHEIGHT" in capsys.readouterr().err
    assert np.array_equal(_args("fp16", "--res", "8X4").res, (8, 4))


def test_missing_pass_folder_is_refused_before_the_jit(tmp_path, monkeypatch, capsys):
    """``--passes`` naming no pass folder is one message at once, not after the kernels'
    compile (about two minutes on a clean clone)."""

    def compile_first(pixels=None):
        raise AssertionError("measure_jit ran before the pass folder was checked")

    monkeypatch.setattr("cvsss.sss_addon.cli.bench.measure_jit", compile_first)
    argv = ["bench", "--quick", "--no-plots", "--out", str(tmp_path / "o")]
    argv += ["--passes", str(tmp_path / "nonexist"), "--sections", "pareto"]
    assert cli_main.main(argv) == 2
    assert capsys.readouterr().err.strip() == f"error: {tmp_path / 'nonexist'}: no such folder"
    assert not (tmp_path / "o").exists()

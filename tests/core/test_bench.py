"""``cvsss bench``: a smoke run at 32×18 (keys and sane values, never timings) and its helpers."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from cvsss.core.eval import bench, quality
from cvsss.core.mc.processor import SequenceProcessor
from cvsss.core.params import SSSParams
from cvsss.core.synthetic import scene_frame

TARGETS = (
    "ns_per_sample_vs_gather",
    "overhead_fraction_as_ocv",
    "samples_time_r2",
    "peak_rss_mb_largest",
    "as_ccv_time_vs_fixed_at_equal_psnr",
    "quality_45db_error_db",
    "bench_wall_s",
)


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench")
    result = bench.run_bench(out, bench.QUICK, plots=True, log=None)
    return out, result


def _finite_positive(x) -> bool:
    return isinstance(x, float | int) and math.isfinite(x) and x > 0


def test_smoke_writes_bench_json_with_every_figure(smoke):
    out, result = smoke
    data = json.loads((out / "bench.json").read_text(encoding="utf-8"))
    for key in (
        "ns_per_sample",
        "gather_ns_per_sample",
        "samples_time_r2",
        "overhead_fraction",
        "coverage_scaling",
        "resolution_scaling",
        "peak_rss_mb",
        "pareto",
        "targets",
        "environment",
        "config",
        "wall_s",
        "section_s",
    ):
        assert key in data, key
    assert set(TARGETS) <= set(data["targets"])
    for t in data["targets"].values():
        assert set(t) >= {"value", "target", "met"} and isinstance(t["met"], bool)
    assert data == json.loads(json.dumps(bench._clean_json(result)))


def test_smoke_values_are_sane(smoke):
    _, r = smoke
    assert _finite_positive(r["ns_per_sample"]["32x18"])
    assert _finite_positive(r["gather_ns_per_sample"]["32x18"])
    assert r["samples_time_r2"]["value"] <= 1.0
    for method in ("fixed", "as", "as_ocv", "as_ccv"):
        assert 0.0 <= r["overhead_fraction"][method] < 1.0
    assert r["overhead_fraction"]["fixed"] < r["overhead_fraction"]["as_ocv"] + 1e-9
    cov = r["coverage_scaling"]["rows"]
    assert [row["coverage"] for row in cov] == [0.5, 1.0]
    assert cov[0]["sss_pixels"] < cov[1]["sss_pixels"]
    eps = r["coverage_scaling"]["eps_u"]
    assert eps["raised"]["distant_pixels"] < eps["default"]["distant_pixels"]
    res = r["resolution_scaling"]["rows"]
    assert [row["pixels"] for row in res] == [32 * 18, 64 * 36]
    assert all(_finite_positive(row["ns_per_pixel"]) for row in res)
    rss = r["peak_rss_mb"]
    assert set(rss["32x18"]["as_ocv"]) == {"float32", "float16"}
    assert all(10 < v < 4096 for v in rss["32x18"]["as_ocv"].values())


def test_smoke_pareto_points_and_front(smoke):
    _, r = smoke
    par = r["pareto"]
    assert par["reference"]["mode"] == "affine"
    labels = {p["label"] for p in par["points"]}
    assert {
        "fixed N=1",
        "fixed N=16",
        "as σ0²=0.01",
        "as_ocv σ0²=0.0001",
        "as_ccv σ0²=0.01 β_min=4",
    } <= labels
    for p in par["points"]:
        assert p["frames"] == bench.QUICK.pareto_frames
        assert 20 < p["psnr_db"] <= 100 and p["pass_ms"] > 0
    fixed = sorted((p for p in par["points"] if p["method"] == "fixed"), key=lambda p: p["value"])
    assert [p["spp"] > 0 for p in fixed] and fixed[0]["psnr_db"] < fixed[-1]["psnr_db"]
    assert par["front"] and all(p["front"] == (p["label"] in par["front"]) for p in par["points"])
    if "separable" in r["pareto"]["separable"] and "skipped" not in par["separable"]:
        assert any(p["method"] == "separable" for p in par["points"])


def test_smoke_calibration_loads_and_plots_exist(smoke):
    out, r = smoke
    cal = quality.load_calibration(out / "quality_calibration.json")
    assert {"fixed", "as", "as_ocv", "as_ccv"} <= set(cal.methods)
    assert {f.fixed["beta_min"] for f in cal.methods["as_ccv"]} == {8, 4}
    checks = r["pareto"]["quality_checks"]
    assert checks["psnr"]["target"] == 45.0 and math.isfinite(checks["psnr"]["measured_psnr_db"])
    for name in ("pareto.png", "quality.png", "scaling.png"):
        assert (out / name).stat().st_size > 1000


def test_affine_reference_equals_the_reference_with_the_same_samples():
    frames = [scene_frame("flash", n, 24, 14) for n in range(1, 10)]
    params = SSSParams(reference_spp=32)
    ref, info = bench.reference_composites(frames, params)
    assert info["mode"] == "affine"
    proc = SequenceProcessor("reference", params)
    for i in (0, 4, 8):
        direct = proc.process(dataclasses.replace(frames[i], number=0)).composite
        np.testing.assert_allclose(ref(i), direct, rtol=1e-5, atol=1e-6)


def test_affine_detection_refuses_unrelated_lighting():
    frames = [scene_frame("regular", n, 24, 14) for n in (1, 2, 3)]
    frames.append(scene_frame("static", 4, 24, 14))
    rng = np.random.default_rng(3)
    frames[1] = dataclasses.replace(frames[1], lighting=rng.random(frames[1].lighting.shape))
    assert bench._affine_coefficients(frames) is None


def test_pareto_front_and_fixed_interpolation_known_values():
    pts = [
        {"method": "fixed", "pass_ms": 10.0, "psnr_db": 40.0},
        {"method": "fixed", "pass_ms": 100.0, "psnr_db": 50.0},
        {"method": "as_ccv", "pass_ms": 20.0, "psnr_db": 48.0},
        {"method": "as", "pass_ms": 120.0, "psnr_db": 49.0},
    ]
    assert bench.pareto_front(pts) == [0, 2, 1]
    t, extra = bench.fixed_time_at(pts, 45.0)
    assert t == pytest.approx(math.sqrt(10.0 * 100.0)) and not extra
    t, extra = bench.fixed_time_at(pts, 55.0)
    assert t == pytest.approx(100.0 * math.sqrt(10.0)) and extra


def test_gather_roofline_counts_every_sample():
    light = np.ones((18, 32, 3), np.float32)
    counts = np.zeros((18, 32), np.int32)
    assert math.isnan(bench.gather_ns_per_sample(light, counts))
    counts[5:10, 5:10] = 7
    assert bench.gather_ns_per_sample(light, counts) > 0


def test_config_from_args_refuses_unknown_sections():
    args = bench.build_parser().parse_args(["--quick", "--sections", "pareto,cost"])
    assert bench.config_from_args(args).sections == ("pareto", "cost")
    with pytest.raises(ValueError, match="sections"):
        bench.config_from_args(bench.build_parser().parse_args(["--sections", "speed"]))

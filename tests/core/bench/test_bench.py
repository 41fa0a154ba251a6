"""The bench's measuring functions (core.bench): known values and a smoke run at 32×18.

Timings are never asserted against thresholds; what is asserted is how each
figure is derived from what was measured (ratios, fits, fronts, sample
counts), which a bug in the bookkeeping breaks. The command line, files, plots
and the memory subprocesses are tested in tests/sss_addon/test_bench_cli.py.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from cvsss.core.bench import config, fit, gather, jobs, pareto, reference, results, rss, sections
from cvsss.core.eval import quality
from cvsss.core.eval.metrics import PSNR_CAP_DB
from cvsss.core.methods import make_processor
from cvsss.core.params import SeparableParams, SSSParams
from cvsss.core.synthetic import scene_frame


def _fake_rss(calls: list):
    """A measure_rss recording its specs and answering 100, 101, … MB in order."""

    def measure(specs: list[dict]) -> list[dict]:
        calls.append(specs)
        return [{"peak_rss_mb": 100.0 + i, "source": "fake"} for i in range(len(specs))]

    return measure


@pytest.fixture(scope="module")
def smoke():
    calls: list = []
    result = sections.run_sections(config.QUICK, measure_rss=_fake_rss(calls))
    return result, calls


def _dominated(p: dict, q: dict) -> bool:
    """q is at least as fast and as good as p, and strictly better in one."""
    return (
        q["sampling_ms"] <= p["sampling_ms"]
        and q["psnr_db"] >= p["psnr_db"]
        and (q["sampling_ms"] < p["sampling_ms"] or q["psnr_db"] > p["psnr_db"])
    )


# -- fits, fronts, interpolation: constructed data ----------------------------------------
def test_linear_fit_recovers_slope_intercept_and_r2_of_constructed_data():
    # Residuals orthogonal to [1, x]: the least-squares line is exactly 3 + 2x,
    # SS_res = 10 and SS_tot = 4·Σ(x − 2)² + Σe² = 50, so R² = 0.8.
    x = np.arange(5.0)
    e = np.array([1.0, -2.0, 0.0, 2.0, -1.0])
    line = fit.linear_fit(x, 3.0 + 2.0 * x + e)
    assert line["slope"] == pytest.approx(2.0, abs=1e-12)
    assert line["intercept"] == pytest.approx(3.0, abs=1e-12)
    assert line["r2"] == pytest.approx(0.8, abs=1e-12)


def test_linear_fit_matches_an_independent_fit_on_random_data(rng):
    x = rng.random(50) * 1e6
    y = 0.3 + 2e-5 * x + rng.normal(0.0, 2.0, 50)
    line = fit.linear_fit(x, y)
    design = np.stack([np.ones_like(x), x], axis=1)
    (a, b), *_ = np.linalg.lstsq(design, y, rcond=None)
    assert line["slope"] == pytest.approx(b, rel=1e-9)
    assert line["intercept"] == pytest.approx(a, rel=1e-9)
    assert line["r2"] == pytest.approx(np.corrcoef(x, y)[0, 1] ** 2, rel=1e-9)


def test_linear_fit_of_constant_data_is_nan():
    assert all(math.isnan(v) for v in fit.linear_fit([2.0, 2.0, 2.0], [1.0, 2.0, 3.0]).values())
    assert math.isnan(fit.linear_fit([1.0, 2.0, 3.0], [5.0, 5.0, 5.0])["r2"])
    assert math.isnan(fit.linear_fit([1.0], [1.0])["slope"])


def test_pareto_front_is_exactly_the_non_dominated_points():
    pts = [
        {"sampling_ms": 1.0, "psnr_db": 30.0},  # 0 front
        {"sampling_ms": 2.0, "psnr_db": 20.0},  # 1 dominated by 0
        {"sampling_ms": 2.0, "psnr_db": 35.0},  # 2 front
        {"sampling_ms": 3.0, "psnr_db": 35.0},  # 3 as good as 2 but slower
        {"sampling_ms": 3.0, "psnr_db": 40.0},  # 4 front
        {"sampling_ms": 5.0, "psnr_db": 39.0},  # 5 dominated by 4
        {"sampling_ms": 1.0, "psnr_db": 25.0},  # 6 as fast as 0 but worse
    ]
    assert pareto.pareto_front(pts) == [0, 2, 4]


def test_pareto_front_agrees_with_brute_force_on_random_points(rng):
    for _ in range(5):
        pts = [{"sampling_ms": float(t), "psnr_db": float(p)} for t, p in rng.random((60, 2))]
        expected = {i for i, p in enumerate(pts) if not any(_dominated(p, q) for q in pts)}
        front = pareto.pareto_front(pts)
        assert set(front) == expected
        assert [pts[i]["sampling_ms"] for i in front] == sorted(
            pts[i]["sampling_ms"] for i in front
        )


def test_fixed_time_at_interpolates_log_time_and_extrapolates():
    pts = [
        {"method": "fixed", "sampling_ms": 10.0, "psnr_db": 40.0},
        {"method": "fixed", "sampling_ms": 100.0, "psnr_db": 50.0},
        {"method": "as_ccv", "sampling_ms": 20.0, "psnr_db": 48.0},
        {"method": "as", "sampling_ms": 120.0, "psnr_db": 49.0},
    ]
    t, extra = pareto.fixed_time_at(pts, 45.0)
    assert t == pytest.approx(math.sqrt(10.0 * 100.0)) and not extra
    t, extra = pareto.fixed_time_at(pts, 55.0)
    assert t == pytest.approx(100.0 * math.sqrt(10.0)) and extra
    # A slower fixed point that is worse than a faster one does not count.
    slow = [*pts, {"method": "fixed", "sampling_ms": 1000.0, "psnr_db": 45.0}]
    assert pareto.fixed_time_at(slow, 45.0)[0] == pytest.approx(100.0)
    assert math.isnan(pareto.fixed_time_at(pts[:1], 45.0)[0])


def test_evaluate_targets_compares_values_with_thresholds():
    t = results.evaluate_targets(
        {
            "samples_time_r2": {"value": 0.96, "size": "8x8"},
            "wall_s": 901.0,
            "environment": {"cpus": 3},
        }
    )
    assert t["samples_time_r2"] == {"value": 0.96, "target": ">= 0.95", "met": True, "size": "8x8"}
    assert t["bench_wall_s"]["met"] is False and t["bench_wall_s"]["cpus"] == 3
    nan = results.evaluate_targets({"samples_time_r2": {"value": math.nan, "size": "8x8"}})
    assert nan["samples_time_r2"]["met"] is False


def test_the_temporal_steady_frame_is_held_against_half_a_second_at_1080p():
    def steady(size, median):
        row = {"median_s": median, "min_s": median - 0.1, "max_s": median + 0.2}
        row["runs_s"] = [row["min_s"], median, median, median, row["max_s"]]
        methods = {"as_ccv_t": row, "as_ccv": {**row, "median_s": 0.1}}
        return {"frame_time_ms": {"steady": {"size": size, "backend": "numba", "methods": methods}}}

    t = results.evaluate_targets(steady("1920x1080", 0.45))["as_ccv_t_1080p_s"]
    assert t == {
        "value": 0.45, "target": "<= 0.5", "met": True, "min_s": 0.35, "max_s": 0.65,
        "runs": 5, "backend": "numba",
    }  # fmt: skip
    assert results.evaluate_targets(steady("1920x1080", 0.51))["as_ccv_t_1080p_s"]["met"] is False
    # Another size is no figure for the target.
    assert "as_ccv_t_1080p_s" not in results.evaluate_targets(steady("32x18", 0.01))


def test_config_refuses_unknown_sections():
    with pytest.raises(ValueError, match="sections"):
        dataclasses.replace(config.QUICK, sections=("cost", "speed"))
    with pytest.raises(ValueError, match="sections"):
        dataclasses.replace(config.QUICK, sections=())


def test_rss_section_needs_a_measure():
    with pytest.raises(ValueError, match="measure_rss"):
        sections.run_sections(dataclasses.replace(config.QUICK, sections=("rss",)))


def test_clean_json_and_to_json():
    data = {"a": math.nan, 3: (np.float32(0.5), np.int64(2)), "b": [math.inf, 1.5]}
    assert results.clean_json(data) == {"a": None, "3": [0.5, 2], "b": [None, 1.5]}
    assert type(results.clean_json(np.int64(2))) is int
    assert results.to_json(data).endswith("\n")


def test_write_json_is_atomic_and_readable(tmp_path):
    path = tmp_path / "sub" / "x.json"
    results.write_json(path, {"v": math.nan, "σ": 1})
    assert json.loads(path.read_text(encoding="utf-8")) == {"v": None, "σ": 1}
    assert [p.name for p in path.parent.iterdir()] == ["x.json"]  # no temporaries left


# -- the gather roofline ---------------------------------------------------------------------
def test_gather_indices_stay_within_radius_of_their_pixel():
    counts = np.zeros((18, 32), np.int32)
    counts[0, 0] = 3
    counts[5:10, 20:25] = 7
    counts[17, 31] = 2
    q = gather.gather_indices(counts, seed=4, radius=3)
    assert q.size == counts.sum()
    centre = np.repeat(
        np.flatnonzero(counts.reshape(-1)), counts.reshape(-1)[counts.reshape(-1) > 0]
    )
    qy, qx = np.divmod(q, 32)
    cy, cx = np.divmod(centre, 32)
    assert np.all(np.abs(qy - cy) <= 3) and np.all(np.abs(qx - cx) <= 3)
    assert q.min() >= 0 and q.max() < counts.size
    assert len(np.unique(q)) > 10  # offsets are random, not the centre


def test_gather_ns_per_sample_divides_the_time_by_every_gather(monkeypatch):
    shapes = []

    def fake_best_of(fn, repeats=3):
        shapes.append(fn().shape)
        return 2e-3  # seconds

    monkeypatch.setattr(gather, "best_of", fake_best_of)
    light = np.ones((18, 32, 3), np.float32)
    counts = np.zeros((18, 32), np.int32)
    assert math.isnan(gather.gather_ns_per_sample(light, counts))
    assert shapes == []
    counts[5:10, 5:10] = 7
    counts[0, 0] = 1
    assert gather.gather_ns_per_sample(light, counts) == pytest.approx(2e6 / 176)
    assert shapes == [(176, 3)]


# -- running sequences -----------------------------------------------------------------------
def test_fixed_takes_exactly_n_samples_on_pixels_that_need_distant_samples():
    frames = [scene_frame("flash", n, 32, 18) for n in (1, 2)]
    params = SSSParams(fixed_spp=5)
    records, last = jobs.run_sequence(frames, "fixed", params, keep_last=True)
    need = last.mask & (last.gamma.max(axis=-1) >= params.eps_u)
    assert need.any() and (last.mask & ~need).any()
    assert np.all(last.counts[need] == 5) and np.all(last.counts[~need] == 0)
    rec = records[-1]
    assert rec["samples"] == 5 * int(need.sum()) == int(last.counts.sum())
    assert rec["spp"] == pytest.approx(5 * need.sum() / last.mask.sum())
    assert rec["sss_pixels"] == int(last.mask.sum())
    assert [r["frame"] for r in records] == [1, 2]


def test_reference_against_itself_has_the_psnr_cap():
    frames = [scene_frame("flash", n, 24, 14) for n in (1, 2, 3)]  # lighting differs per frame
    params = SSSParams(reference_spp=8)
    proc = make_processor("reference", params)
    refs = [proc.process(f).composite for f in frames]
    records, _ = jobs.run_sequence(frames, "reference", params, reference=refs.__getitem__)
    assert [r["psnr_db"] for r in records] == [PSNR_CAP_DB] * 3
    # The reference of another frame is not the cap: the index is what was compared.
    shifted, _ = jobs.run_sequence(frames, "reference", params, reference=lambda i: refs[i - 1])
    assert all(r["psnr_db"] < PSNR_CAP_DB for r in shifted)


def test_run_jobs_warms_up_and_records_from_the_given_frames():
    frames = [scene_frame("flash", n, 24, 14) for n in range(1, 5)]
    base = SSSParams(target_variance=1e-8)  # counts above β_min once there is history
    late = jobs.Job("late", "fixed", base, frames.__getitem__, first=1, record_from=2)
    warm = jobs.Job("warm", "as", base, frames.__getitem__, record_from=2, gather=True)
    jobs.run_jobs([late, warm], len(frames))
    assert [r["frame"] for r in late.records] == [3, 4]
    assert [r["frame"] for r in warm.records] == [3, 4]
    # The gather roofline is timed after the recorded frames of the jobs that ask for it.
    assert all(r["gather_ns"] > 0 for r in warm.records)
    assert not any("gather_ns" in r for r in late.records)
    # The adaptive job had frames 1 and 2 of history: its counts left β_min.
    cold, _ = jobs.run_sequence(frames[2:], "as", base)
    assert warm.records[0]["samples"] != cold[0]["samples"]


def test_repeats_restore_the_state_between_repetitions():
    frames = [scene_frame("flash", n, 24, 14) for n in range(1, 5)]
    once, thrice = make_processor("as_ocv"), make_processor("as_ocv")
    for frame in frames[:3]:
        a, _ = jobs.process_timed(once, frame, 1)
        b, times = jobs.process_timed(thrice, frame, 3)
        assert len(times) == 3
        np.testing.assert_array_equal(a.counts, b.counts)
    np.testing.assert_array_equal(once.process(frames[3]).alpha, thrice.process(frames[3]).alpha)


def test_separable_jobs_count_their_reads_as_samples():
    frames = [scene_frame("flash", 1, 24, 14)]
    sep = SeparableParams(kernel="svd2", taps=11)
    records, last = jobs.run_sequence(frames, "separable", SSSParams(), separable=sep)
    assert records[0]["spp"] == 2 * 2 * 11
    assert records[0]["samples"] == 2 * 2 * 11 * records[0]["sss_pixels"]


# -- the reference ------------------------------------------------------------------------
def test_affine_reference_equals_the_reference_with_the_same_samples():
    frames = [scene_frame("flash", n, 24, 14) for n in range(1, 10)]
    params = SSSParams(reference_spp=32)
    ref, info = reference.reference_composites(frames, params)
    assert info["mode"] == "affine"
    proc = make_processor("reference", params)
    for i in (0, 4, 8):
        direct = proc.process(dataclasses.replace(frames[i], number=0)).composite
        np.testing.assert_allclose(ref(i), direct, rtol=1e-5, atol=1e-6)


def test_affine_detection_refuses_unrelated_lighting_or_weights(rng):
    frames = [scene_frame("flash", n, 24, 14) for n in (1, 2, 3)]
    assert reference._affine_coefficients(frames) is not None
    lit = list(frames)
    lit[1] = dataclasses.replace(frames[1], lighting=rng.random(frames[1].lighting.shape))
    assert reference._affine_coefficients(lit) is None
    weighted = list(frames)
    weight = np.full(frames[2].shape, 0.5, np.float32)
    weighted[2] = dataclasses.replace(frames[2], sss_weight=weight)
    assert reference._affine_coefficients(weighted) is None


# -- the smoke run (QUICK, every section, memory measured by a fake) ---------------------------
def test_smoke_cost_figures_are_the_recorded_ratios(smoke):
    pytest.importorskip("numba")  # both backends side by side
    r, _ = smoke
    rows = r["cost"]["sizes"]["32x18"]
    assert set(rows) == set(config.COST_METHODS)
    for method, row in rows.items():
        assert row["samples"] > 0, method
        assert row["ns_per_sample"] == pytest.approx(row["sampling_ms"] * 1e6 / row["samples"])
        assert row["ratio_to_gather"] == pytest.approx(
            row["ns_per_sample"] / row["gather_ns_per_sample"]
        )
        assert row["overhead_fraction"] == pytest.approx(row["update_ms"] / row["total_ms"])
        # The spread is over the steady runs: every frame timed but the first.
        assert row["ratio_runs"] == config.QUICK.cost_frames - 1
        assert row["ratio_min"] <= row["ratio_median"] <= row["ratio_max"]
    assert rows["fixed"]["update_ms"] < min(rows[m]["update_ms"] for m in config.ADAPTIVE)
    # Both backends measured side by side; the default one (numba here) fills "sizes".
    by = r["cost"]["by_backend"]
    # Each row holds its own roofline (timed after each of its frames); the size's is
    # the fastest of them.
    gathers = [row["gather_ns_per_sample"] for b in by.values() for row in b["32x18"].values()]
    assert all(g > 0 for g in gathers) and len(set(gathers)) > 1
    assert r["cost"]["gather_ns_per_sample"]["32x18"] == min(gathers)
    assert r["backend_default"] == r["cost"]["backend_default"] == "numba"
    assert set(by) == {"numpy", "numba"} and rows is by["numba"]["32x18"]
    assert r["cost_method"] == "as_ccv"
    for key in ("ns_per_sample", "gather_ns_per_sample"):
        assert r[key] == {b: {"32x18": by[b]["32x18"]["as_ccv"][key]} for b in ("numpy", "numba")}
    for method in config.COST_METHODS:  # the same samples on both backends
        assert by["numpy"]["32x18"][method]["samples"] == rows[method]["samples"] > 0
    assert r["overhead_fraction"]["as_ocv"] == rows["as_ocv"]["overhead_fraction"]
    breakdown = r["cost"]["breakdown"]
    assert "unavailable" not in breakdown, breakdown.get("unavailable")


def test_smoke_frame_time_per_backend_size_and_method(smoke):
    pytest.importorskip("numba")  # both backends side by side
    ft = smoke[0]["frame_time_ms"]
    assert ft["backend_default"] == "numba" and ft["frames"] == config.QUICK.frame_frames
    for b in ("numpy", "numba"):
        assert set(ft[b]) == {"32x18", "48x27"}
        for rows in ft[b].values():
            assert set(rows) == set(config.QUICK.frame_methods)
            assert all(ms > 0 for ms in rows.values())
    steady = ft["steady"]
    assert steady["size"] == "32x18" and steady["backend"] == "numba"
    assert (steady["warmup"], steady["runs"]) == (2, 5)
    assert set(steady["methods"]) == set(config.QUICK.steady_methods)
    for row in steady["methods"].values():
        runs = row["runs_s"]
        assert len(runs) == 5 and all(s > 0 for s in runs)
        assert (row["min_s"], row["max_s"]) == (min(runs), max(runs))
        assert row["median_s"] == sorted(runs)[2]


def test_smoke_pareto_per_backend_same_samples_other_times(smoke):
    pytest.importorskip("numba")  # both backends side by side
    par = smoke[0]["pareto"]
    by = par["by_backend"]
    assert par["backend_default"] == "numba" and set(by) == {"numpy", "numba"}
    numba_pts = {p["label"]: p for p in by["numba"]}
    numpy_pts = {p["label"].removesuffix(" [numpy]"): p for p in by["numpy"]}
    mc = {label for label, p in numba_pts.items() if p["method"] != "separable"}
    assert mc and mc == set(numpy_pts)
    for label in mc:
        a, b = numba_pts[label], numpy_pts[label]
        assert a["spp"] == b["spp"], label
        assert a["psnr_db"] == pytest.approx(b["psnr_db"], abs=1e-3), label
        assert a["sampling_ms"] > 0 and b["sampling_ms"] > 0
    for pts in by.values():
        assert any(p["front"] for p in pts)
        front = [p for p in pts if p["front"]]
        others = [p for p in pts if p["method"] != "separable"]
        assert not any(_dominated(p, q) for p in front for q in others)


def test_smoke_fit_r2_matches_an_independent_fit(smoke):
    fit = smoke[0]["samples_time_r2"]
    x = np.array([p[0] for p in fit["points"]], float)
    y = np.array([p[1] for p in fit["points"]], float)
    labels = {p[2] for p in fit["points"]}
    assert labels == {"fixed N=2", "fixed N=8", "as", "as_ocv", "as_ccv"}
    assert fit["value"] == pytest.approx(np.corrcoef(x, y)[0, 1] ** 2, rel=1e-9)
    assert fit["slope_ns_per_sample"] == pytest.approx(np.polyfit(x, y, 1)[0] * 1e6, rel=1e-9)
    # fixed N = 8 takes 4× the samples of N = 2 on the same pixels.
    cfg = fit["configs"]
    assert cfg["fixed N=8"]["samples"] == 4 * cfg["fixed N=2"]["samples"]


def test_smoke_coverage_and_resolution_rows(smoke):
    r, _ = smoke
    cov = r["coverage_scaling"]["rows"]
    assert [row["coverage"] for row in cov] == [0.5, 1.0]
    assert cov[1]["sss_pixels"] == 32 * 18  # the whole image
    assert cov[0]["sss_ratio"] == pytest.approx(0.5, abs=0.1)
    assert cov[1]["time_ratio"] == 1.0 and cov[1]["pass_ratio"] == 1.0
    eps = r["coverage_scaling"]["eps_u"]
    # ε_u at the median max γ keeps (at least) half of the SSS pixels, fewer than before.
    assert eps["raised"]["distant_pixels"] >= 0.5 * eps["raised"]["sss_pixels"]
    assert eps["raised"]["distant_pixels"] < eps["default"]["distant_pixels"]
    assert eps["distant_ratio"] == pytest.approx(
        eps["raised"]["distant_pixels"] / eps["default"]["distant_pixels"]
    )
    res = r["resolution_scaling"]["rows"]
    assert [row["pixels"] for row in res] == [32 * 18, 64 * 36]
    for row in res:
        assert row["ns_per_pixel"] == pytest.approx(row["total_ms"] * 1e6 / row["pixels"])
        assert row["ns_per_sample"] == pytest.approx(row["sampling_ms"] * 1e6 / row["samples"])


def test_smoke_rss_table_follows_the_measured_specs(smoke):
    r, calls = smoke
    (specs,) = calls
    assert [(s["size"], s["method"], s["precision"], s["frames"]) for s in specs] == [
        ([32, 18], "as_ocv", "float32", 1),
        ([32, 18], "as_ocv", "float16", 1),
        ([32, 18], "as_ocv", "float32", 2),  # the second-frame check
    ]
    rss = r["peak_rss_mb"]
    assert rss["32x18"] == {"as_ocv": {"float32": 100.0, "float16": 101.0}}
    assert rss["second_frame_check"]["one_frame_mb"] == 100.0
    assert rss["second_frame_check"]["two_frames_mb"] == 102.0
    assert [row["source"] for row in rss["rows"]] == ["fake", "fake"]


def test_rss_specs_add_the_separable_method_once():
    specs, check = rss.rss_specs(
        dataclasses.replace(config.QUICK, rss_methods=("fixed",), rss_separable=True)
    )
    assert [(s["method"], s["precision"]) for s in specs] == [
        ("fixed", "float32"),
        ("separable", "float32"),
    ]
    assert check is None  # no adaptive configuration to check


def test_smoke_pareto_points(smoke):
    par = smoke[0]["pareto"]
    assert par["reference"]["mode"] == "affine"
    pts = {p["label"]: p for p in par["points"]}
    assert {"fixed N=1", "fixed N=16", "as σ0²=0.01", "as_ccv σ0²=0.01 β_min=4"} <= set(pts)
    for p in par["points"]:
        assert p["frames"] == config.QUICK.pareto_frames
        assert len(p["per_frame"]) == p["frames"]
        assert p["psnr_db"] == pytest.approx(np.mean([f[2] for f in p["per_frame"]]))
    # fixed N: N samples on the same pixels, so spp/N is one number; more samples, less noise.
    fixed = [pts[f"fixed N={n}"] for n in config.QUICK.fixed_spp]
    share = fixed[0]["spp"] / config.QUICK.fixed_spp[0]
    for n, p in zip(config.QUICK.fixed_spp, fixed):
        assert p["spp"] == pytest.approx(n * share)
    assert fixed[0]["psnr_db"] < fixed[1]["psnr_db"] < fixed[2]["psnr_db"]
    # separable: every kernel, its reads per pixel (2·J·taps) as spp.
    sep = [p for p in par["points"] if p["method"] == "separable"]
    assert len(sep) == len(pareto.separable_kernels()[0])
    assert pts["separable svd2"]["spp"] == 2 * 2 * SeparableParams().taps


def test_smoke_front_flags_are_the_non_dominated_points(smoke):
    par = smoke[0]["pareto"]
    pts = par["points"]
    for p in pts:
        assert p["front"] == (not any(_dominated(p, q) for q in pts)), p["label"]
    assert par["front"] == [p["label"] for p in pts if p["front"]]


def test_smoke_calibration_holds_the_swept_curves(smoke):
    par = smoke[0]["pareto"]
    cal = quality.Calibration.from_dict(par["calibration"])
    assert {"fixed", "as", "as_ocv", "as_ccv"} <= set(cal.methods)
    (fixed,) = par["calibration"]["methods"]["fixed"]["families"]
    assert fixed["values"] == list(config.QUICK.fixed_spp)
    fams = par["calibration"]["methods"]["as_ccv"]["families"]
    assert [f["fixed"]["beta_min"] for f in fams] == [8, 4]
    assert fams[0]["values"] == list(config.QUICK.sigmas)
    assert fams[1]["values"] == list(config.QUICK.calib_families[0][1])
    sweep = [p for p in par["points"] if p["method"] == "as_ccv" and p["beta_min"] == 8]
    assert fams[0]["psnr_db"] == [p["psnr_db"] for p in sweep]


def test_smoke_quality_checks_measure_what_the_calibration_chose(smoke):
    checks = smoke[0]["pareto"]["quality_checks"]
    psnr_check, spp_check = checks["psnr"], checks["spp"]
    assert psnr_check["target"] == 45.0 and spp_check["target"] == config.QUICK.check_spp
    assert psnr_check["error"] == pytest.approx(psnr_check["measured_psnr_db"] - 45.0)
    assert spp_check["error"] == pytest.approx(spp_check["measured_spp"] - config.QUICK.check_spp)
    # spp follows the chosen parameters on the independent seed (β_min-bound here).
    for c in (psnr_check, spp_check):
        assert c["measured_spp"] == pytest.approx(c["predicted_spp"], rel=0.05)


def test_smoke_result_is_json_without_nan(smoke):
    r, _ = smoke

    def refuse(name):
        raise AssertionError(f"{name} in the JSON")

    data = json.loads(results.to_json(r), parse_constant=refuse)
    assert set(data["section_s"]) == set(config.SECTIONS)
    assert set(data) >= {"cost", "samples_time_r2", "coverage_scaling", "peak_rss_mb", "pareto"}

"""`cvsss demo`: the main job end to end on tiny synthetic passes (no bpy).

The Blender source of the same command is tested in tests/blender/test_demo_blender.py.
"""

import csv
import json

import pytest

from cvsss.sss_addon.cli import demo
from cvsss.sss_addon.cli import main as cli
from cvsss.sss_addon.cli.demo import passes as demo_passes
from cvsss.sss_addon.cli.demo import targets


@pytest.fixture(scope="module")
def small_demo(tmp_path_factory):
    out = tmp_path_factory.mktemp("demo")
    code = cli.main(
        [
            "demo",
            "--source",
            "synthetic",
            "--out",
            str(out),
            "--res",
            "40x24",
            "--frames",
            "6",
            "--reference-every",
            "2",
            "--reference-spp",
            "128",
        ]
    )
    assert code == 0
    return out


def test_summary_has_every_scene_and_method(small_demo):
    summary = json.loads((small_demo / "summary.json").read_text())
    assert list(summary) == list(demo.SYNTHETIC_SCENES)
    for scene, methods in summary.items():
        assert list(methods) == ["reference", *[m for m in demo.DEMO_METHODS if m != "reference"]]
        for method, v in methods.items():
            assert {"spp", "sampling_ms", "psnr_db", "spp_max"} <= set(v)
            assert 0 <= v["spp"] <= v["spp_max"] and v["sampling_ms"] > 0
            assert 15 < v["psnr_db"] <= 100, (scene, method)
        # fixed takes N = 64 where distant scattering is needed (gamma >= eps_u), 0 elsewhere
        assert 0 < methods["fixed"]["spp"] <= 64
        # separable reports its reads per pixel: 2 passes x 1 term x 17 taps
        assert 0 < methods["reference"]["spp"] <= 128 and methods["separable"]["spp"] == 34


def test_reference_only_on_every_kth_frame(small_demo):
    rows = list(csv.DictReader(open(small_demo / "flash" / "metrics.csv")))
    assert [int(r["frame"]) for r in rows if r["method"] == "reference"] == [1, 3, 5]
    psnr_frames = [int(r["frame"]) for r in rows if r["method"] == "as" and r["psnr_db"]]
    assert psnr_frames == [1, 3, 5]
    assert len([r for r in rows if r["method"] == "as_ccv"]) == 6


def test_report_lists_table_targets_and_plots(small_demo):
    report = (small_demo / "report.md").read_text()
    assert "| flash | as_ccv |" in report and "| regular | separable |" in report
    assert "## Targets" in report and "spp AS / AS+CCV >= 1.8" in report
    assert "every 2nd frame (frames 1, 3, …)" in report
    for name in ("flash_frames.png", "regular_strip_as_ccv.png", "pareto.png"):
        assert f"({name})" in report
        assert (small_demo / name).stat().st_size > 1000


def test_bad_scene_is_one_clear_error(tmp_path, capsys):
    code = cli.main(
        ["demo", "--source", "synthetic", "--scenes", "boids", "--out", str(tmp_path / "d")]
    )
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("error: --scenes must be a list of flash, regular (--source synthetic)")
    assert "Traceback" not in err and not (tmp_path / "d").exists()


def test_pass_cache_follows_the_settings(tmp_path):
    out = tmp_path / "d"
    base = [
        "demo",
        "--source",
        "synthetic",
        "--scenes",
        "flash",
        "--out",
        str(out),
        "--reference-every",
        "3",
        "--reference-spp",
        "32",
    ]
    assert cli.main([*base, "--res", "24x16", "--frames", "5"]) == 0
    passes = out / "flash" / "passes"
    first = {p.name: p.stat().st_mtime_ns for p in passes.iterdir()}
    assert len(first) == 10  # 5 EXRs + 5 sidecars
    assert cli.main([*base, "--res", "24x16", "--frames", "5"]) == 0  # same settings: reused
    assert {p.name: p.stat().st_mtime_ns for p in passes.iterdir()} == first
    # Fewer frames: the extra frames go (they would enter the summary otherwise).
    assert cli.main([*base, "--res", "24x16", "--frames", "3"]) == 0
    assert sorted(p.name for p in passes.glob("*.exr")) == ["0001.exr", "0002.exr", "0003.exr"]
    rows = list(csv.DictReader(open(out / "flash" / "metrics.csv")))
    assert {int(r["frame"]) for r in rows} == {1, 2, 3}
    assert sorted(p.name for p in (out / "flash" / "as").glob("*.exr")) == [
        "0001.exr",
        "0002.exr",
        "0003.exr",
    ]
    # Passes of unknown origin (no stamp) are not trusted either.
    (out / "flash" / "demo.json").unlink()
    mtime = (passes / "0001.exr").stat().st_mtime_ns
    assert cli.main([*base, "--res", "24x16", "--frames", "3"]) == 0
    assert (passes / "0001.exr").stat().st_mtime_ns != mtime
    assert json.loads((out / "flash" / "demo.json").read_text())["frames"] == 3


def test_a_new_pass_format_renders_the_passes_again_but_keeps_the_ground_truth(tmp_path):
    """Only the passes depend on what the pass render writes (``pass_format``): the ground
    truth and the equal-time frames, rendered from the same scene, are kept; a change to
    the scene itself removes them all."""

    scene = tmp_path / "flash"
    kept = ["ground_truth/0001.exr", "equal_time/cycles_16/0021.exr", "timing.json"]
    gone = ["passes/0001.exr", "passes/0001.json", "denoised/passes/0001.exr"]
    for name in kept + gone:
        (scene / name).parent.mkdir(parents=True, exist_ok=True)
        (scene / name).write_text("{}")
    old = {"source": "blender", "scene": "flash", "frames": 5, "scenes_sha256": "a"}
    (scene / "demo.json").write_text(json.dumps(old))
    logged = []
    demo_passes.pass_cache(scene, {**old, "pass_format": 2}, False, logged.append)
    assert [n for n in kept + gone if (scene / n).exists()] == kept
    assert "removing 3 pass file(s)" in logged[0]
    assert json.loads((scene / "demo.json").read_text())["pass_format"] == 2
    demo_passes.pass_cache(scene, {**old, "pass_format": 2, "scenes_sha256": "b"}, False, None)
    assert not any((scene / n).exists() for n in kept)


def test_each_missed_ground_truth_target_says_why():
    """report.md explains every missed ground-truth target with the figure that shows why:
    the noise-free reference's room over separable and what as_ccv's noise costs of it,
    the reference's own rim, and its ceiling against Cycles with its denoiser."""

    def method(gt, warm, outer=1.0):
        return {"psnr_gt_db": gt, "psnr_gt_warm_db": warm, "rim_outer_ratio": outer}

    summary = {
        "s": {
            "reference": method(31.5, 31.5, 1.066),
            "as_ccv": method(30.5, 30.5, 1.067),
            "as_ccv_t": method(31.2, 31.2),
            "separable": method(29.1, 29.1),
            "none": method(26.4, 26.4),
        }
    }
    extras = {
        "s": {"equal_time": [{"what": "Cycles subsurface, 16 spp + OIDN", "psnr_gt_db": 36.2}]}
    }
    rows = [
        {
            "scene": "s",
            "check": "as_ccv - separable, warm frames (dB) >= 2",
            "value": 1.4,
            "met": False,
        },
        {
            "scene": "s",
            "check": "outer silhouette luminance as_ccv / GT - 1",
            "value": 0.07,
            "met": False,
        },
        {
            "scene": "s",
            "check": "denoised passes + as_ccv - Cycles (dB)",
            "value": -5.0,
            "met": False,
        },
        {"scene": "s", "check": "as_ccv - none, warm frames (dB) >= 3", "value": 4.1, "met": True},
    ]
    lines = targets.truth_reasons(summary, extras, rows)
    reasons = [line for line in lines if line.startswith("- s, ")]
    assert len(reasons) == 3  # one per miss, none for the target met
    assert "+2.40 dB from separable, so the model has the room" in reasons[0]
    assert "costs 1.00 dB" in reasons[0] and "+2.10 dB from separable" in reasons[0]
    assert "outer rim is +0.066 too" in reasons[1]
    assert "reaches 31.50 dB" in reasons[2] and "36.20 dB" in reasons[2]
    assert targets.truth_reasons(summary, extras, rows[3:]) == []


def _users_extra(met_psnr: bool) -> dict:
    """A what-you-had section's data: one PSNR target and one time target."""
    target = {
        "setting": "Cycles 16 spp + denoiser, Christensen-Burley (the materials' own)",
        "target": "subsurface pixels >= plain + 1 dB",
        "met": met_psnr,
        "ours": 30.0,
        "plain": 33.0,
        "required": 34.0,
        "why": [],
    }
    timing = {**target, "target": "time per frame <= 1.25 x plain", "met": False}
    return {
        "frames": [21, 22],
        "describe": "Frames 21-22.",
        "rows": [],
        "targets": [target, timing],
    }


def test_a_missed_psnr_target_names_the_models_ceiling():
    from cvsss.sss_addon.cli.demo.users import format_users_frame

    reference = {"psnr_gt_db": 31.5, "psnr_gt_full_db": 33.25}
    text = "\n".join(format_users_frame("flash", _users_extra(False), reference))
    assert "31.50 dB PSNR against Cycles on subsurface pixels, 33.25 dB whole" in text
    # Met PSNR targets (a missed time target alone) or no reference row: no such line.
    assert "converged" not in "\n".join(format_users_frame("flash", _users_extra(True), reference))
    assert "converged" not in "\n".join(format_users_frame("flash", _users_extra(False), None))

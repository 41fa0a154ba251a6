"""``cvsss render``: the headless command, as a bpy-module command and as a Blender script."""

import csv
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

bpy = pytest.importorskip("bpy")

from cvsss.core.io.exr import read_result  # noqa: E402
from cvsss.sss_addon.cli import main as cli  # noqa: E402

pytestmark = pytest.mark.bpy

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture
def plain_blend(addon, tmp_path):
    """A scene with a camera and only a non-subsurface material (resets the session)."""
    from cvsss.demo_blend.scenes import diffuse_material

    bpy.ops.wm.read_homefile(use_empty=True, use_factory_startup=True)
    scene = bpy.context.scene
    mesh = bpy.data.meshes.new("m")
    mesh.materials.append(diffuse_material("grey", (0.5, 0.5, 0.5)))
    scene.collection.objects.link(bpy.data.objects.new("o", mesh))
    cam = bpy.data.objects.new("cam", bpy.data.cameras.new("cam"))
    scene.collection.objects.link(cam)
    scene.camera = cam
    path = tmp_path / "plain.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path


def _error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("error: ")
    return err[0]


def test_user_errors_print_one_line_and_exit_2(demo_blend, plain_blend, tmp_path, capsys):
    out = str(tmp_path / "o")
    assert cli.main(["render", str(tmp_path / "missing.blend"), "--out", out]) == 2
    assert "missing.blend: no such .blend file" in _error_line(capsys)
    for bad in ("3-1", "a-b", "1-2-3", "-4"):
        assert cli.main(["render", str(demo_blend), "--frames", bad, "--out", out]) == 2
        assert "--frames must be A-B" in _error_line(capsys)
    blocker = tmp_path / "file"
    blocker.write_text("x")
    assert cli.main(["render", str(demo_blend), "--frames", "1", "--out", str(blocker / "o")]) == 2
    assert "cannot write to output folder" in _error_line(capsys)
    assert cli.main(["render", str(plain_blend), "--frames", "1", "--out", out]) == 2
    assert "no material in scene 'Scene' takes part" in _error_line(capsys)
    assert cli.main(["render", str(demo_blend), "--out", out, "--eta", "0"]) == 2
    assert "eta must be in (0, 1]" in _error_line(capsys)
    assert cli.main(["render", str(demo_blend), "--out", out, "--method", "bogus"]) == 2
    assert "--method must be" in _error_line(capsys)
    assert not Path(out).exists()


def _run(args, cwd):
    return subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=300, cwd=cwd, check=False
    )


def test_headless_command_and_blender_script_do_the_same_job(demo_blend, tmp_path):
    before = demo_blend.read_bytes()
    # `cvsss render` with the bpy module…
    run = _run(
        [
            "-m",
            "cvsss.sss_addon.cli.main",
            "render",
            str(demo_blend),
            "--frames",
            "1-2",
            "--out",
            str(tmp_path / "a"),
            "--quiet",
        ],
        tmp_path,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    # …and the script form Blender runs: blender -b scene.blend --python cli.py -- render …
    run = _run(
        [
            str(ROOT / "sss_addon" / "cli" / "main.py"),
            "--",
            "render",
            str(demo_blend),
            "--frames",
            "1-2",
            "--out",
            str(tmp_path / "b"),
            "--reference",
            "--reference-spp",
            "32",
        ],
        tmp_path,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    assert "frame 2/2 (2)" in run.stdout
    assert "Saved:" not in run.stdout  # Blender's lines about the temporary pass files
    assert demo_blend.read_bytes() == before  # never saved

    # The scene's saved settings choose the method (as_ocv); no reference unless asked.
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["as_ocv", "metrics.csv", "passes"]
    rows_a = list(csv.DictReader(open(tmp_path / "a" / "metrics.csv")))
    rows_b = list(csv.DictReader(open(tmp_path / "b" / "metrics.csv")))
    assert [(r["frame"], r["method"]) for r in rows_a] == [("1", "as_ocv"), ("2", "as_ocv")]
    assert [r["method"] for r in rows_b] == ["reference", "as_ocv"] * 2
    assert all(r["psnr_db"] == "" for r in rows_a)
    assert all(float(r["psnr_db"]) > 20 for r in rows_b)
    for frame in ("0001.exr", "0002.exr"):
        a = read_result(tmp_path / "a" / "as_ocv" / frame)
        b = read_result(tmp_path / "b" / "as_ocv" / frame)
        np.testing.assert_array_equal(a["SampleCount"], b["SampleCount"])
        np.testing.assert_array_equal(a["Composite"], b["Composite"])
    assert [r["spp"] for r in rows_a] == [r["spp"] for r in rows_b if r["method"] == "as_ocv"]


def test_render_sequence_api_uses_current_scene(demo, tmp_path):
    from cvsss.sss_addon.blender.standalone import render_sequence

    rows = render_sequence(
        None,
        (2, 2),
        tmp_path / "api",
        ["fixed"],
        {"fixed_spp": 4},
        "CYCLES",
        False,
        None,
        reference=False,
    )
    assert rows == [
        {
            "frame": 2,
            "method": "fixed",
            "spp": rows[0]["spp"],
            "sampling_ms": rows[0]["sampling_ms"],
            "frame_ms": rows[0]["frame_ms"],
            "psnr_db": "",
        }
    ]
    assert float(rows[0]["spp"]) == 4.0
    assert (tmp_path / "api" / "fixed" / "0002.exr").is_file()
    assert demo.frame_current == 1


def test_warmup_frames_fill_the_history_without_results(demo, tmp_path, capsys):
    out = tmp_path / "warm"
    assert cli.main(["render", "--frames", "1-2", "--out", str(out), "--warmup-frames", "-1"]) == 2
    assert "--warmup-frames must be >= 0" in _error_line(capsys)
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "scene.blend"))
    args = ["render", "--frames", "1-2", "--out", str(out), "--method", "as_ocv", "--no-reference"]
    assert cli.main([*args, "--warmup-frames", "2"]) == 0
    printed = capsys.readouterr().out
    assert "warm-up frame 1/2 (-1) passes rendered" in printed
    assert "warm-up frame -1 processed (not written)" in printed
    # Warm-up passes are kept beside the others; only the range has results and rows.
    assert sorted(p.name for p in (out / "passes").glob("*.exr")) == [
        "-001.exr",
        "0000.exr",
        "0001.exr",
        "0002.exr",
    ]
    assert sorted(p.name for p in (out / "as_ocv").glob("*.exr")) == ["0001.exr", "0002.exr"]
    rows = list(csv.DictReader(open(out / "metrics.csv")))
    assert [r["frame"] for r in rows] == ["1", "2"]
    # Another warm-up is another run: it starts over (the passes are reused).
    warm = read_result(out / "as_ocv" / "0001.exr")["Composite"]
    assert cli.main([*args, "--warmup-frames", "0", "--quiet"]) == 0
    assert not np.array_equal(warm, read_result(out / "as_ocv" / "0001.exr")["Composite"])


def test_render_sequence_prepares_after_the_render_before_the_post(
    demo, tmp_path, no_compile, slow_compile
):
    """The compile runs between the first passes' render and the first post-process, with
    nothing beside it (compiling beside Blender's render crashed the bpy module)."""
    from cvsss.sss_addon.blender.standalone import render_sequence

    calls = slow_compile(0.3)
    lines: list[tuple[float, str]] = []
    render_sequence(
        None,
        (2, 2),
        tmp_path / "run",
        ["as_ccv"],
        None,
        "CYCLES",
        False,
        lambda text: lines.append((time.perf_counter(), text)),
        reference=False,
    )
    assert calls == [(48 * 32, "cvsss-compile")]
    rendered = next(t for t, text in lines if "passes rendered" in text)
    processed = next(t for t, text in lines if " as_ccv:" in text)
    assert rendered < no_compile["began"] and no_compile["ended"] <= processed
    assert (tmp_path / "run" / "as_ccv" / "0002.exr").is_file()


# -- Python in the .blend: drivers and registered scripts (Blender's auto-execution) ----------
#: rig.py, a registered text block: defines the function the camera's lens driver calls.
RIG = "import bpy\nbpy.app.driver_namespace['lens_at'] = lambda frame: 50.0 + 2.0 * frame\n"


@pytest.fixture
def scripted_blend(demo, tmp_path):
    """The demo .blend with a Python driver on the camera's lens (``lens_at(frame)``, which
    only the registered text block rig.py defines) and that text block: 50 + 2·frame mm
    when they run. Skipped, the driver evaluates to 0, which the lens clamps to its
    minimum (as in Blender's own render)."""
    demo.sss_settings.use_reference = False
    camera = demo.camera.data
    driver = camera.driver_add("lens").driver
    driver.type = "SCRIPTED"
    driver.expression = "lens_at(frame)"
    rig = bpy.data.texts.new("rig.py")
    rig.write(RIG)
    rig.use_module = True
    demo.frame_set(1)
    # This session runs no file's Python (factory preferences): the driver is skipped.
    assert not driver.is_valid
    path = tmp_path / "scripted.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    return path, camera.name


#: The lens a skipped driver leaves: its value 0, clamped to the property's minimum (mm).
SKIPPED_LENS = max(0.0, bpy.types.Camera.bl_rna.properties["lens"].hard_min)


def _lenses(out: Path) -> dict[int, float]:
    """The camera lens (mm) each pass sidecar recorded, by frame."""
    return {
        int(p.stem): json.loads(p.read_text())["camera"]["lens"]
        for p in sorted((out / "passes").glob("*.json"))
    }


def test_python_drivers_and_scripts_run_with_enable_autoexec(scripted_blend, tmp_path):
    blend, camera = scripted_blend
    before = blend.read_bytes()
    args = ["-m", "cvsss.sss_addon.cli.main", "render", str(blend), "--frames", "1-2", "--quiet"]
    # Off (Blender's default): one warning line naming what is not run.
    off = _run([*args, "--out", str(tmp_path / "off")], tmp_path)
    assert off.returncode == 0, off.stderr[-3000:]
    warnings = [ln for ln in off.stderr.splitlines() if ln.startswith("warning: Python auto-exec")]
    assert warnings == [
        "warning: Python auto-execution is off: 1 Python driver(s) "
        f"({camera}: lens) and script 'rig.py' are not run; "
        "pass --enable-autoexec to run them"
    ], off.stderr[-3000:]
    assert _lenses(tmp_path / "off") == {1: SKIPPED_LENS, 2: SKIPPED_LENS}
    # On: rig.py runs, so the driver does, at each frame; no warning.
    on = _run([*args, "--out", str(tmp_path / "on"), "--enable-autoexec"], tmp_path)
    assert on.returncode == 0, on.stderr[-3000:]
    assert "auto-execution" not in on.stderr
    assert _lenses(tmp_path / "on") == {1: 52.0, 2: 54.0}
    # -Y: never, as blender -Y.
    never = _run([*args, "--out", str(tmp_path / "never"), "-Y", "--frames", "2"], tmp_path)
    assert never.returncode == 0, never.stderr[-3000:]
    assert "pass --enable-autoexec to run them" in never.stderr
    assert _lenses(tmp_path / "never") == {2: SKIPPED_LENS}
    assert blend.read_bytes() == before  # never saved


def test_file_blender_opened_keeps_blenders_own_choice(scripted_blend, tmp_path, capsys):
    """``blender -b FILE --python main.py -- render``: Blender opened the file (here: the
    bpy module, which has no -y), so its choice stands and the warning says how to change it."""
    blend, camera = scripted_blend
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    out = str(tmp_path / "here")
    assert cli.main(["render", "--frames", "1", "--out", out, "--enable-autoexec"]) == 2
    assert "give Blender -y or -Y" in _error_line(capsys)
    assert cli.main(["render", "--frames", "1", "--out", out, "--quiet"]) == 0
    err = capsys.readouterr().err.splitlines()
    assert [ln for ln in err if "auto-execution" in ln] == [
        "warning: Python auto-execution is off: 1 Python driver(s) "
        f"({camera}: lens) and script 'rig.py' are not run; run Blender with -y to run them"
    ]
    assert _lenses(Path(out)) == {1: SKIPPED_LENS}
    assert bpy.context.scene.frame_current == 1


def test_what_was_skipped_fits_one_line():
    from cvsss.sss_addon.blender.autoexec import Skipped

    many = Skipped([f"Cube.{i}: location[0]" for i in range(5)], ["a.py", "b.py"])
    assert many.describe() == (
        "5 Python driver(s) (Cube.0: location[0], Cube.1: location[0], Cube.2: location[0], "
        "2 more) and scripts 'a.py', 'b.py'"
    )
    assert Skipped([], ["rig.py"]).describe() == "script 'rig.py'"
    assert not Skipped()


def _composites(folder: Path, method: str) -> dict[int, np.ndarray]:
    return {
        int(p.stem): read_result(p)["Composite"] for p in sorted((folder / method).glob("*.exr"))
    }


def _guides(path: Path) -> tuple[np.ndarray, np.ndarray]:
    import OpenEXR

    exr = OpenEXR.File(str(path), separate_channels=True)
    channels = {k: c.pixels for p in exr.parts for k, c in p.channels.items()}
    return tuple(
        np.stack([channels[f"ViewLayer.Denoising {name}.{c}"] for c in letters], -1)
        for name, letters in (("Albedo", "RGB"), ("Normal", "XYZ"))
    )


def test_render_and_post_denoise_as_the_scene_asks(demo, tmp_path, capsys, oidn):
    """``cvsss render`` denoises the finished frames when the scene's render denoises (its
    prefilter and quality), and records it in the pass sidecars, which ``cvsss post``
    follows; ``--no-denoise`` keeps them as the post made them."""
    scene = demo
    scene.sss_settings.frame_start, scene.sss_settings.frame_end = 1, 2
    scene.cycles.use_denoising = True
    scene.cycles.denoising_prefilter, scene.cycles.denoising_quality = "NONE", "FAST"
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    method = scene.sss_settings.method
    on, off = tmp_path / "on", tmp_path / "off"
    assert cli.main(["render", str(blend), "--out", str(on), "--quiet"]) == 0
    assert cli.main(["render", str(blend), "--out", str(off), "--no-denoise", "--quiet"]) == 0
    sidecar = json.loads((on / "passes" / "0001.json").read_text())
    assert sidecar["denoise"]["prefilter"] == "NONE" and sidecar["denoise"]["quality"] == "FAST"
    assert sidecar["denoise"]["stand_in_gain"] == 0.0  # under 64 samples: denoised once
    assert "denoise" not in json.loads((off / "passes" / "0001.json").read_text())
    denoised, plain = _composites(on, method), _composites(off, method)
    assert sorted(denoised) == sorted(plain) == [1, 2]
    for frame, composite in denoised.items():
        want = oidn(plain[frame], *_guides(on / "passes" / f"{frame:04d}.exr"), "None", "Fast")
        np.testing.assert_allclose(composite, want, rtol=0, atol=1e-6)
        assert np.abs(composite - plain[frame]).max() > 1e-3
    # post: the sidecars say to denoise, --no-denoise does not; passes without the
    # guides cannot be denoised (one line, status 2).
    params = ["--method", method, "--quiet"]
    assert cli.main(["post", str(on / "passes"), "--out", str(tmp_path / "p1"), *params]) == 0
    assert (
        cli.main(
            ["post", str(on / "passes"), "--out", str(tmp_path / "p0"), "--no-denoise", *params]
        )
        == 0
    )
    post_on, post_off = _composites(tmp_path / "p1", method), _composites(tmp_path / "p0", method)
    for frame, composite in post_on.items():
        guides = _guides(on / "passes" / f"{frame:04d}.exr")
        want = oidn(post_off[frame], *guides, "None", "Fast")
        np.testing.assert_allclose(composite, want, rtol=0, atol=1e-6)
    capsys.readouterr()
    assert cli.main(["post", str(off / "passes"), "--out", str(tmp_path / "p2"), "--denoise"]) == 2
    assert "holds no denoiser guides" in _error_line(capsys)

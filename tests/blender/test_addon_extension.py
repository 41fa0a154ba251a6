"""The extension as users get it: built by Blender's tool, installed, enabled, disabled."""

import os
import re
import tomllib
import zipfile
from pathlib import Path

import pytest

pytest.importorskip("bpy")

from cvsss.core.methods import METHODS  # noqa: E402
from cvsss.core.params import SSSParams  # noqa: E402

pytestmark = pytest.mark.bpy

ROOT = Path(__file__).resolve().parents[2]


def test_zip_content(extension_zip):
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    assert manifest["id"] == "cvsss" and manifest["blender_version_min"] == "4.2.0"
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert manifest["permissions"]["files"]
    names = zipfile.ZipFile(extension_zip).namelist()
    assert "__init__.py" in names and "blender_manifest.toml" in names
    assert "sss_addon/cli/main.py" in names and "core/mc/processor.py" in names
    assert "demo_blend/scenes.py" in names and "operators/sequence.py" in names
    # --split-platforms: the Linux x64 zip carries the Linux x64 wheels of the manifest.
    assert extension_zip.name == f"cvsss-{manifest['version']}-linux_x64.zip"
    assert sorted(n for n in names if n.startswith("wheels/")) == sorted(
        w.removeprefix("./")
        for w in manifest["wheels"]
        if "linux" in w and w.endswith("x86_64.whl")
    )
    assert {n.split("/")[1].split("-")[0] for n in names if n.startswith("wheels/")} == {
        "openexr",
        "numba",
        "llvmlite",
    }
    built = tomllib.loads(zipfile.ZipFile(extension_zip).read("blender_manifest.toml").decode())
    assert built["build"]["generated"]["platforms"] == ["linux-x64"]
    for bad in (
        r"^tests/",
        r"^\.",
        r"/\.",
        r"__pycache__",
        r"\.egg-info",
        r"^Makefile$",
        r"^pyproject\.toml$",
        r"^requirements\.txt$",
        r"^requirements-farm\.txt$",
        r"^farm/",
        # Only OpenEXR and the compiled backend's wheels, for this zip's platform only;
        # the farm extra's dependencies (dask, openjd) are never bundled.
        r"^wheels/(?!openexr-|numba-|llvmlite-)",
        r"^wheels/.*(win_|macosx_|aarch64)",
        r"^out/",
        r"^dist/",
        r"\.blend$",
    ):
        assert not [n for n in names if re.search(bad, n)], bad


def _addon_files(path: Path) -> dict[str, bytes]:
    """A zip's files besides its wheels and its (generated) manifest."""
    with zipfile.ZipFile(path) as z:
        return {
            n: z.read(n)
            for n in z.namelist()
            if not n.startswith("wheels/") and n != "blender_manifest.toml"
        }


def test_windows_arm64_zip_carries_openexr_only(extension_zip):
    """numba 0.60 and llvmlite 0.43 publish no Windows-on-ARM wheel: that platform's zip
    bundles OpenEXR alone (the add-on then runs NumPy: see
    test_installed_zip_without_numba_runs_numpy), and is otherwise the same add-on as
    the Linux x64 zip, file for file."""
    manifest = tomllib.loads((ROOT / "blender_manifest.toml").read_text())
    arm = extension_zip.with_name(f"cvsss-{manifest['version']}-windows_arm64.zip")
    with zipfile.ZipFile(arm) as z:
        wheels = sorted(n for n in z.namelist() if n.startswith("wheels/"))
        built = tomllib.loads(z.read("blender_manifest.toml").decode())
    assert wheels == ["wheels/openexr-3.5.3-cp311-cp311-win_arm64.whl"]
    assert built["build"]["generated"] == {
        "platforms": ["windows-arm64"],
        "wheels": ["./wheels/openexr-3.5.3-cp311-cp311-win_arm64.whl"],
    }
    assert _addon_files(arm) == _addon_files(extension_zip)


@pytest.fixture(scope="module")
def installed(extension_zip, tmp_path_factory, check_script):
    """(extension_check.py's report, its work folder): run once, it renders."""
    work = tmp_path_factory.mktemp("installed")
    report, _ = check_script("extension_check.py", extension_zip, work, cwd=work)
    return report, work


def test_install_enable_check_disable(installed):
    report, tmp_path = installed

    assert report["install"] == ["FINISHED"] and report["enabled"]
    assert report["module_file"].startswith(str(tmp_path / "repo" / "cvsss"))
    assert report["core_module"].startswith(str(tmp_path / "repo" / "cvsss"))
    assert "tests" not in report["installed_files"]
    assert report["operators"] == [
        "apply_frame",
        "build_demo",
        "finish_render",
        "render_passes",
        "render_sequence",
    ]
    assert report["panels"] == ["SSS_PT_material", "SSS_PT_render", "SSS_PT_render_advanced"]

    settings = report["settings"]
    defaults = SSSParams()
    assert report["params"] == defaults.to_dict()
    for name, value in defaults.to_dict().items():
        if name in settings:
            assert settings[name]["value"] == pytest.approx(value), name
            assert settings[name]["description"], name
    assert settings["method"]["value"] == "as_ccv" and settings["cv_mode"]["value"] == "constant"
    assert settings["method"]["value"] in METHODS
    assert settings["engine"]["value"] == "CYCLES"
    assert settings["history_precision"]["value"] == "float32"
    assert settings["output_dir"]["value"] == "//cvsss/"
    assert not settings["apply_on_render"]["value"] and settings["warmup_frames"]["value"] == 8
    assert not settings["use_frame_range"]["value"] and not settings["overwrite"]["value"]
    for name, entry in settings.items():
        if entry["default"] is not None and name not in ("cv_mode",):
            assert (
                entry["value"] == pytest.approx(entry["default"])
                if isinstance(entry["value"], float)
                else entry["value"] == entry["default"]
            ), name
    material = report["material"]
    assert material["mode"]["value"] == "AUTO" and material["participates"]["value"] is False
    assert material["preset"]["value"] == "NONE" and material["use_override"]["value"] is False

    assert report["render"] == ["FINISHED"]
    assert report["outputs"] == ["as_ccv", "metrics.csv", "passes"]
    assert report["images"] == [
        "SSS CV Alpha",
        "SSS Gamma",
        "SSS Result",
        "SSS Sample Count",
        "SSS Variance",
    ]

    assert not report["enabled_after"]
    assert report["types_left"] == []
    assert report["scene_props_left"] == [] and report["material_props_left"] == []
    assert report["operators_left"] == []
    assert report["handlers_left"] == []
    assert report["uninstalled"]


def test_installed_zip_runs_the_compiled_backend(installed):
    """Blender installs the zip's numba/llvmlite wheels; the operators' render ran the kernel
    imported from them (not from the test environment)."""
    report, _ = installed
    assert {"numba", "llvmlite", "openexr"} <= set(report["wheel_site"])
    assert not report["numba_preloaded"]
    site = os.path.join("extensions", ".local")
    assert site in report["numba_file"] and site in report["llvmlite_file"]
    assert report["backend"].startswith("numba (0.60.0, ")
    assert report["kernel_signatures"] >= 1  # compiled and called (serial at this size)
    assert report["render"] == ["FINISHED"]


@pytest.fixture(scope="module")
def installed_without_numba(extension_zip, tmp_path_factory, check_script):
    """extension_check.py with numba and llvmlite refused: (report, stdout)."""
    work = tmp_path_factory.mktemp("installed_without_numba")
    return check_script("extension_check.py", extension_zip, work, "--no-numba", cwd=work)


def test_installed_zip_without_numba_runs_numpy(installed_without_numba):
    """Where numba cannot be imported (the windows-arm64 zip has no wheel of it) the installed
    add-on installs, renders through its operators on NumPy, says so (panel and log), starts
    no background compile and unregisters cleanly."""
    report, stdout = installed_without_numba
    assert report["install"] == ["FINISHED"] and report["enabled"]
    assert report["render"] == ["FINISHED"]
    assert report["outputs"] == ["as_ccv", "metrics.csv", "passes"]
    assert "SSS Sample Count" in report["images"]
    assert report["backend"].startswith("NumPy (numba unavailable (ModuleNotFoundError")
    assert report["numba_file"] is None and report["llvmlite_file"] is None
    assert report["kernel_signatures"] == 0
    # Asked "auto": the log says which backend runs and why, at INFO (not a warning).
    ((level, message),) = (r for r in report["log"] if "Monte Carlo backend" in r[1])
    assert level == "INFO" and "backend numpy (asked auto" in message
    assert "NumPy fallback" in message
    # The background compile is on in this run; with no numba it starts nothing.
    assert not report["background_compile"]
    assert "compiling the numba passes" not in stdout
    assert not [r for r in report["log"] if "no background compile" in r[1]]  # not even tried
    assert not [r for r in report["log"] if r[0] in ("WARNING", "ERROR")]
    assert not report["enabled_after"] and report["types_left"] == []
    assert report["handlers_left"] == [] and report["uninstalled"]

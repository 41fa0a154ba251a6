"""The extension as users get it: built by Blender's tool, installed, enabled, disabled."""

import json
import os
import re
import subprocess
import sys
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
    assert sorted(n for n in names if n.startswith("wheels/")) == sorted(
        w.removeprefix("./") for w in manifest["wheels"]
    )
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
        r"^wheels/(?!openexr-)",  # the farm extra's dependencies are never bundled
        r"^out/",
        r"^dist/",
        r"\.blend$",
    ):
        assert not [n for n in names if re.search(bad, n)], bad


def test_install_enable_check_disable(extension_zip, tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "BLENDER_USER_RESOURCES"}
    run = subprocess.run(
        [
            sys.executable,
            str(Path(__file__).with_name("extension_check.py")),
            str(extension_zip),
            str(tmp_path),
        ],
        capture_output=True,
        text=True,
        check=False,
        timeout=600,
        env=env,
        cwd=tmp_path,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    (line,) = (ln for ln in run.stdout.splitlines() if ln.startswith("REPORT "))
    report = json.loads(line.removeprefix("REPORT "))

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

"""farm/openjd: the Open Job Description bundle passes ``openjd check``."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("openjd.cli", reason="needs the cvsss[farm] extra (openjd-cli)")

ROOT = Path(__file__).resolve().parents[2]
BUNDLE = ROOT / "farm" / "openjd"


def openjd(*args: str, timeout: float = 60) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "openjd", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def test_template_passes_openjd_check():
    run = openjd("check", str(BUNDLE / "template.yaml"))
    assert run.returncode == 0, run.stdout + run.stderr
    assert "passes validation checks" in run.stdout


def test_parameter_defaults_name_template_parameters():
    yaml = pytest.importorskip("yaml")
    template = yaml.safe_load((BUNDLE / "template.yaml").read_text())
    defaults = yaml.safe_load((BUNDLE / "parameter_values.yaml").read_text())
    names = {p["name"]: p for p in template["parameterDefinitions"]}
    assert set(defaults) <= set(names)
    assert {"BlendFile", "OutputDir"} - set(defaults) == {"BlendFile", "OutputDir"}
    for name, value in defaults.items():
        assert names[name].get("default") == value, name
    steps = [s["name"] for s in template["steps"]]
    assert steps == ["Passes", "Post"]
    assert template["steps"][1]["dependencies"] == [{"dependsOn": "Passes"}]

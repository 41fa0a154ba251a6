"""The parameter and command-line references under docs/reference are what the code says
(tools/reference.py writes them from the parameter specs and ``--help``)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def _reference():
    spec = importlib.util.spec_from_file_location("reference", ROOT / "tools" / "reference.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["parameters.md", "cli.md"])
def test_reference_pages_are_current(name):
    page = _reference().pages()[name]
    committed = (ROOT / "docs" / "reference" / name).read_text(encoding="utf-8")
    assert committed == page, (
        f"docs/reference/{name} is out of date: regenerate it with "
        "`.venv/bin/python tools/reference.py`"
    )


def test_every_flag_of_every_parameter_is_in_the_reference():
    from cvsss.core.params import SSSParams, flag_of, specs

    page = (ROOT / "docs" / "reference" / "parameters.md").read_text(encoding="utf-8")
    for f, spec in specs(SSSParams):
        if flag_of(f, spec):
            assert f"`--{flag_of(f, spec)}`" in page, f.name

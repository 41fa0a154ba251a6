"""The examples in the core's docstrings run and give what they show (doctest)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import cvsss.core

#: Modules that import numba at import time: their examples run where numba does.
_NEEDS_NUMBA = "cvsss.core.backends.numba"


def _modules() -> list[str]:
    return sorted(
        info.name
        for info in pkgutil.walk_packages(cvsss.core.__path__, "cvsss.core.")
        if not info.name.startswith(_NEEDS_NUMBA)
    )


def test_the_core_has_examples():
    examples = 0
    for name in _modules():
        module = importlib.import_module(name)
        examples += sum(len(t.examples) for t in doctest.DocTestFinder().find(module))
    assert examples >= 20  # the colour, sequence, profile, frame and metric examples


@pytest.mark.parametrize("name", _modules())
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS, report=False)
    assert result.failed == 0, f"{name}: {result.failed} of {result.attempted} examples failed"

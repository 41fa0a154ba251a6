"""core/ is pure computation: no Blender, command line, plotting, processes, threads or printing.

Two checks:

- every module under ``cvsss.core`` imports in a fresh interpreter in which
  ``bpy``, ``argparse``, ``matplotlib`` and ``subprocess`` cannot be imported
  (a ``sys.meta_path`` finder refuses them). ``threading`` cannot be blocked
  this way: NumPy itself imports it (and ``platform``) at import time, so it
  is left to the source check;
- the sources of core/ contain no ``print(``, ``exit``/``sys.exit`` calls, no
  import of those modules (nor ``threading``, ``concurrent``,
  ``multiprocessing``) and no ``/proc/`` path, found with :mod:`ast` so
  comments and docstrings that mention them do not count.
"""

from __future__ import annotations

import ast
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import cvsss.core

CORE = Path(cvsss.core.__file__).resolve().parent
BLOCKED = ("bpy", "argparse", "matplotlib", "subprocess")
FORBIDDEN_IMPORTS = frozenset(
    {*BLOCKED, "threading", "concurrent", "multiprocessing", "_thread", "resource"}
)

_IMPORT_ALL = textwrap.dedent(
    """
    import importlib, json, pkgutil, sys

    BLOCKED = set(json.loads(sys.argv[1]))
    preloaded = sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED)

    class Refuse:
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] in BLOCKED:
                raise ImportError(f"{name} is blocked in core")
            return None

    sys.meta_path.insert(0, Refuse())
    try:
        import argparse  # noqa: F401
        blocker_works = False
    except ImportError:
        blocker_works = True

    failures = {}
    names = ["cvsss.core"]

    def failed(name):
        failures[name] = repr(sys.exc_info()[1])

    try:
        core = importlib.import_module("cvsss.core")
    except Exception as exc:
        failures["cvsss.core"] = repr(exc)
    else:
        for info in pkgutil.walk_packages(core.__path__, "cvsss.core.", onerror=failed):
            names.append(info.name)
            try:
                importlib.import_module(info.name)
            except Exception as exc:
                failures[info.name] = repr(exc)
    print(json.dumps({
        "preloaded": preloaded,
        "blocker_works": blocker_works,
        "modules": names,
        "failures": failures,
        "loaded": sorted(m for m in sys.modules if m.split(".")[0] in BLOCKED),
    }))
    """
)


def _core_files() -> list[Path]:
    return sorted(p for p in CORE.rglob("*.py") if "__pycache__" not in p.parts)


def test_every_core_module_imports_without_blocked_modules():
    proc = subprocess.run(
        [sys.executable, "-c", _IMPORT_ALL, json.dumps(BLOCKED)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr
    report = json.loads(proc.stdout.strip().splitlines()[-1])
    assert report["preloaded"] == []  # else blocking them would prove nothing
    assert report["blocker_works"]
    assert report["failures"] == {}
    assert report["loaded"] == []
    # Every source file was imported (the walk did not stop early).
    expected = {
        ".".join(("cvsss", *p.relative_to(CORE.parent).with_suffix("").parts)).removesuffix(
            ".__init__"
        )
        for p in _core_files()
    }
    assert expected <= set(report["modules"])


def offences(source: str) -> list[str]:
    """Front-end code in ``source``: forbidden imports, print/exit calls, /proc paths."""
    tree = ast.parse(source)
    docstrings = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            body = node.body
            if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant):
                docstrings.add(id(body[0].value))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names = [node.module]
        else:
            names = []
        found += [
            f"line {node.lineno}: import {n}" for n in names if n.split(".")[0] in FORBIDDEN_IMPORTS
        ]
        if isinstance(node, ast.Call):
            f = node.func
            if isinstance(f, ast.Name) and f.id in ("print", "exit", "quit", "breakpoint"):
                found.append(f"line {node.lineno}: {f.id}()")
            if (
                isinstance(f, ast.Attribute)
                and isinstance(f.value, ast.Name)
                and (f.value.id, f.attr) in (("sys", "exit"), ("os", "_exit"), ("os", "system"))
            ):
                found.append(f"line {node.lineno}: {f.value.id}.{f.attr}()")
        if (
            isinstance(node, ast.Constant)
            and isinstance(node.value, str)
            and "/proc/" in node.value
            and id(node) not in docstrings
        ):
            found.append(f"line {node.lineno}: /proc path")
    return found


def test_the_source_check_finds_real_code_only():
    source = textwrap.dedent(
        '''
        """Docstring mentioning print( and import argparse and /proc/self/status."""
        import os
        import concurrent.futures
        from matplotlib import pyplot
        from . import subprocess  # a sibling module of that name is fine
        # print("commented out")

        def f():
            """print(x) and sys.exit(1) in a docstring."""
            text = "print(1)"
            print(text)
            sys.exit(2)
            return open("/proc/self/status")
        '''
    )
    assert [o.split(": ", 1)[1] for o in offences(source)] == [
        "import concurrent.futures",
        "import matplotlib",
        "print()",
        "sys.exit()",
        "/proc path",
    ]


@pytest.mark.parametrize("path", _core_files(), ids=lambda p: str(p.relative_to(CORE)))
def test_core_source_has_no_front_end_code(path):
    assert offences(path.read_text(encoding="utf-8")) == []

"""The house's floors hold: no import circle anywhere in the package, function-level
imports included, and the backends floor imports nothing above the ground floor.

The graph is read from the source (relative imports, the way the package imports
itself), so a circle shows here before it shows as an ImportError at some import order.
Imports under ``if TYPE_CHECKING:`` are annotations only and do not count.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FOLDERS = ("core", "sss_addon", "operators", "demo_blend")

#: What the backends floor may import: itself and the ground floor.
BACKENDS_MAY_IMPORT = (
    "core.backends",
    "core.params",
    "core.sampling",
    "core.color",
    "core.io.atomic",
    "core.io.errors",
)


def _module(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def _exists(module: str) -> bool:
    base = ROOT.joinpath(*module.split("."))
    return base.with_suffix(".py").is_file() or (base / "__init__.py").is_file()


def import_edges() -> set[tuple[str, str]]:
    """(importer, imported) of every relative import of the package's own modules, with
    the packages an import initialises on the way."""
    edges = set()
    for folder in FOLDERS:
        for path in sorted((ROOT / folder).rglob("*.py")):
            here = _module(path)
            package = here.split(".") if path.name == "__init__.py" else here.split(".")[:-1]
            tree = ast.parse(path.read_text(encoding="utf-8"))
            parents = {
                child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)
            }
            for node in ast.walk(tree):
                if not (isinstance(node, ast.ImportFrom) and node.level):
                    continue
                up, typing_only = node, False
                while up in parents:
                    up = parents[up]
                    if isinstance(up, ast.If) and "TYPE_CHECKING" in ast.unparse(up.test):
                        typing_only = True
                if typing_only:
                    continue
                base = package[: len(package) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
                if not target:  # the extension root (``from ... import register``)
                    edges.add((here, "<root>"))
                    continue
                for alias in node.names:
                    name = f"{target}.{alias.name}"
                    edges.add((here, name if _exists(name) else target))
                parts = target.split(".")
                for i in range(1, len(parts)):
                    ancestor = ".".join(parts[:i])
                    if not (here == ancestor or here.startswith(ancestor + ".")):
                        edges.add((here, ancestor))
    return edges


def circles(edges: set[tuple[str, str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    graph: dict[str, set[str]] = {}
    for a, b in edges:
        if a != b:
            graph.setdefault(a, set()).add(b)
            graph.setdefault(b, set())
    index, low, stack, on, found, counter = {}, {}, [], set(), [], [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_the_graph_sees_the_package():
    edges = import_edges()
    assert ("core.mc.processor", "core.mc.estimator") in edges
    assert ("core.geometry", "core.backends.twins") in edges
    assert len(edges) > 300


def test_circles_are_found_where_they_exist():
    assert circles({("a", "b"), ("b", "c"), ("c", "a"), ("c", "d")}) == [["a", "b", "c"]]
    assert circles({("a", "b"), ("b", "c")}) == []


def test_no_import_circle_anywhere():
    assert circles(import_edges()) == []


def _empty_package(module: str) -> bool:
    """A package whose ``__init__`` imports nothing (initialising it loads nothing else)."""
    init = ROOT.joinpath(*module.split("."), "__init__.py")
    if not init.is_file():
        return False
    tree = ast.parse(init.read_text(encoding="utf-8"))
    return not any(isinstance(n, ast.Import | ast.ImportFrom) for n in ast.walk(tree))


def test_the_backends_floor_imports_only_the_ground_floor():
    upward = sorted(
        (a, b)
        for a, b in import_edges()
        if a.startswith("core.backends")
        and not any(b == m or b.startswith(m + ".") for m in BACKENDS_MAY_IMPORT)
        and not _empty_package(b)
    )
    assert upward == []


def test_the_core_never_imports_the_glue():
    upward = sorted(
        (a, b) for a, b in import_edges() if a.startswith("core") and not b.startswith("core")
    )
    assert upward == []


def test_the_render_glue_never_imports_the_operators_or_the_root():
    """The operators call ``sss_addon``; the extension's root registers both. An import
    the other way (``sss_addon`` reaching up for the operators or the root ``register``)
    would put the floors back in a loop through Blender's registration."""
    upward = sorted(
        (a, b)
        for a, b in import_edges()
        if a.startswith("sss_addon") and (b == "<root>" or b.startswith("operators"))
    )
    assert upward == []

"""The package's import graph has no cycles (docs/architecture.md: each layer depends only on the ones above it).

The graph is read from the source (the AST), not by importing: an edge ``a -> b`` for every import that runs
when ``a`` is imported (module level, ``if``/``try`` blocks and class bodies included; imports inside functions
and under ``if TYPE_CHECKING:`` excluded), ``b`` the ``stp_env`` module it names (``from p import name`` names
the submodule ``p.name`` when that file exists, else the package ``p``).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "stp_env"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE


def module_names(root: Path = ROOT, package: str = PACKAGE) -> dict[str, Path]:
    """Every module of the package by dotted name (a package is its ``__init__.py``)."""
    out = {}
    for path in sorted(root.rglob("*.py")):
        parts = (package, *path.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _load_time_imports(tree: ast.Module):
    """The import statements of ``tree`` that run when the module is imported."""
    stack = list(tree.body)
    while stack:
        node = stack.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            yield node
        elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        elif isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            stack.extend(node.orelse)
        else:
            stack.extend(ast.iter_child_nodes(node))


def import_graph(root: Path = ROOT, package: str = PACKAGE) -> dict[str, set[str]]:
    """``module -> {modules of the package it imports at load time}``."""
    modules = module_names(root, package)
    graph = {name: set() for name in modules}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        for node in _load_time_imports(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [alias.name for alias in node.names]
            else:
                if node.level:
                    base = name.split(".")
                    base = base[:len(base) - node.level + (1 if is_package else 0)]
                    stem = ".".join(base + ([node.module] if node.module else []))
                else:
                    stem = node.module or ""
                targets = [f"{stem}.{alias.name}" if f"{stem}.{alias.name}" in modules else stem
                           for alias in node.names]
            for target in targets:
                while target and target not in modules:  # ``import stp_env.a.b.name`` style: the longest module
                    target = target.rpartition(".")[0]
                if target and target != name:
                    graph[name].add(target)
    return graph


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as ``[a, b, ..., a]``, or ``None`` if it is acyclic (iterative depth-first search)."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    for start in sorted(graph):
        if state.get(start):
            continue
        path, iters = [start], [iter(sorted(graph.get(start, ())))]
        state[start] = 1
        while path:
            nxt = next(iters[-1], None)
            if nxt is None:
                state[path.pop()] = 2
                iters.pop()
            elif state.get(nxt) == 1:
                return [*path[path.index(nxt):], nxt]
            elif not state.get(nxt):
                state[nxt] = 1
                path.append(nxt)
                iters.append(iter(sorted(graph.get(nxt, ()))))
    return None


def test_the_cycle_finder_finds_a_cycle_and_only_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set(), "d": {"a", "c"}}) is None
    assert find_cycle({}) is None
    cycle = find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}})
    assert cycle is not None and cycle[0] == cycle[-1] and sorted(cycle[:-1]) == ["a", "b", "c"]
    assert find_cycle({"a": {"a"}}) == ["a", "a"]


def test_the_graph_reads_load_time_imports_only(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from pkg import a\n")
    (pkg / "a.py").write_text("import pkg.sub.b\nfrom pkg.sub import c as _c\n\ndef f():\n    from pkg import d\n")
    (pkg / "sub" / "__init__.py").write_text("from .b import name\n")
    (pkg / "sub" / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import a\n"
                                      "try:\n    from .. import d\nexcept ImportError:\n    pass\n")
    (pkg / "sub" / "c.py").write_text("from pkg.sub import name\n")
    (pkg / "d.py").write_text("from pkg.sub.c import something\n")
    graph = import_graph(pkg, "pkg")
    assert graph == {"pkg": {"pkg.a"}, "pkg.a": {"pkg.sub.b", "pkg.sub.c"}, "pkg.sub": {"pkg.sub.b"},
                     "pkg.sub.b": {"pkg.d"}, "pkg.sub.c": {"pkg.sub"}, "pkg.d": {"pkg.sub.c"}}
    # pkg.sub.c -> pkg.sub -> pkg.sub.b -> pkg.d -> pkg.sub.c
    assert find_cycle(graph) is not None
    (pkg / "sub" / "c.py").write_text("from pkg.sub.b import name\n")
    assert find_cycle(import_graph(pkg, "pkg")) is not None  # c -> b -> d -> c
    (pkg / "d.py").write_text("def f():\n    from pkg.sub.c import something\n")
    assert find_cycle(import_graph(pkg, "pkg")) is None


def test_the_package_has_no_import_cycle():
    graph = import_graph()
    assert len(graph) > 50 and sum(map(len, graph.values())) > 100  # the whole package was read
    cycle = find_cycle(graph)
    if cycle is not None:
        pytest.fail("import cycle: " + " -> ".join(cycle))


def test_the_bounds_row_is_read_by_the_names_it_is_built_with():
    """The ``(5,)`` bounds row of ``EnvParams`` is built and read in one place (:mod:`stp_env.sim.bounds`)."""
    from stp_env.dynamics import DubinsWind
    from stp_env.sim import bounds

    dyn = DubinsWind(v_min=1.5, v_max=22.0, omega_max=1.25, wind=7.0, heading_disturbance=0.125)
    row = bounds.bounds_row(dyn)
    named = {"v_min": bounds.V_MIN, "v_max": bounds.V_MAX, "omega_max": bounds.OMEGA_MAX, "wind": bounds.WIND,
             "heading_disturbance": bounds.HEADING_DISTURBANCE}
    assert sorted(named.values()) == list(range(len(bounds.COLUMNS))) == list(range(len(row)))
    for name, column in named.items():
        assert row[column] == getattr(dyn, name) and bounds.COLUMNS[column] == name

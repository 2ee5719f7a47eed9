"""The package's layering, enforced (docs/architecture.md, "Layers"): every import of every module, those inside
functions included, goes to its own layer or a lower one (:data:`LAYERS`), and the import graph has no cycle, between
modules or between packages.

The graph is read from the source (the AST), not by importing: an edge ``a -> b`` for every import statement of
``a`` (module level, ``if``/``try`` blocks, class bodies, function bodies and ``if TYPE_CHECKING:`` blocks alike),
``b`` the ``stp_env`` module it names (``from p import name`` names the submodule ``p.name`` when that file exists,
else the package ``p``). Imports made by name at run time (``importlib.import_module``: the registries loading their
own plug-in modules) are not statements and are not read.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = "stp_env"
ROOT = Path(__file__).resolve().parents[1] / PACKAGE

LAYERS: tuple[tuple[str, tuple[str, ...]], ...] = (
    # Lowest first. A module may import modules of its own layer and of the layers before it; within a layer the
    # packages import each other without a cycle. A module is in the layer of the longest prefix that names it.
    ("foundation", ("stp_env.angles", "stp_env.kinematics", "stp_env.version", "stp_env.arguments", "stp_env.seeds",
                    "stp_env.loaders", "stp_env.files", "stp_env.progress", "stp_env.compilation_cache",
                    "stp_env.cpu_threads", "stp_env.cli_kit", "stp_env.resources", "stp_env.catalog",
                    # the execution seam (jobs of pieces, in-process or on Ray): knows no simulator, so every
                    # layer's long jobs (the evaluator's batches, the falsifier's restarts) can run on it
                    "stp_env.execution")),
    ("solver", ("stp_env.hj",)),
    ("models", ("stp_env.dynamics",)),
    ("store", ("stp_env.artifacts",)),
    ("sets", ("stp_env.reach",)),
    ("core", ("stp_env.sim",)),
    ("policies", ("stp_env.policies",)),
    ("planning", ("stp_env.planning",)),
    ("scenarios", ("stp_env.scenarios",)),
    ("assembly", ("stp_env.assembly", "stp_env.params_checks", "stp_env.requirements")),
    ("adapters", ("stp_env.render", "stp_env.env", "stp_env.env_checks", "stp_env.env_infos", "stp_env.replanning",
                  "stp_env.registration", "stp_env.evaluation")),
    ("learning", ("stp_env.rl",)),
    ("attacks", ("stp_env.falsify",)),
    ("studies", ("stp_env.survivability", "stp_env.coobservation")),
    ("entry", ("stp_env.cli", "stp_env.data_tools", "stp_env")),
)

ALLOWED_UPWARD: dict[tuple[str, str], str] = {
    # (importing module or package, imported module or package): why this arrow against the layers stays. None
    # today.
}


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


def _all_imports(tree: ast.Module):
    """Every import statement of ``tree``, wherever it is."""
    return (node for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom)))


def import_edges(root: Path = ROOT, package: str = PACKAGE, *, load_time_only: bool = False
                 ) -> dict[str, dict[str, int]]:
    """``module -> {module of the package it imports: the line of the first such import}`` (every import, or with
    ``load_time_only`` those that run when the module is imported)."""
    modules = module_names(root, package)
    edges: dict[str, dict[str, int]] = {name: {} for name in modules}
    for name, path in modules.items():
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(), str(path))
        for node in sorted(_load_time_imports(tree) if load_time_only else _all_imports(tree),
                           key=lambda n: n.lineno):
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
                    edges[name].setdefault(target, node.lineno)
    return edges


def import_graph(root: Path = ROOT, package: str = PACKAGE, *, load_time_only: bool = False) -> dict[str, set[str]]:
    """``module -> {modules of the package it imports}`` (:func:`import_edges`)."""
    return {name: set(targets) for name, targets in import_edges(root, package,
                                                                  load_time_only=load_time_only).items()}


def _longest_prefix(module: str, prefixes) -> str | None:
    """The longest of ``prefixes`` that is ``module`` or a package holding it (the top package, a name without a
    dot, names only itself: a module of it that no other prefix names is in no layer)."""
    hits = [p for p in prefixes if module == p or ("." in p and module.startswith(p + "."))]
    return max(hits, key=len) if hits else None


def layer_of(module: str, layers=LAYERS) -> int | None:
    """The index in ``layers`` of ``module``'s layer (``None`` when no prefix names it)."""
    prefix = _longest_prefix(module, [p for _, prefixes in layers for p in prefixes])
    return None if prefix is None else next(i for i, (_, prefixes) in enumerate(layers) if prefix in prefixes)


def unit_of(module: str, layers=LAYERS) -> str:
    """The layer entry (a package or a module of :data:`LAYERS`) that holds ``module``."""
    return _longest_prefix(module, [p for _, prefixes in layers for p in prefixes]) or module


def allowed_entry(module: str, target: str, allowed=ALLOWED_UPWARD) -> tuple[str, str] | None:
    """The entry of ``allowed`` that covers the import ``module -> target`` (``None`` if none does)."""
    return next((key for key in allowed if _longest_prefix(module, [key[0]]) and _longest_prefix(target, [key[1]])),
                None)


def without_allowed(graph: dict[str, set[str]], allowed=ALLOWED_UPWARD) -> dict[str, set[str]]:
    """``graph`` less the imports that ``allowed`` lets go up the layers (they are lazy aliases, resolved on use, so
    they close no cycle at import)."""
    return {module: {t for t in targets if allowed_entry(module, t, allowed) is None}
            for module, targets in graph.items()}


def layer_violations(edges: dict[str, dict[str, int]], layers=LAYERS, allowed=ALLOWED_UPWARD,
                     used: set | None = None) -> list[str]:
    """Every import that goes up the layers and is not in ``allowed`` (``"a:line -> b (layer x above y)"``), and
    every module that no layer names; ``used`` collects the ``allowed`` entries that served."""
    out = []
    for module in sorted(edges):
        mine = layer_of(module, layers)
        if mine is None:
            out.append(f"{module} is in no layer: add it to LAYERS")
            continue
        for target, line in sorted(edges[module].items()):
            theirs = layer_of(target, layers)
            if theirs is None or theirs <= mine:
                continue
            entry = allowed_entry(module, target, allowed)
            if entry is not None:
                if used is not None:
                    used.add(entry)
                continue
            out.append(f"{module}:{line} -> {target} (layer {layers[theirs][0]!r} is above {layers[mine][0]!r})")
    return out


def unit_graph(graph: dict[str, set[str]], layers=LAYERS) -> dict[str, set[str]]:
    """The graph between the entries of ``layers`` (packages and top-level modules)."""
    out: dict[str, set[str]] = {}
    for module, targets in graph.items():
        a = unit_of(module, layers)
        out.setdefault(a, set()).update(b for b in map(lambda t: unit_of(t, layers), targets) if b != a)
    return out


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


def _planted_package(tmp_path) -> Path:
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text("from pkg import a\n")
    (pkg / "a.py").write_text("import pkg.sub.b\nfrom pkg.sub import c as _c\n\ndef f():\n    from pkg import d\n")
    (pkg / "sub" / "__init__.py").write_text("from .b import name\n")
    (pkg / "sub" / "b.py").write_text("from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg import a\n"
                                      "try:\n    from .. import d\nexcept ImportError:\n    pass\n")
    (pkg / "sub" / "c.py").write_text("from pkg.sub import name\n")
    (pkg / "d.py").write_text("from pkg.sub.c import something\n")
    return pkg


def test_the_graph_reads_load_time_imports_apart(tmp_path):
    pkg = _planted_package(tmp_path)
    graph = import_graph(pkg, "pkg", load_time_only=True)
    assert graph == {"pkg": {"pkg.a"}, "pkg.a": {"pkg.sub.b", "pkg.sub.c"}, "pkg.sub": {"pkg.sub.b"},
                     "pkg.sub.b": {"pkg.d"}, "pkg.sub.c": {"pkg.sub"}, "pkg.d": {"pkg.sub.c"}}
    # pkg.sub.c -> pkg.sub -> pkg.sub.b -> pkg.d -> pkg.sub.c
    assert find_cycle(graph) is not None
    (pkg / "sub" / "c.py").write_text("from pkg.sub.b import name\n")
    assert find_cycle(import_graph(pkg, "pkg", load_time_only=True)) is not None  # c -> b -> d -> c
    (pkg / "d.py").write_text("def f():\n    from pkg.sub.c import something\n")
    assert find_cycle(import_graph(pkg, "pkg", load_time_only=True)) is None
    assert find_cycle(import_graph(pkg, "pkg")) is not None  # the import inside the function closes it


def test_the_graph_reads_every_import(tmp_path):
    pkg = _planted_package(tmp_path)
    edges = import_edges(pkg, "pkg")
    assert {name: set(targets) for name, targets in edges.items()} == {
        "pkg": {"pkg.a"}, "pkg.a": {"pkg.sub.b", "pkg.sub.c", "pkg.d"}, "pkg.sub": {"pkg.sub.b"},
        "pkg.sub.b": {"pkg.a", "pkg.d"}, "pkg.sub.c": {"pkg.sub"}, "pkg.d": {"pkg.sub.c"}}
    assert edges["pkg.a"]["pkg.d"] == 5 and edges["pkg.sub.b"]["pkg.a"] == 3  # the line of the import


def test_the_layer_check_finds_an_upward_import_and_honours_the_allow_list(tmp_path):
    pkg = tmp_path / "pkg"
    (pkg / "low").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "low" / "__init__.py").write_text("")
    (pkg / "low" / "x.py").write_text("import math\n")
    (pkg / "high.py").write_text("from pkg.low import x\n")
    layers = (("low", ("pkg.low",)), ("high", ("pkg.high", "pkg")))
    assert layer_violations(import_edges(pkg, "pkg"), layers, {}) == []
    (pkg / "low" / "x.py").write_text("import math\n\n\ndef f():\n    from pkg import high\n")  # planted
    edges = import_edges(pkg, "pkg")
    assert layer_violations(edges, layers, {}) == [
        "pkg.low.x:5 -> pkg.high (layer 'high' is above 'low')"]
    used = set()
    assert layer_violations(edges, layers, {("pkg.low", "pkg.high"): "a reason"}, used) == []
    assert used == {("pkg.low", "pkg.high")}
    (pkg / "stray.py").write_text("")  # the top package's entry names only itself
    assert layer_violations(import_edges(pkg, "pkg"), layers, {("pkg.low", "pkg.high"): "a reason"}) == [
        "pkg.stray is in no layer: add it to LAYERS"]
    assert find_cycle(unit_graph(import_graph(pkg, "pkg"), layers)) is not None  # low.x -> high -> low.x
    (pkg / "low" / "x.py").write_text("import math\n")
    assert find_cycle(unit_graph(import_graph(pkg, "pkg"), layers)) is None
    (pkg / "low" / "__init__.py").write_text("from pkg.high import y\n")  # low -> high -> low.x, packages
    assert find_cycle(import_graph(pkg, "pkg")) is None
    assert find_cycle(unit_graph(import_graph(pkg, "pkg"), layers)) is not None


def test_the_package_has_no_import_cycle():
    graph = without_allowed(import_graph())
    assert len(graph) > 50 and sum(map(len, graph.values())) > 100  # the whole package was read
    cycle = find_cycle(graph)
    if cycle is not None:
        pytest.fail("import cycle: " + " -> ".join(cycle))


def test_the_packages_have_no_import_cycle():
    """Between the entries of :data:`LAYERS` (``sim``, ``planning``, ``evaluation``, ``rl``, ...), imports inside
    functions included: two packages that import each other are one."""
    cycle = find_cycle(unit_graph(without_allowed(import_graph())))
    if cycle is not None:
        pytest.fail("import cycle between packages: " + " -> ".join(cycle))


def test_every_import_follows_the_layers():
    used: set = set()
    violations = layer_violations(import_edges(), used=used)
    if violations:
        pytest.fail("imports against the layers of docs/architecture.md (tests/test_architecture.py: LAYERS, "
                    "ALLOWED_UPWARD):\n" + "\n".join(violations))
    assert used == set(ALLOWED_UPWARD), f"allow-list entries no import needs: {set(ALLOWED_UPWARD) - used}"


SCANS: dict[str, str] = {
    # Every module with a ``lax.scan``, and why. One loop over the simulator's step: the episode engine.
    "stp_env.sim.engine": "the episode engine: the one loop over the steps of an episode (every rollout, the "
                          "evaluator, the worst-case reproductions, the falsifier's attacks, the co-observation "
                          "threat and its learned attacker run on it)",
    "stp_env.sim.core": "the inner control steps inside one step of the core",
    "stp_env.reach.closed_loop": "the avoid game in closed loop on exact Dubins motion (certification), no core",
    "stp_env.planning.single": "the planner's extraction of a trajectory from the HJ model, no core",
    "stp_env.planning.obstacles": "nearest moving disks, a reduction over disks",
    "stp_env.falsify.harness": "a legal reference of exact Dubins motion (kinematics.dubins_step), no core",
    "stp_env.survivability.dense": "the dynamic programme over the mission's time windows",
    "stp_env.coobservation.exploration": "the exploration flows' positions over their waypoints, no core",
    "stp_env.rl.jax_ppo": "PPO's rollout over any gymnax environment's batched step (the envs reset themselves: no "
                          "episode to stop), its GAE, its epochs and minibatches",
}


def scan_sites(root: Path = ROOT, package: str = PACKAGE) -> dict[str, list[int]]:
    """``module -> [lines]`` of every call of ``lax.scan`` (``jax.lax.scan``, ``lax.scan`` or a ``scan`` imported
    from ``jax.lax``)."""
    out: dict[str, list[int]] = {}
    for name, path in module_names(root, package).items():
        tree = ast.parse(path.read_text(), str(path))
        bare = any(isinstance(n, ast.ImportFrom) and n.module == "jax.lax" and any(a.name == "scan" for a in n.names)
                   for n in ast.walk(tree))
        for node in ast.walk(tree):
            if isinstance(node, ast.Call):
                func = ast.unparse(node.func)
                if func.endswith("lax.scan") or (bare and func == "scan"):
                    out.setdefault(name, []).append(node.lineno)
    return out


def test_the_scan_finder_finds_every_spelling(tmp_path):
    pkg = tmp_path / "pkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "a.py").write_text("import jax\n\ndef f(b, c, x):\n    return jax.lax.scan(b, c, x)\n")
    (pkg / "b.py").write_text("from jax import lax\n\ndef f(b, c, x):\n    return lax.scan(b, c, x)\n")
    (pkg / "c.py").write_text("from jax.lax import scan\n\ndef f(b, c, x):\n    return scan(b, c, x)\n")
    (pkg / "d.py").write_text("def scan(x):\n    return x\n\ndef f(x):\n    return scan(x)\n")  # not JAX's
    assert scan_sites(pkg, "pkg") == {"pkg.a": [4], "pkg.b": [4], "pkg.c": [4]}


@pytest.mark.slow
def test_one_scan_runs_the_episodes():
    """Every loop over the core's step is :mod:`stp_env.sim.engine`'s (docs/architecture.md): a new ``lax.scan``
    fails here until it is classified in :data:`SCANS` (a loop over the core's step belongs on the engine)."""
    sites = scan_sites()
    unclassified = {m: lines for m, lines in sites.items() if m not in SCANS}
    assert not unclassified, (f"lax.scan outside the episode engine (stp_env/sim/engine.py): {unclassified}; build "
                              "a loop over the core's step on stp_env.sim.engine, or classify the scan in SCANS")
    assert set(SCANS) <= set(sites), f"SCANS entries without a scan: {set(SCANS) - set(sites)}"
    assert len(sites["stp_env.sim.engine"]) == 1


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

"""The benchmarks and examples use only names the package has: every ``from stp_env... import name`` and every
``module.attribute`` read through a name bound to an ``stp_env`` module resolves, without a deprecation warning.

Benchmarks and examples are not run by the suite (they are full-size measurements), so a refactor that renames or
moves something they use would otherwise only be noticed by the next person who runs them. Checked statically
(the files are parsed, never executed); the package's modules are imported, which computes nothing."""

from __future__ import annotations

import ast
import importlib
import warnings
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
FILES = sorted([*(ROOT / "benchmarks").glob("*.py"), *(ROOT / "examples").glob("*.py")])
# (the data-maintenance scripts that were beside them are ``stp-env data`` subcommands: stp_env/data_tools)


def _module(name: str):
    try:
        return importlib.import_module(name)
    except ImportError:
        return None


def _resolve(module, attr: str) -> bool:
    """Whether ``module.attr`` exists (an attribute, or a submodule not yet imported) without a deprecation."""
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)
        try:
            getattr(module, attr)
            return True
        except AttributeError:
            return _module(f"{module.__name__}.{attr}") is not None
        except DeprecationWarning:
            return False


def missing_names(path: Path) -> list[str]:
    """The ``stp_env`` names ``path`` uses that do not resolve (``module.name (line N)``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    aliases: dict[str, object] = {}  # a local name bound to an stp_env module
    missing = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.startswith("stp_env"):
                    module = _module(alias.name)
                    if module is None:
                        missing.append(f"{alias.name} (line {node.lineno})")
                    elif alias.asname:
                        aliases[alias.asname] = module
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("stp_env"):
            module = _module(node.module)
            if module is None:
                missing.append(f"{node.module} (line {node.lineno})")
                continue
            for alias in node.names:
                if alias.name == "*":
                    continue
                if not _resolve(module, alias.name):
                    missing.append(f"{node.module}.{alias.name} (line {node.lineno})")
                    continue
                value = getattr(module, alias.name, None) or _module(f"{node.module}.{alias.name}")
                if isinstance(value, type(importlib)):
                    aliases[alias.asname or alias.name] = value
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load) and isinstance(node.value, ast.Name)
                and node.value.id in aliases):
            module = aliases[node.value.id]
            if not _resolve(module, node.attr):
                missing.append(f"{module.__name__}.{node.attr} (line {node.lineno})")
    return missing


@pytest.mark.parametrize("path", FILES, ids=[str(p.relative_to(ROOT)) for p in FILES])
def test_benchmarks_and_examples_use_names_the_package_has(path):
    assert not missing_names(path), f"{path.relative_to(ROOT)} uses names stp_env does not have (or deprecated ones)"


def test_the_check_finds_a_removed_name(tmp_path):
    stale = tmp_path / "stale.py"
    stale.write_text("import stp_env.env as env_module\nfrom stp_env.sim import core, gone_name\n"
                     "from stp_env import sim\n"
                     "step = env_module._no_such_helper\ncore._no_such_either\nsim.load_artifacts\n"
                     "env_module.parallel_env\n", encoding="utf-8")
    found = missing_names(stale)
    assert found == ["stp_env.sim.gone_name (line 2)", "stp_env.env._no_such_helper (line 4)",
                     "stp_env.sim.core._no_such_either (line 5)", "stp_env.sim.load_artifacts (line 6)"]

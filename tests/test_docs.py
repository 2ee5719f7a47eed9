"""The documentation runs: every Python code block of README.md, of the guides in docs/ and of the package's
docstrings (``::`` literal blocks) is executed, on a small scenario where the documented one would be slow (each
substitution below must still match its block, so a changed block is noticed); every ``stp-env`` command in the
README's shell blocks parses; every paper the package names is in docs/references.md; the README stays an entry
point."""

from __future__ import annotations

import ast
import importlib
import re
import shlex
import textwrap
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "stp_env"

# (file, text in the block) -> [(old, new), ...]: what makes a documented block small enough for the suite.
SMALL = {
    "parallel_env()": [("parallel_env()", 'parallel_env("tiny-intruder")')],
    'TrainConfig(scenario="town", kbar=2, total_timesteps=200_000, out_dir="runs/intruder")': [
        ('TrainConfig(scenario="town", kbar=2, total_timesteps=200_000, out_dir="runs/intruder")',
         'TrainConfig(scenario="tiny-intruder", total_timesteps=64, n_envs=4, n_steps=16, batch_size=64, '
         'eval_every=0, eval_episodes=2, checkpoint_every=0, out_dir=str(OUT / "intruder"))')],
    'gymnasium.make("stp_env/Intruder-v0", scenario="town")': [
        ('gymnasium.make("stp_env/Intruder-v0", scenario="town")',
         'gymnasium.make("stp_env/Intruder-v0", scenario="tiny-intruder")')],
    'assembly.params_for("town", sim.EnvConfig(spawn_mode="boundary"))': [
        ('assembly.params_for("town"', 'assembly.params_for("tiny-intruder"'), ("n_envs=1000", "n_envs=4")],
    "SearchConfig(budget=10_000)": [("SearchConfig(budget=10_000)", "SearchConfig(budget=64)")],
    # docs/training.md, "Multi-agent clients" (tests/test_clients.py runs each route at length)
    "parallel_api_test(parallel_env(\"town\"), num_cycles=1000)": [("num_cycles=1000", "num_cycles=100")],
    "model.learn(total_timesteps=200_000)": [("total_timesteps=200_000", "total_timesteps=1536")],
    "PettingZooWrapper(env=parallel_env(": [("max_cycles=300", "max_cycles=20"), ("max_steps=1000", "max_steps=50")],
    "register_env(\"stp\"": [("train_batch_size=4000", "train_batch_size=400, minibatch_size=200, num_epochs=1"),
                             ("range(10)", "range(1)")],
    '(61, 61, 60)': [("(61, 61, 60)", "(21, 21, 20)"), ('with_accuracy("very_high")', 'with_accuracy("low")')],
}

# blocks that need a client outside the dev extra: skipped without it (ray[rllib] pins gymnasium==1.2.2)
OPTIONAL_CLIENTS = {
    "from ray.rllib": ("ray.rllib.algorithms.ppo", "RLlib's dependencies are not installed: pip install 'ray[rllib]'"),
}

NOT_PYTHON = {
    # literal blocks that are formulas, not code
    ("stp_env/coobservation/admm.py", "q^{k+1} = argmin_q Phi(q) + rho/2 ||D(q) - z^k + u^k||^2"),
}


def _fenced(path: Path, language: str) -> list[tuple[str, int, str]]:
    blocks, lines = [], path.read_text(encoding="utf-8").splitlines()
    i = 0
    while i < len(lines):
        if lines[i].strip() == f"```{language}":
            start = i + 1
            j = start
            while lines[j].strip() != "```":
                j += 1
            blocks.append((str(path.relative_to(ROOT)), start + 1, "\n".join(lines[start:j]) + "\n"))
            i = j
        i += 1
    return blocks


def _docstring_blocks() -> list[tuple[str, int, str]]:
    """The ``::`` literal blocks of every module docstring of the package."""
    blocks = []
    for path in sorted(PACKAGE.rglob("*.py")):
        doc = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8")), clean=False)
        if not doc:
            continue
        lines = doc.splitlines()
        for i, line in enumerate(lines):
            if not line.rstrip().endswith("::"):
                continue
            j = i + 1
            while j < len(lines) and not lines[j].strip():
                j += 1
            body = []
            while j < len(lines) and (not lines[j].strip() or lines[j].startswith((" ", "\t"))):
                body.append(lines[j])
                j += 1
            text = textwrap.dedent("\n".join(body)).strip("\n") + "\n"
            blocks.append((str(path.relative_to(ROOT)), i + 2, text))
    return blocks


CHECKED_ELSEWHERE = {
    # plug-in examples that register a wind model, an intruder and a scenario: tests/test_extension_points.py
    # writes them as modules and checks them, without registering them in this process's registries
    "docs/architecture.md",
}
PYTHON_BLOCKS = ([b for b in _fenced(ROOT / "README.md", "python")]
                 + [b for doc in sorted((ROOT / "docs").glob("*.md")) for b in _fenced(doc, "python")
                    if str(doc.relative_to(ROOT)) not in CHECKED_ELSEWHERE]
                 + _docstring_blocks())


def _small(text: str) -> str:
    for key, substitutions in SMALL.items():
        if key in text:
            for old, new in substitutions:
                assert old in text, f"the substitution {old!r} no longer matches its block"
                text = text.replace(old, new)
    return text


def _module_globals(file: str) -> dict:
    """A docstring's block runs in its module's namespace (the names it documents, as doctest does)."""
    if not file.startswith("stp_env/"):
        return {}
    name = file[:-3].replace("/", ".").removesuffix(".__init__")
    module = importlib.import_module(name)
    return {**vars(module), **{n: getattr(module, n) for n in getattr(module, "__all__", ())}}  # lazy exports too


def test_there_are_blocks_to_run():
    files = {f for f, _, _ in PYTHON_BLOCKS}
    assert {"README.md", "stp_env/env.py", "stp_env/coobservation/env.py"} <= files


@pytest.mark.parametrize(("file", "line", "text"), PYTHON_BLOCKS, ids=[f"{f}:{n}" for f, n, _ in PYTHON_BLOCKS])
def test_code_block_runs(file, line, text, tmp_path, monkeypatch):
    try:
        ast.parse(text)
    except SyntaxError:
        assert any(file == f and marker in text for f, marker in NOT_PYTHON), (
            f"{file}:{line} is a literal block that is not Python; list it in NOT_PYTHON if it is meant as prose")
        return
    for marker, (module, reason) in OPTIONAL_CLIENTS.items():
        if marker in text:
            pytest.importorskip(module, reason=reason)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("STP_ENV_PROGRESS", "0")
    code = _small(text)
    namespace = {**_module_globals(file), "__name__": "__docs__", "OUT": tmp_path}
    exec(compile(code, f"{file}:{line}", "exec"), namespace)


def _stp_env_commands(path: Path) -> list[list[str]]:
    commands = []
    for _, _, block in _fenced(path, "bash"):
        for line in block.splitlines():
            for part in re.split(r"&&|;", line.split("#")[0]):
                words = shlex.split(part)
                if words[:1] == ["stp-env"]:
                    commands.append(words[1:])
    return commands


def test_the_readmes_commands_parse():
    from stp_env.cli import _build_parser

    commands = _stp_env_commands(ROOT / "README.md")
    assert len(commands) >= 4
    parser = _build_parser()
    for argv in commands:
        parser.parse_args(argv)  # SystemExit on an unknown command or option


def test_the_readme_is_an_entry_point():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 150
    for link in re.findall(r"\]\((docs/[^)#]+)\)", text):
        assert (ROOT / link).is_file(), link


def _reference_names() -> set[str]:
    text = (ROOT / "docs" / "references.md").read_text(encoding="utf-8")
    names = set(re.findall(r"\bthe ([\w-]+) papers?\b", text, flags=re.IGNORECASE))
    return {n.lower() for n in names}


def test_every_paper_the_package_names_is_referenced():
    names = _reference_names()
    assert {"spp", "intruder", "beacls", "survivability", "co-observation"} <= names
    unknown = {}
    for path in [*PACKAGE.rglob("*.py"), *(ROOT / "examples").glob("*.py"), *(ROOT / "benchmarks").glob("*.py")]:
        for name in re.findall(r"\bthe ([\w-]+) papers?\b", path.read_text(encoding="utf-8"), flags=re.IGNORECASE):
            if name.lower() not in names:
                unknown.setdefault(name, []).append(str(path.relative_to(ROOT)))
    assert not unknown, f"papers named in the package but not in docs/references.md: {unknown}"

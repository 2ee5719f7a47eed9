"""What the README's test command leaves to the slow tests: its share of the suite's time, and what every module
of the package keeps covered without it.

The README's test command runs every test but those marked ``slow`` (``-m "not slow"``); CI runs that command
only, and the ``slow`` ones are run by hand (docs/development.md). This reads one whole-suite run, made with
per-test coverage and a JUnit report:

    STP_ENV_CACHE_DIR=$(mktemp -d) python -m pytest -q -n 2 --dist loadfile --junitxml=suite.xml \\
        --cov=stp_env --cov-context=test --cov-report=

(``pip install pytest-cov``; the empty cache directory is what a clean CI machine sees), collects which tests are
marked ``slow`` today (``pytest --collect-only -m slow``), and prints one JSON line: the worker-seconds of the whole
suite, of the tests the README command runs, and their ratio (the peer: the same run's whole suite); the lines of
the package covered by the whole suite and by the README command; and every module whose covered lines the README
command alone does not reach (``--show N`` lists the N largest gaps on stderr). A module covered by the whole
suite but not at all by the README command is named in ``uncovered_modules``: the split should leave none.

    python benchmarks/suite_split.py suite.xml .coverage [--show 20]

``--threshold S`` answers "what if": the tests that took longer than S seconds in that run are counted as slow
instead of today's markers.
"""

from __future__ import annotations

import argparse
import collections
import json
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def junit_times(path: Path) -> dict[str, float]:
    """Node id (``tests/test_x.py::test_y[p]``) -> the test's time in the JUnit report (setup, call and teardown)."""
    times: dict[str, float] = {}
    for case in ET.parse(path).getroot().iter("testcase"):
        module = case.get("classname", "")
        file = module.replace(".", "/")
        # a test in a class: classname is tests.test_x.TestY
        parts = file.split("/")
        if parts and parts[-1][:1].isupper():
            node = "/".join(parts[:-1]) + ".py::" + parts[-1] + "::" + case.get("name", "")
        else:
            node = file + ".py::" + case.get("name", "")
        times[node] = times.get(node, 0.0) + float(case.get("time", 0.0))
    return times


def marked_slow() -> set[str]:
    """The node ids ``pytest --collect-only -m slow`` collects today."""
    out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-m", "slow",
                          "-p", "no:cacheprovider",
                          "-o", "addopts="], cwd=ROOT, capture_output=True, text=True, check=False)
    return {line.strip() for line in out.stdout.splitlines() if "::" in line}


def covered_lines(data_file: Path, slow: set[str]):
    """Per measured file: (statements, lines any test ran, lines a test outside ``slow`` ran)."""
    import coverage

    cov = coverage.Coverage(data_file=str(data_file))
    cov.load()
    data = cov.get_data()
    result = {}
    for filename in sorted(data.measured_files()):
        try:
            statements = set(cov.analysis2(filename)[1])
        except Exception:  # a file that is gone or cannot be parsed: counted by what ran
            statements = None
        every, fast = set(), set()
        for line, contexts in data.contexts_by_lineno(filename).items():
            if statements is not None and line not in statements:
                continue
            for context in contexts:
                node = context.rsplit("|", 1)[0]
                every.add(line)
                # the empty context is what ran outside a test: importing the package while collecting, which
                # both commands do (a deselected test's module is still imported)
                if not node or node not in slow:
                    fast.add(line)
                    break
        result[filename] = (len(statements) if statements is not None else len(every), every, fast)
    return result


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("junit", type=Path, help="the run's --junitxml report")
    parser.add_argument("coverage", type=Path, help="the run's coverage data file (with --cov-context=test)")
    parser.add_argument("--threshold", type=float, default=None,
                        help="count the tests longer than this many seconds as slow instead of today's markers")
    parser.add_argument("--show", type=int, default=15, help="list this many modules with the largest gaps")
    args = parser.parse_args(argv)
    for path in (args.junit, args.coverage):
        if not path.is_file():
            parser.error(f"{path}: no such file")
    times = junit_times(args.junit)
    if args.threshold is not None:
        slow = {node for node, t in times.items() if t > args.threshold}
    else:
        slow = marked_slow()
    total = sum(times.values())
    fast_time = sum(t for node, t in times.items() if node not in slow)
    per_file = covered_lines(args.coverage, slow)
    gaps = []
    uncovered = []
    statements = every_n = fast_n = 0
    for filename, (n, every, fast) in per_file.items():
        statements += n
        every_n += len(every)
        fast_n += len(fast)
        name = "stp_env/" + filename.split("/stp_env/", 1)[1] if "/stp_env/" in filename else filename
        if every and not fast:
            uncovered.append(name)
        if len(every) > len(fast):
            gaps.append((len(every) - len(fast), name, n, len(every), len(fast)))
    gaps.sort(reverse=True)
    for lost, name, n, every, fast in gaps[: args.show]:
        print(f"{name}: {every}/{n} lines covered by the suite, {fast} by the README command ({lost} only by slow)",
              file=sys.stderr)
    by_file = collections.Counter()
    for node, t in times.items():
        if node in slow:
            by_file[node.split("::")[0]] += t
    print(json.dumps({
        "benchmark": "suite_split",
        "tests": len(times),
        "slow_tests": sum(1 for node in times if node in slow),
        "suite_worker_s": round(total, 1),
        "readme_command_worker_s": round(fast_time, 1),
        "readme_over_suite": round(fast_time / total, 3) if total else None,
        "statements": statements,
        "covered_by_suite": every_n,
        "covered_by_readme_command": fast_n,
        "modules_with_gaps": len(gaps),
        "uncovered_modules": uncovered,
        "slow_worker_s_by_file": {k: round(v, 1) for k, v in by_file.most_common(10)},
    }))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Where the test suite's time goes: JAX tracing, lowering and XLA compilation against the rest, per test and file.

A pytest plugin and its summary. Run the suite with the plugin (each xdist worker appends its tests to the file):

    PYTHONPATH=benchmarks SUITE_PROFILE_OUT=profile.jsonl \
        python -m pytest -q -n 2 --dist loadfile -p suite_compile_share

then summarise (one JSON line; the peer of the compile time is the tests' own wall time in the same run):

    python benchmarks/suite_compile_share.py profile.jsonl [--top 15]

The durations come from ``jax.monitoring`` (the events JAX records for every trace, lowering and backend compile),
summed over each test's setup, call and teardown; ``wall`` is the test's whole run protocol. A compile that runs in
a background thread of another test would be charged to the test running then (JAX compiles on the calling thread).
"""

from __future__ import annotations

import argparse
import collections
import json
import os
import sys
import time

COMPILE = "/jax/core/compile/backend_compile_duration"
TRACE = "/jax/core/compile/jaxpr_trace_duration"
LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"

_current: list = [None]
_sums: dict = collections.defaultdict(collections.Counter)


def _listener(event: str, duration: float, **_) -> None:
    if _current[0] is not None and event in (COMPILE, TRACE, LOWER):
        _sums[_current[0]][event] += duration


def pytest_configure(config):
    import jax.monitoring

    jax.monitoring.register_event_duration_secs_listener(_listener)


def pytest_runtest_protocol(item, nextitem):
    # a plain hook returning None: pytest runs the default protocol after it; the timing is in the two below
    _current[0] = item.nodeid
    _sums[item.nodeid]["_start"] = time.perf_counter()


def pytest_runtest_logfinish(nodeid, location):
    counter = _sums.get(nodeid)
    if counter is not None and "_start" in counter:
        counter["wall"] += time.perf_counter() - counter.pop("_start")
    _current[0] = None


def pytest_sessionfinish(session):
    if not _sums:
        return
    out = os.environ.get("SUITE_PROFILE_OUT", "suite_profile.jsonl")
    lines = "".join(json.dumps({"test": k, **{e: round(v, 4) for e, v in c.items() if not e.startswith("_")}}) + "\n"
                    for k, c in _sums.items())
    with open(out, "a", encoding="utf-8") as f:  # one write per worker
        f.write(lines)


def summarize(rows: list[dict], top: int = 15) -> dict:
    files = collections.defaultdict(collections.Counter)
    for r in rows:
        f = r["test"].split("::")[0]
        files[f]["wall"] += r.get("wall", 0.0)
        files[f]["compile"] += r.get(COMPILE, 0.0)
        files[f]["trace_lower"] += r.get(TRACE, 0.0) + r.get(LOWER, 0.0)
    wall = sum(c["wall"] for c in files.values())
    comp = sum(c["compile"] for c in files.values())
    tl = sum(c["trace_lower"] for c in files.values())
    ranked = sorted(files.items(), key=lambda kv: -kv[1]["wall"])[:top]
    return {"case": "suite_compile_share", "tests": len(rows), "worker_s": round(wall, 1),
            "xla_compile_s": round(comp, 1), "trace_lower_s": round(tl, 1),
            "compile_share": round(comp / wall, 3) if wall else None,
            "jax_share": round((comp + tl) / wall, 3) if wall else None,
            "files": [{"file": f, "worker_s": round(c["wall"], 1),
                       "compile_share": round(c["compile"] / c["wall"], 2) if c["wall"] else None}
                      for f, c in ranked]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("profile", help="the JSON-lines file the plugin wrote")
    ap.add_argument("--top", type=int, default=15, help="files listed, longest first")
    args = ap.parse_args(argv)
    with open(args.profile, encoding="utf-8") as f:
        rows = [json.loads(line) for line in f if line.strip()]
    if not rows:
        print(f"{args.profile}: no tests recorded", file=sys.stderr)
        return 1
    print(json.dumps(summarize(rows, args.top)))
    return 0


if __name__ == "__main__":
    sys.exit(main())

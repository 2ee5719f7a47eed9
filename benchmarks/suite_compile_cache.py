"""The test suite with JAX's persistent compilation cache (stp_env/compilation_cache.py) against the same tests
without it, in the same run: test files under the README's runner (``-n 2 --dist loadfile``), three times: the
cache off (``STP_ENV_COMPILATION_CACHE=0``: every worker compiles every program it meets), on in an empty folder
(``cold``: the workers share what they compile within the run, as on a clean CI machine), and on again in that
folder (``warm``: a rerun on the same machine).

    python benchmarks/suite_compile_cache.py tests/test_fleet.py tests/test_falsify.py [--artifacts DIR]
    python benchmarks/suite_compile_cache.py tests/test_env.py tests/test_sim.py --crowded 3000

With ``--crowded N`` two more runs start from a folder that already holds N entries (small dummy programs, dated as
JAX dates them), as the shared folder does half-way through a suite run: one with the package's size limit (JAX
locks the folder and, before each write, reads the size and access date of every entry), one with JAX's own ``-1``
(no limit: no lock, no reading of the folder). Their ratio is the price of that reading at N entries.

The reachability artifacts come from ``--artifacts`` (default: the usual artifact cache), computed before the timed
runs by an untimed run with the cache off, so that no timed run computes one. Prints one JSON line: per run the
wall seconds, the CPU seconds of pytest and its workers (user + system), the seconds JAX spent compiling or loading
programs (``jax.monitoring``'s backend-compile events, summed over the workers by
``benchmarks/suite_compile_share.py``), the pytest outcome, and the ratios off / cold and off / warm.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))

from suite_compile_share import summarize  # noqa: E402


def run(files: list[str], env: dict, profile: Path) -> dict:
    env = {**env, "PYTHONPATH": os.pathsep.join([str(ROOT / "benchmarks"), str(ROOT)]),
           "SUITE_PROFILE_OUT": str(profile)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    out = subprocess.run([sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadfile", "-p",
                          "suite_compile_share", "-p", "no:cacheprovider", *files], cwd=ROOT, env=env,
                         capture_output=True, text=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    rows = [json.loads(line) for line in profile.read_text().splitlines() if line.strip()] if profile.exists() else []
    summary = summarize(rows) if rows else {"xla_compile_s": None, "trace_lower_s": None}
    lines = [x for x in out.stdout.strip().splitlines() if x.strip()]
    return {"wall_s": round(wall, 1), "cpu_s": round(cpu, 1), "compile_or_load_s": summary["xla_compile_s"],
            "trace_lower_s": summary["trace_lower_s"],
            "result": lines[-1] if lines else out.stderr[-300:]}


def crowd(folder: Path, n: int, dated: bool) -> None:
    """``n`` dummy entries of 2 kB in ``folder`` (with JAX's access-date files when ``dated``)."""
    folder.mkdir(parents=True)
    now = time.time_ns().to_bytes(8, "little")
    for i in range(n):
        (folder / f"crowd{i:06d}-cache").write_bytes(b"x" * 2000)
        if dated:
            (folder / f"crowd{i:06d}-atime").write_bytes(now)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+")
    parser.add_argument("--artifacts", default=None, help="artifact cache directory (default: the usual one)")
    parser.add_argument("--crowded", type=int, default=0, metavar="N",
                        help="also run from a folder holding N entries, with the size limit and without one")
    args = parser.parse_args()
    base = {k: v for k, v in os.environ.items()
            if not k.startswith(("JAX_COMPILATION_CACHE", "JAX_PERSISTENT", "STP_ENV_COMPILATION"))}
    if args.artifacts:
        base["STP_ENV_CACHE_DIR"] = args.artifacts
    off = {**base, "STP_ENV_COMPILATION_CACHE": "0"}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        run(args.files, off, tmp / "warmup.jsonl")  # artifacts, untimed
        load = round(os.getloadavg()[0], 2)
        on = {**base, "STP_ENV_COMPILATION_CACHE_DIR": str(tmp / "xla")}
        results = {"off": run(args.files, off, tmp / "off.jsonl"),
                   "cold": run(args.files, on, tmp / "cold.jsonl"),
                   "warm": run(args.files, on, tmp / "warm.jsonl")}
        size = sum(p.stat().st_size for p in (tmp / "xla").rglob("*") if p.is_file())
        if args.crowded:
            for name, limits in (("crowded_limit", {}),
                                 ("crowded_no_limit", {"STP_ENV_COMPILATION_CACHE_MAX_GB": "",
                                                       "JAX_COMPILATION_CACHE_MAX_SIZE": "-1"})):
                folder = tmp / name
                crowd(folder, args.crowded, dated=not limits)
                results[name] = run(args.files, {**on, "STP_ENV_COMPILATION_CACHE_DIR": str(folder), **limits},
                                    tmp / f"{name}.jsonl")
            results["crowded_limit_over_no_limit"] = round(results["crowded_limit"]["wall_s"]
                                                           / results["crowded_no_limit"]["wall_s"], 2)
    print(json.dumps({"case": "suite_compile_cache", "files": args.files, **results,
                      "cache_mb": round(size / 2**20, 1),
                      "cpu_off_over_cold": round(results["off"]["cpu_s"] / results["cold"]["cpu_s"], 2),
                      "cpu_off_over_warm": round(results["off"]["cpu_s"] / results["warm"]["cpu_s"], 2),
                      "wall_off_over_cold": round(results["off"]["wall_s"] / results["cold"]["wall_s"], 2),
                      "cpu_count": os.cpu_count(), "load_avg_1min_at_start": load,
                      "load_avg_1min_at_end": round(os.getloadavg()[0], 2)}))


if __name__ == "__main__":
    main()

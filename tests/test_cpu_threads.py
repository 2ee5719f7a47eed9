"""XLA's CPU thread pools (stp_env.cpu_threads): the setting reaches XLA, is refused once fixed, changes no result."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from stp_env import cpu_threads

_PROBE = """
import collections, json, os, sys
import numpy as np
import stp_env
want = json.loads(sys.argv[1])
if want != "unset":
    stp_env.set_cpu_threads(want)
env = stp_env.parallel_env("town", vehicle_policy="switching")
obs, _ = env.reset(seed=3)
rng = np.random.default_rng(0)
seen = [np.concatenate([obs[a] for a in sorted(obs)]).tolist()]
zero = np.zeros(2, np.float32)
for _ in range(30):
    obs, rew, *_ = env.step({a: (rng.uniform(-1, 1, 2).astype(np.float32) if a == "intruder" else zero)
                             for a in env.agents})
    seen.append(np.concatenate([obs[a] for a in sorted(obs)] + [np.asarray([rew[a] for a in sorted(rew)])]).tolist())
names = [open(f"/proc/self/task/{t}/comm").read().strip() for t in os.listdir("/proc/self/task")]
errors = []
for n in (want if want != "unset" else None, 2 if want == 1 else 1):
    try:
        stp_env.set_cpu_threads(n)
        errors.append(None)
    except RuntimeError as err:
        errors.append(str(err))
print(json.dumps({"eigen": sum("Eigen" in n for n in names), "seen": seen, "errors": errors,
                  "env": os.environ.get("PJRT_NPROC")}))
"""


def _probe(want):
    env = {k: v for k, v in os.environ.items() if k not in ("PJRT_NPROC", "NPROC")}
    out = subprocess.run([sys.executable, "-c", _PROBE, json.dumps(want)], capture_output=True, text=True, env=env,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.slow
@pytest.mark.skipif(not os.path.isdir("/proc/self/task"), reason="counts threads through /proc")
def test_one_thread_reaches_xla_is_refused_after_start_and_changes_nothing():
    one, default = _probe(1), _probe("unset")
    assert one["eigen"] == 1
    assert default["eigen"] == len(os.sched_getaffinity(0))
    assert one["seen"] == default["seen"]  # the same episode, bit for bit (floats through JSON round-trip exactly)
    # after the first computation: the setting in effect is accepted, another one refused, nothing changed
    assert one["errors"][0] is None and "already started" in one["errors"][1]
    assert one["env"] == "1"
    assert default["errors"][0] is None and "already started" in default["errors"][1]


@pytest.mark.parametrize("bad", [0, -1, True, 1.5, "1"])
def test_bad_counts_are_refused(bad, monkeypatch):
    monkeypatch.delenv("PJRT_NPROC", raising=False)
    with pytest.raises(ValueError, match="positive integer"):
        cpu_threads.set_cpu_threads(bad)
    assert "PJRT_NPROC" not in os.environ


def test_reads_the_variables_xla_reads(monkeypatch):
    monkeypatch.delenv("PJRT_NPROC", raising=False)
    monkeypatch.delenv("NPROC", raising=False)
    assert cpu_threads.cpu_threads() is None
    monkeypatch.setenv("NPROC", "3")
    assert cpu_threads.cpu_threads() == 3
    monkeypatch.setenv("PJRT_NPROC", "1")
    assert cpu_threads.cpu_threads() == 1
    monkeypatch.setenv("PJRT_NPROC", "one")  # unparseable: XLA goes on to NPROC
    assert cpu_threads.cpu_threads() == 3

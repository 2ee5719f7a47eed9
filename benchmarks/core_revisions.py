"""The batched core (or the PettingZoo adapter's step loop) of this tree against that of another git revision, in
the same run: time and whether the two compute the same episodes.

    python benchmarks/core_revisions.py --base REV [--scenarios town city] [--envs 256] [--steps 50] [--reps 3]
        [--ignore FIELD ...] [--program core|adapter]

``REV``'s ``stp_env`` package is exported with ``git archive`` into a temporary directory and imported from there
(this tree's ``stp_env`` otherwise); everything else is the same: the scenario's shipped plan, ``switching``
vehicles, the HJ intruder, ``sim.rollout`` over ``--envs`` episodes of ``--steps`` steps, the whole fleet. Each
(tree, scenario) runs in its own process; its time is the fastest of three calls after a first (compiling) one.
The two trees alternate ``--reps`` times and the fastest run of each is kept (the machine is noisy). The final
states and per-step records of the first call are hashed: ``same_episodes`` says whether both trees computed them
bit for bit. Prints one JSON line per scenario; ``speedup`` is the base's time over this tree's.

``--program adapter``: instead of the batched core, ``--steps`` steps of one ``parallel_env(scenario,
vehicle_policy="switching")`` (the vehicles flown inside the step, the intruder's actions from a seeded generator,
auto-reset; what training an intruder runs), after 300 warm-up steps; its time is the fastest of three such loops,
and the digest covers every observation, reward, termination and the final state. ``--program intruder_env`` and
``--program coobservation_env``: the same for the single Gymnasium intruder env (``stp_env.rl.IntruderEnv``, town)
and the co-observation env (coarse artifacts, unsecured schedule), seeded random actions.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def _digest(tree, ignore=()) -> str:
    """A hash of every leaf of ``tree`` except those under a field named in ``ignore`` (a field one tree added)."""
    import jax
    import numpy as np

    h = hashlib.sha256()
    for path, leaf in jax.tree_util.tree_leaves_with_path(tree):
        if any(getattr(k, "name", getattr(k, "key", None)) in ignore for k in path):
            continue
        if jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
            leaf = jax.random.key_data(leaf)
        h.update(np.ascontiguousarray(np.asarray(leaf)).tobytes())
    return h.hexdigest()[:16]


def time_rollout(params, n_envs: int, n_steps: int, record: bool = False, ignore=()) -> dict:
    """``sim.rollout`` of ``switching`` vehicles against the HJ intruder: the first (compiling) call's seconds, the
    fastest of three more calls, and the digest of the first call's output."""
    import jax

    from stp_env import sim
    from stp_env.policies import INTRUDERS, switching

    def go(seed):
        return jax.block_until_ready(sim.rollout(jax.random.key(seed), params, switching, INTRUDERS["hj"], n_envs,
                                                 n_steps, record=record))

    t0 = time.perf_counter()
    first = go(0)
    first_s = time.perf_counter() - t0
    times = []
    for i in range(3):
        t0 = time.perf_counter()
        go(i + 1)
        times.append(time.perf_counter() - t0)
    return {"first_s": first_s, "run_s": min(times), "digest": _digest(first, ignore)}


def time_adapter(scenario: str, n_steps: int, ignore=()) -> dict:
    """The adapter's step loop (``vehicle_policy="switching"``, seeded random intruder actions, auto-reset): the
    fastest of three loops of ``n_steps`` after 300 warm-up steps, and the digest of the warm-up loop's outputs."""
    import numpy as np

    from stp_env.env import parallel_env

    env = parallel_env(scenario=scenario, vehicle_policy="switching")
    rng = np.random.default_rng(0)
    zero = np.zeros(2, np.float32)
    episode = [0]
    env.reset(seed=0)

    def loop(n, record=None):
        for _ in range(n):
            if not env.agents:
                episode[0] += 1
                env.reset(seed=episode[0])
            out = env.step({a: (rng.uniform(-1, 1, 2).astype(np.float32) if a == "intruder" else zero)
                            for a in env.agents})
            if record is not None:
                record.append(out[:4])

    t0 = time.perf_counter()
    record = []
    loop(300, record)
    first_s = time.perf_counter() - t0
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        loop(n_steps)
        times.append(time.perf_counter() - t0)
    leaves = [np.asarray(v, np.float64) for step in record for part in step for _, v in sorted(part.items())]
    return {"first_s": first_s, "run_s": min(times), "digest": _digest([leaves, env.env_state], ignore)}


def _time_loop(step, state, n_steps: int, ignore=()) -> dict:
    """``step()`` (one env step, returning what it gave the user) 300 times recorded, then the fastest of three loops
    of ``n_steps``; the digest covers the recorded outputs and ``state()`` after them."""
    import numpy as np

    t0 = time.perf_counter()
    record = [step() for _ in range(300)]
    first_s = time.perf_counter() - t0
    leaves = [np.asarray(x, np.float64) for out in record for x in _flat_numbers(out)]
    digest = _digest([leaves, state()], ignore)
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        for _ in range(n_steps):
            step()
        times.append(time.perf_counter() - t0)
    return {"first_s": first_s, "run_s": min(times), "digest": digest}


def _flat_numbers(x):
    """The numbers in nested dicts, lists and tuples of arrays and scalars, in a fixed order (None and strings
    skipped)."""
    if isinstance(x, dict):
        return [v for k in sorted(x, key=str) for v in _flat_numbers(x[k])]
    if isinstance(x, (list, tuple)):
        return [v for item in x for v in _flat_numbers(item)]
    if x is None or isinstance(x, str):
        return []
    return [x]


def time_intruder_env(n_steps: int, ignore=()) -> dict:
    """``stp_env.rl.IntruderEnv`` on the town, seeded random actions, reset when an episode ends."""
    import numpy as np

    from stp_env.rl import IntruderEnv

    env = IntruderEnv("town")
    env.reset(seed=0)
    rng = np.random.default_rng(0)

    def step():
        out = env.step(rng.uniform(-1, 1, 2).astype(np.float32))
        if out[2] or out[3]:
            env.reset()
        return out[:4]

    return _time_loop(step, lambda: env.state, n_steps, ignore)


def time_coobservation_env(n_steps: int, ignore=()) -> dict:
    """The co-observation env (coarse artifacts, unsecured schedule, vehicle 0 compromised at once), the attacker's
    seeded random actions, reset when the episode ends."""
    import numpy as np

    from stp_env.coobservation.env import parallel_env
    from stp_env.coobservation.uav import FormationScenario

    scenario = FormationScenario()
    env = parallel_env(schedule="unsecured", params=scenario.params(artifacts=scenario.coarse_artifacts()),
                       max_cycles=10**9)
    options = {"compromised": 0, "compromise_time": 0.0}
    env.reset(seed=0, options=options)
    rng = np.random.default_rng(0)
    episode = [0]

    def step():
        if not env.agents:
            episode[0] += 1
            env.reset(seed=episode[0], options=options)
        return env.step({"attacker": rng.uniform(-1, 1, 2).astype(np.float32)})[:4]

    return _time_loop(step, lambda: env.threat_state, n_steps, ignore)


def run_one(scenario: str, n_envs: int, n_steps: int, ignore=(), program: str = "core") -> dict:
    if program in ("adapter", "intruder_env", "coobservation_env"):
        import stp_env

        timed = {"adapter": lambda: time_adapter(scenario, n_steps, ignore),
                 "intruder_env": lambda: time_intruder_env(n_steps, ignore),
                 "coobservation_env": lambda: time_coobservation_env(n_steps, ignore)}[program]()
        return {**timed, "package": stp_env.__file__}
    sys.path.insert(0, HERE)
    import env_throughput

    import stp_env

    _, params = env_throughput._params(scenario)
    return {**time_rollout(params, n_envs, n_steps, record=True, ignore=ignore), "package": stp_env.__file__}


def export(rev: str, into: str) -> str:
    """``rev``'s ``stp_env`` package under ``into`` (``git archive``); returns the directory to import from."""
    archive = subprocess.run(["git", "-C", ROOT, "archive", rev, "stp_env"], capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", into], input=archive.stdout, check=True)
    return into


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--base", help="the git revision to compare against (e.g. HEAD~1)")
    parser.add_argument("--scenarios", nargs="+", default=["town", "city"])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--ignore", nargs="*", default=[],
                        help="state fields left out of the episodes' digest (a field one of the trees added)")
    parser.add_argument("--program", choices=("core", "adapter", "intruder_env", "coobservation_env"),
                        default="core",
                        help="the batched core's rollout, the adapter's step loop, or the step loop of the single "
                             "Gymnasium intruder env (town) or of the co-observation env (--envs and, for the "
                             "last two, --scenarios ignored)")
    parser.add_argument("--one", action="store_true", help="run one case in this process (used internally)")
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.scenarios[0], args.envs, args.steps, tuple(args.ignore), args.program)))
        return
    if not args.base:
        parser.error("--base REV is required")
    rev = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", args.base], capture_output=True, text=True,
                         check=True).stdout.strip()
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this": ROOT, "base": export(rev, tmp)}
        for scenario in args.scenarios:
            load = round(os.getloadavg()[0], 2)
            runs = {name: [] for name in trees}
            for _ in range(args.reps):
                for name, path in trees.items():
                    env = dict(os.environ, PYTHONPATH=os.pathsep.join([path, os.environ.get("PYTHONPATH", "")]))
                    res = subprocess.run([sys.executable, __file__, "--one", "--scenarios", scenario, "--envs",
                                          str(args.envs), "--steps", str(args.steps), "--program", args.program,
                                          "--ignore", *args.ignore],
                                         capture_output=True,
                                         text=True, check=True, env=env, cwd=tmp)
                    out = json.loads(res.stdout.strip().splitlines()[-1])
                    if not out["package"].startswith(path):
                        raise SystemExit(f"the {name} run imported {out['package']}, not the package in {path}")
                    runs[name].append(out)
            best = {name: min(r["run_s"] for r in runs[name]) for name in trees}
            print(json.dumps({
                "benchmark": "core_revisions", "program": args.program, "scenario": scenario, "base": rev,
                "envs": args.envs, "steps": args.steps, "reps": args.reps, "loadavg_1min_before": load,
                "run_s": {name: round(best[name], 3) for name in trees},
                "run_s_all": {name: [round(r["run_s"], 3) for r in runs[name]] for name in trees},
                "first_call_s": {name: round(min(r["first_s"] for r in runs[name]), 1) for name in trees},
                "speedup": round(best["base"] / best["this"], 2),
                "same_episodes": len({r["digest"] for name in trees for r in runs[name]}) == 1,
                "env_steps_per_s_this": round((args.envs if args.program == "core" else 1) * args.steps
                                              / best["this"]),
            }), flush=True)


if __name__ == "__main__":
    main()

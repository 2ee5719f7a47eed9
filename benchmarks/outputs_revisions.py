"""The numbers of this tree against those of another git revision, bit for bit: the evaluation of the default
suite, the worst-case reproduction, the falsifier's searches, a co-observation batch (the threat's rollouts and the
learned attacker's decisions) and a survivability slice.

    python benchmarks/outputs_revisions.py --base REV [--cases evaluate worst_case falsify coobservation
        survivability] [--episodes 200]

``REV``'s ``stp_env`` package is exported with ``git archive`` into a temporary directory and imported from there
(this tree's ``stp_env`` otherwise), as ``benchmarks/core_revisions.py`` does; each (tree, case) runs in its own
process from the same code below, which uses only names both trees have. Every array a case produces (final
states, per-episode results, recorded trajectories, the searches' worst inputs and values) is hashed in order;
``same`` says whether both trees produced the same bytes. Prints one JSON line per case, and exits 1 when a case
differs. On two busy cores the default run (200 episodes of the default suite) takes about half an hour for
both trees; ``--episodes 20`` a third of that.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import os
import subprocess
import sys
import tempfile
import time

from core_revisions import export  # the same export of a revision's package (this folder is on sys.path)

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
CASES = ("evaluate", "worst_case", "falsify", "coobservation", "survivability")


class Digest:
    """A SHA-256 over a sequence of pytrees of arrays and numbers (keys sorted; PRNG keys by their data)."""

    def __init__(self):
        self.h = hashlib.sha256()
        self.leaves = 0

    def add(self, tree) -> None:
        import jax
        import numpy as np

        if isinstance(tree, dict):
            for k in sorted(tree, key=str):
                self.h.update(str(k).encode())
                self.add(tree[k])
            return
        for leaf in jax.tree_util.tree_leaves(tree):
            if isinstance(leaf, (jax.Array, np.ndarray)) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
                leaf = jax.random.key_data(leaf)
            arr = np.ascontiguousarray(np.asarray(leaf))
            self.h.update(str((arr.dtype, arr.shape)).encode())
            self.h.update(arr.tobytes())
            self.leaves += 1

    def hexdigest(self) -> str:
        return self.h.hexdigest()[:16]


def _assembly():
    try:
        from stp_env import assembly
    except ImportError:  # revisions before stp_env.assembly: the same functions in stp_env.sim
        from stp_env import sim as assembly
    return assembly


def case_evaluate(d: Digest, episodes: int) -> dict:
    """``evaluate`` of the default suite (``stp-env evaluate``'s default): every per-episode result, the showcase
    trajectory and the summary less its timings."""
    from stp_env.evaluation.config import default_suite
    from stp_env.evaluation.runner import evaluate

    out = {}
    for r in evaluate(default_suite(), episodes=episodes, seed=0, batch_size=min(episodes, 250), progress=False):
        summary = {k: v for k, v in r.summary.items() if k not in ("seconds", "episodes_per_s")}
        d.add(r.episodes)
        d.add(r.showcase)
        d.h.update(json.dumps(summary, sort_keys=True, default=str).encode())
        out[r.config.label] = {"forced_max": summary.get("forced_max"), "forced_mean": summary.get("forced_mean")}
    return out


def case_worst_case(d: Digest, episodes: int) -> dict:
    """The intruder paper's Fig. 6 (buffer game's worst vehicles against ``optimal-max-k``) and Fig. 7 (``u*``
    against ``max-k``) on the core from the fixed spawn: trajectories and final states."""
    from stp_env.evaluation import worst_case

    try:
        policies = importlib.import_module("stp_env.policies")
    except ImportError:  # a revision from before the package's policies were renamed (its name then: "baselines")
        policies = importlib.import_module("stp_env.baselines")
    INTRUDERS, VEHICLE_POLICIES = policies.INTRUDERS, policies.VEHICLE_POLICIES

    params = worst_case.fig6_params()
    out = {}
    for name, vehicles, intruder in (("fig6", "worst", "optimal-max-k"), ("fig7", "switching", "max-k")):
        r = worst_case.reproduce(params, VEHICLE_POLICIES[vehicles], INTRUDERS[intruder], seed=0)
        d.add(r["trajectory"])
        d.add(r["final"])
        out[name] = r["avoid_start_s"]
    return out


def case_falsify(d: Digest, episodes: int) -> dict:
    """A short search of each falsifier target on ``town`` (k̄ = 2): the worst input and value, the spread and the
    details of the worst attack."""
    from stp_env.falsify.counterexample import AttackSpec, run
    from stp_env.falsify.search import SearchConfig

    out = {}
    for target in ("tracking", "avoidance", "kbar"):
        config = SearchConfig(method="both", budget=64, population=16, restarts=2, batch=16)
        o = run(AttackSpec(target=target, scenario="town", kbar=2), config, seed=0, progress=False)
        d.add({"z": o.z, "worst": o.worst, "margin": o.margin, "quantiles": list(o.quantiles),
               "seed_values": list(o.seed_values)})
        d.h.update(json.dumps(o.details, sort_keys=True, default=str).encode())
        out[target] = round(o.worst, 6)
    return out


def case_coobservation(d: Digest, episodes: int) -> dict:
    """The co-observation threat's batched rollouts (secured and unsecured schedules, two attackers, 64 episodes
    each) and eight learned-attacker environments stepped 4 decisions with fixed actions."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from stp_env.coobservation import learned, threat
    from stp_env.coobservation.attackers import ATTACKERS
    from stp_env.coobservation.cli import schedules_for
    from stp_env.coobservation.uav import FormationScenario

    scenario = FormationScenario()
    params = scenario.params(progress=False)
    times = schedules_for(scenario, ("secured", "unsecured"), 90.0, progress=False)
    schedules = {k: scenario.schedule(v) for k, v in times.items()}
    m = max(len(s) for s in schedules.values())
    threats = {k: threat.threat_params(s, scenario.forbidden, scenario.observation_radius, pad_to=m)
               for k, s in schedules.items()}
    window = (0.0, scenario.duration - 10.0)
    n_steps = threat.steps_for(params)
    out = {}
    for s_name, tp in threats.items():
        for a_name in ("reckless", "opportunistic"):
            final, traj = threat.rollout(jax.random.key(0), params, tp, ATTACKERS[a_name], 64, n_steps, window,
                                         record=a_name == "reckless")
            d.add({"final": final, "traj": traj})
            out[f"{s_name}/{a_name}"] = float(np.mean(threat.outcomes(jax.device_get(final))["success"]))
    tp = threats["secured"]
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(1), i))(jnp.arange(8))
    keys, states, obs = learned.batch_reset(keys, params, tp, window)
    for i in range(4):
        actions = jnp.stack([jnp.linspace(-1.0, 1.0, 8), jnp.full((8,), 0.5 * (-1) ** i)], axis=-1)
        keys, states, obs, rewards, dones, terminal, stats = learned.batch_step(
            keys, states, actions, params, tp, window, 5, 0.99, 1.0)
        d.add({"states": states, "obs": obs, "rewards": rewards, "dones": dones, "terminal": terminal, "stats": stats})
    out["learned_rewards"] = np.asarray(rewards).round(6).tolist()
    return out


def case_survivability(d: Digest, episodes: int) -> dict:
    """Trajectory counts to any landing site without traffic on the paper's compact mission graph (the
    survivability study's first table; ``benchmarks/survivability.py``'s ``counts``)."""
    import numpy as np

    from stp_env.survivability import dp
    from stp_env.survivability.graph import build_graph

    graph = build_graph()
    counts = np.asarray(dp.counts(graph, np.ones(graph.n_segments, bool), "all"))
    d.add(counts)
    return {"states": int(counts.size), "at_origin": float(counts[graph.origin])}


def run_one(case: str, episodes: int) -> dict:
    import stp_env

    d = Digest()
    t0 = time.perf_counter()
    summary = globals()[f"case_{case}"](d, episodes)
    return {"case": case, "digest": d.hexdigest(), "leaves": d.leaves, "seconds": round(time.perf_counter() - t0, 1),
            "summary": summary, "package": stp_env.__file__}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--base", help="the git revision to compare against (e.g. HEAD~1)")
    parser.add_argument("--cases", nargs="+", choices=CASES, default=list(CASES))
    parser.add_argument("--episodes", type=int, default=200, help="episodes of each configuration of the suite")
    parser.add_argument("--one", action="store_true", help="run one case in this process (used internally)")
    args = parser.parse_args()
    if args.one:
        print(json.dumps(run_one(args.cases[0], args.episodes), default=str))
        return
    if not args.base:
        parser.error("--base REV is required")
    rev = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", args.base], capture_output=True, text=True,
                         check=True).stdout.strip()
    differ = False
    with tempfile.TemporaryDirectory() as tmp:
        trees = {"this": ROOT, "base": export(rev, tmp)}
        for case in args.cases:
            runs = {}
            for name, path in trees.items():
                env = dict(os.environ, PYTHONPATH=os.pathsep.join([path, os.environ.get("PYTHONPATH", "")]))
                res = subprocess.run([sys.executable, __file__, "--one", "--cases", case, "--episodes",
                                      str(args.episodes)], capture_output=True, text=True, env=env, cwd=tmp)
                if res.returncode != 0:
                    raise SystemExit(f"{case} failed in the {name} tree:\n{res.stderr[-4000:]}")
                out = json.loads(res.stdout.strip().splitlines()[-1])
                if not out.pop("package").startswith(path):
                    raise SystemExit(f"the {name} run of {case} imported another stp_env than the one in {path}")
                runs[name] = out
            same = runs["this"]["digest"] == runs["base"]["digest"] and runs["this"]["leaves"] == runs["base"]["leaves"]
            differ |= not same
            print(json.dumps({"benchmark": "outputs_revisions", "case": case, "base": rev, "episodes": args.episodes,
                              "same": same, "digest": {k: v["digest"] for k, v in runs.items()},
                              "arrays": runs["this"]["leaves"], "seconds": {k: v["seconds"] for k, v in runs.items()},
                              "summary": runs["this"]["summary"]}, default=str), flush=True)
    sys.exit(1 if differ else 0)


if __name__ == "__main__":
    main()

"""Train an SB3 PPO planning policy on the mission environment and compare it with pi_S and pi_Nf.

    python examples/survivability_ppo.py train [--timesteps 60000] [--out runs/survivability-ppo] [--ship]
    python examples/survivability_ppo.py compare [--policy ppo|PATH.npz] [--instances 200] [--out DIR]

``train``: PPO with action masking (sb3-contrib's ``MaskablePPO``: only the valid primitives of
:meth:`~stp_env.survivability.gym_env.SurvivabilityEnv.action_masks` are sampled; ``--no-masking`` for SB3's plain
PPO, which never learns to land: every one of its episodes ends in an emergency landing), ``MlpPolicy``, a 64 x 64
tanh MLP, CPU, on :class:`stp_env.survivability.gym_env.SurvivabilityEnv`
on a pool of 1,800 training instances (50 per scenario of the 36-scenario grid, seeds ``(1, j)``, one drawn at
each reset), segment robustness from 500 Monte Carlo realisations (for speed; the comparison uses 2,500 like the
study) and rewards 1 (goal), 0.5 (alternative site),
-1 (emergency landing). Writes the SB3 model (``model.zip``), the exported actor (``ppo.npz``, numpy weights,
``allow_pickle=False``) and ``train.json``; ``--ship`` copies ``ppo.npz`` into ``stp_env/data/survivability/``.

``compare``: on held-out instances (seeds ``(2, i)``, never drawn in training: training seeds are ``(1, *)``) of
four scenarios, every instance flown by the learned policy (argmax action), ``pi_S`` and ``pi_Nf``; writes
``compare.json`` (rates with 95 % Clopper-Pearson intervals, paired differences with 95 % normal intervals) and
``docs/survivability_ppo.png``.
"""

from __future__ import annotations

import argparse
import json
import shutil
import time
from pathlib import Path

import numpy as np

from stp_env.survivability import analysis
from stp_env.survivability.config import PlannerConfig, TrafficConfig
from stp_env.survivability.gym_env import SurvivabilityEnv
from stp_env.survivability.learned import load_policy
from stp_env.survivability.mission import initial_tables, make_instance, run_mission
from stp_env.survivability.names import LEVELS

ROOT = Path(__file__).resolve().parents[1]
GRID = [(p, u) for p in LEVELS for u in LEVELS]
HELD_OUT = [(100, 100), (100, 250), (250, 100), (200, 200)]


def train(args) -> None:
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.monitor import Monitor
    from tqdm.auto import tqdm

    from stp_env.policies.learned import export_mlp

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # the earlier model (local traffic, landing count), with which the shipped policy was trained and measured
    planner = PlannerConfig(n_mc=args.train_n_mc, nf_count="landing")
    base = SurvivabilityEnv(GRID, planner=planner, traffic=TrafficConfig(model="local"))
    pool = []
    for j in tqdm(range(args.pool), unit="instance", desc="training instances"):
        scenario = GRID[j % len(GRID)]
        traffic = base.traffic.with_overrides(n_partial=scenario[0], n_unknown=scenario[1])
        pool.append((scenario, make_instance(base.graph, traffic, planner, (1, j))))
    env = Monitor(SurvivabilityEnv(GRID, planner=planner, traffic=base.traffic, reward_failure=-1.0,
                                   graph=base.graph, pool=pool))

    class Progress(BaseCallback):
        def _on_training_start(self):
            self.bar = tqdm(total=args.timesteps, unit="step", desc="PPO")
            self.log = []

        def _on_step(self):
            self.bar.update(1)
            for info in self.locals.get("infos", []):
                if "episode" in info:
                    self.log.append((self.num_timesteps, info["outcome"]))
            return True

        def _on_training_end(self):
            self.bar.close()

    cb = Progress()
    algo = PPO
    if args.masking:
        from sb3_contrib import MaskablePPO

        algo = MaskablePPO
    model = algo("MlpPolicy", env, n_steps=1024, batch_size=256, n_epochs=10, learning_rate=3e-4, gamma=0.99,
                 ent_coef=0.01, seed=args.seed, device="cpu", verbose=0,
                 policy_kwargs={"net_arch": [64, 64], "activation_fn": torch.nn.Tanh})
    t0 = time.perf_counter()
    model.learn(total_timesteps=args.timesteps, callback=cb)
    seconds = time.perf_counter() - t0
    model.save(out / "model.zip")
    meta = {"algo": "MaskablePPO" if args.masking else "PPO", "action_masking": bool(args.masking),
            "timesteps": args.timesteps, "seed": args.seed, "train_n_mc": args.train_n_mc, "pool": args.pool,
            "scenarios": "36-scenario grid", "rewards": [1.0, 0.5, -1.0], "net_arch": [64, 64]}
    path = export_mlp(model, out / "ppo.npz", metadata=meta)
    # Learning curve: outcome shares over successive blocks of episodes.
    outcomes = [o for _, o in cb.log]
    block = max(1, len(outcomes) // 10)
    curve = [{"episodes": f"{i}-{i + block}", **{o: outcomes[i:i + block].count(o) / len(outcomes[i:i + block])
                                                  for o in "GAL"}}
             for i in range(0, len(outcomes), block)]
    (out / "train.json").write_text(json.dumps({**meta, "seconds": round(seconds, 1), "episodes": len(outcomes),
                                                "curve": curve}, indent=1))
    print(json.dumps({"seconds": round(seconds, 1), "episodes": len(outcomes), "npz_bytes": path.stat().st_size,
                      "last": curve[-1] if curve else None}))
    if args.ship:
        dest = ROOT / "stp_env" / "data" / "survivability"
        dest.mkdir(parents=True, exist_ok=True)
        shutil.copy(path, dest / "ppo.npz")


def compare(args) -> None:
    from tqdm.auto import tqdm

    policy = load_policy(args.policy)
    planner = PlannerConfig(nf_count="landing")  # the earlier model, as the shipped policy's measurements
    env = SurvivabilityEnv(HELD_OUT, planner=planner, traffic=TrafficConfig(model="local"))
    graph = env.graph
    rows = []
    t0 = time.perf_counter()
    with tqdm(total=len(HELD_OUT) * args.instances, unit="instance", desc="compare") as bar:
        for scenario in HELD_OUT:
            traffic = env.traffic.with_overrides(n_partial=scenario[0], n_unknown=scenario[1])
            for i in range(args.instances):
                inst = make_instance(graph, traffic, planner, (2, i))
                first = initial_tables(graph, inst, ("S", "Nf"))
                out = {q: run_mission(graph, inst, q, planner, seed=(2, i), initial_tables=first[q]).outcome
                       for q in ("S", "Nf")}
                obs, info = env.reset(options={"scenario": scenario, "instance": inst})
                done = False
                while not done:
                    obs, _, term, trunc, info = env.step(policy(obs))
                    done = term or trunc
                out["PPO"] = info["outcome"] or "L"
                rows.append({"scenario": scenario, "instance": i, **out})
                bar.update(1)
    result = {"instances_per_scenario": args.instances, "seconds": round(time.perf_counter() - t0, 1),
              "policy": args.policy, "scenarios": {}}
    for scenario in HELD_OUT:
        rs = [r for r in rows if r["scenario"] == scenario]
        entry = {}
        for q in ("PPO", "S", "Nf"):
            surv = np.array([r[q] in "GA" for r in rs], float)
            succ = np.array([r[q] == "G" for r in rs], float)
            entry[q] = {"survival": analysis.rate(int(surv.sum()), len(rs)),
                        "success": analysis.rate(int(succ.sum()), len(rs))}
        for ref in ("S", "Nf"):
            a = np.array([r["PPO"] in "GA" for r in rs], float)
            b = np.array([r[ref] in "GA" for r in rs], float)
            entry[f"survival[PPO]-survival[{ref}]"] = analysis.paired(a, b)
        result["scenarios"][f"{scenario[0]},{scenario[1]}"] = entry
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "compare.json").write_text(json.dumps(result, indent=1))
    _figure(result, ROOT / "docs" / "survivability_ppo.png")
    print(json.dumps(result)[:3000])


def _figure(result, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = list(result["scenarios"])
    fig, ax = plt.subplots(figsize=(7.5, 4))
    w = 0.26
    for j, (q, color) in enumerate((("PPO", "tab:red"), ("S", "tab:orange"), ("Nf", "tab:blue"))):
        r = [result["scenarios"][k][q]["survival"] for k in keys]
        y = np.array([100 * v["rate"] for v in r])
        err = np.array([[100 * (v["rate"] - v["ci95"][0]), 100 * (v["ci95"][1] - v["rate"])] for v in r]).T
        label = {"PPO": "PPO (learned)", "S": "π_S", "Nf": "π_Nf"}[q]
        ax.bar(np.arange(len(keys)) + (j - 1) * w, y, w, yerr=err, capsize=3, color=color, label=label)
    ax.set_xticks(np.arange(len(keys)), [f"(N_p, N_u) = ({k})" for k in keys], fontsize=8)
    ax.set_ylabel("mission survival rate [%]")
    ax.set_title(f"Held-out instances ({result['instances_per_scenario']} per scenario), 95 % Clopper-Pearson")
    ax.set_ylim(0, 100)
    ax.legend(loc="lower right", ncol=3, fontsize=8)
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    tr = sub.add_parser("train")
    tr.add_argument("--timesteps", type=int, default=60_000)
    tr.add_argument("--no-masking", dest="masking", action="store_false",
                    help="plain PPO: invalid primitives are sampled too (and end the episode)")
    tr.add_argument("--seed", type=int, default=0)
    tr.add_argument("--train-n-mc", type=int, default=500)
    tr.add_argument("--pool", type=int, default=1800, help="training instances (50 per scenario)")
    tr.add_argument("--out", default="runs/survivability-ppo")
    tr.add_argument("--ship", action="store_true")
    co = sub.add_parser("compare")
    co.add_argument("--policy", default="ppo", help="'ppo' (shipped) or an exported .npz")
    co.add_argument("--instances", type=int, default=200)
    co.add_argument("--out", default="runs/survivability-ppo")
    args = ap.parse_args()
    train(args) if args.cmd == "train" else compare(args)


if __name__ == "__main__":
    main()

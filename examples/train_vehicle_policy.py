"""Train, evaluate and ship a learned vehicle policy under the HJ filters (``docs/learned_vehicles.md``).

    python examples/train_vehicle_policy.py train --out runs/vehicle-crossing [--steps 262144] [--seed 0] [--resume]
    python examples/train_vehicle_policy.py evaluate --policy runs/vehicle-crossing/vehicle.npz --episodes 1024
    python examples/train_vehicle_policy.py ship runs/vehicle-crossing/vehicle.npz crossing-after-avoidance
    python examples/train_vehicle_policy.py curve runs/vehicle-crossing --out docs/learned_vehicle_curve.png

The env is :class:`stp_env.rl.vehicle_env.EgoVehicleVecEnv` on the crossing (k̄ = 2, 6 m/s, the intruder appearing
on a vehicle's avoid boundary, every episode to the vehicles' targets) against the shipped learned intruder
``crossing-kbar2``; PPO (SB3) on a 64 x 64 tanh MLP. ``evaluate`` flies the same held-out episodes (keys from
``--seed``, disjoint from training's) with the ego on ``u*``, on the fallback at ``U``'s top speed and on the policy,
against each ``--intruder``, and prints one JSON line per row (rates with exact 95 % intervals).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from stp_env.evaluation.stats import clopper_pearson_interval

TRAIN_SEED_OFFSET = 1_000_000_000
"""Training envs are seeded from ``seed + TRAIN_SEED_OFFSET``; evaluations use small seeds (disjoint keys)."""


def build(intruder: str, kbar: int = 2):
    from stp_env.rl.ego import ego_params

    return ego_params("crossing", kbar, intruder, progress=True)


def train(args) -> None:
    import torch
    from stable_baselines3 import PPO

    from stp_env.policies.learned import export_mlp
    from stp_env.rl.vehicle_env import EgoVehicleVecEnv

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    params, intruder = build(args.intruder)
    torch.manual_seed(args.seed)
    env = EgoVehicleVecEnv(args.envs, params, intruder, energy=args.energy)
    env.seed(args.seed + TRAIN_SEED_OFFSET)
    log, done = [], 0
    if args.resume:  # continue a run: its model, its curve, its step count
        model = PPO.load(out / "model.zip", env=env, seed=args.seed)
        log = json.loads((out / "curve.json").read_text())
        done = int(log[-1]["steps"]) if log else 0
    else:
        model = PPO("MlpPolicy", env, n_steps=args.n_steps, batch_size=1024, learning_rate=args.learning_rate,
                    gamma=0.99, ent_coef=0.0, seed=args.seed, verbose=0,
                    policy_kwargs={"net_arch": [64, 64], "log_std_init": args.log_std_init})
    started = time.time() - (log[-1]["wall_s"] if log else 0.0)
    while done < args.steps:
        chunk = min(args.eval_every, args.steps - done)
        model.learn(chunk, reset_num_timesteps=False, progress_bar=False)
        done += chunk
        path = export_mlp(model, out / "vehicle.npz", metadata={
            "role": "vehicle", "observation": "core", "scenario": "crossing", "kbar": 2, "intruder": args.intruder,
            "steps": done, "seed": args.seed, "energy": args.energy, "spawn_mode": "boundary"})
        row = {"steps": done, "wall_s": round(time.time() - started, 1), **quick_eval(path, params, intruder, args)}
        log.append(row)
        print(json.dumps(row), flush=True)
        (out / "curve.json").write_text(json.dumps(log, indent=1))
        model.save(out / "model.zip")  # after every chunk: an interrupted run resumes with --resume


def quick_eval(path, params, intruder, args) -> dict:
    from stp_env.policies.learned_vehicles import load_vehicle_mlp
    from stp_env.rl.ego import evaluate_ego

    r = evaluate_ego(params, intruder, "learned", mlp=load_vehicle_mlp(str(path)), episodes=args.eval_episodes,
                     seed=args.eval_seed, energy=args.energy)
    return summarize(r)


def summarize(r: dict) -> dict:
    n = int((~r["empty"]).sum())
    on_time = int(r["on_time"].sum())
    lo, hi = clopper_pearson_interval(on_time, n) if n else (float("nan"), float("nan"))
    delay = r["delay"][r["arrived"]]
    return {"episodes": len(r["empty"]), "egos": n, "on_time": on_time,
            "on_time_rate": round(on_time / n, 4) if n else None, "on_time_ci": [round(lo, 4), round(hi, 4)],
            "arrived": int(r["arrived"].sum()),
            "median_delay_s": round(float(np.median(delay)), 1) if delay.size else None,
            "ego_collisions": int(r["ego_collided"].sum()), "collisions": int(r["collisions"].sum()),
            "guarantee_violations": int(r["guarantee_violations"].sum()),
            "ego_min_separation_m": round(float(np.min(r["ego_min_separation"])), 2),
            "energy_mean": round(float(np.mean(r["energy"][~r["empty"]])), 2) if n else None}


def evaluate(args) -> None:
    from stp_env.policies.learned_vehicles import load_vehicle_mlp
    from stp_env.rl.ego import evaluate_ego

    mlp = load_vehicle_mlp(args.policy)
    for name in args.intruder:
        params, intruder = build(name)
        for kind in ("u*", "fallback-vmax", "learned"):
            started = time.time()
            r = evaluate_ego(params, intruder, kind, mlp=mlp if kind == "learned" else None,
                             episodes=args.episodes, seed=args.eval_seed, energy=args.energy)
            row = {"intruder": name, "ego": kind, **summarize(r), "wall_s": round(time.time() - started, 1)}
            print(json.dumps(row), flush=True)


CHECK = {"scenario": "crossing", "kbar": 2, "intruder": "max-k", "episodes": 16, "seed": 20_240_601}
"""The small batch a shipped file records and ``tests/test_vehicle_filter.py`` replays (``max-k`` needs no ``V^B``)."""


def ship(args) -> None:
    from importlib import resources

    from stp_env.files import atomic_open
    from stp_env.loaders import read_npz
    from stp_env.policies.learned_vehicles import load_vehicle_mlp
    from stp_env.rl.ego import replay_check

    if not args.name.replace("-", "").isalnum():
        raise SystemExit(f"the name is letters, digits and '-'; got {args.name!r}.")
    mlp = load_vehicle_mlp(args.policy)  # refuses what is not a vehicle policy
    check = {**CHECK, **replay_check(mlp, CHECK)}
    arrays = read_npz(args.policy, "learned-policy")
    meta = {**mlp.metadata, "check": check}
    dest = Path(str(resources.files("stp_env") / "data" / "vehicles" / f"{args.name}.npz"))
    dest.parent.mkdir(parents=True, exist_ok=True)
    with atomic_open(dest, "wb") as fh:
        np.savez(fh, **{k: v for k, v in arrays.items() if k != "metadata"},
                 metadata=np.asarray(json.dumps(meta, sort_keys=True)))
    print(json.dumps({"shipped": str(dest), "check_on_time": sum(check["on_time"]), "episodes": check["episodes"]}))


def curve(args) -> None:
    """The training run's held-out on-time rate (with its 95 % interval) and energy against PPO steps, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from stp_env.files import atomic_open

    log = json.loads((Path(args.run) / "curve.json").read_text())
    steps = np.array([r["steps"] for r in log]) / 1e3
    rate = np.array([r["on_time_rate"] for r in log])
    lo, hi = np.array([r["on_time_ci"] for r in log]).T
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(9, 3.4))
    ax.fill_between(steps, lo, hi, alpha=0.3)
    ax.plot(steps, rate, "o-", label="learned (ego after its avoidance)")
    for value, label, style in ((args.reference_u, "u* (fallback at 13 m/s)", "--"),
                                (args.reference_vmax, "fallback at 25 m/s", ":")):
        if value is not None:
            ax.axhline(value, color="k", ls=style, lw=1, label=label)
    ax.set(xlabel="PPO steps (thousands)", ylabel="on time (held-out egos)", ylim=(0, 1.02))
    ax.legend(fontsize=7, loc="lower right")
    bx.plot(steps, [r["energy_mean"] for r in log], "o-")
    bx.set(xlabel="PPO steps (thousands)", ylabel="energy: mean integral of (v / v_max)^2 [s]")
    fig.suptitle(f"crossing, k̄ = 2, against {log[0].get('intruder', 'learned:crossing-kbar2')}: "
                 f"{log[0]['episodes']} held-out episodes per point", fontsize=9)
    fig.tight_layout()
    with atomic_open(Path(args.out), "wb") as fh:
        fig.savefig(fh, format="png", dpi=110)
    print(f"wrote {args.out}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train")
    tr.add_argument("--out", default="runs/vehicle-crossing")
    tr.add_argument("--steps", type=int, default=262_144)
    tr.add_argument("--envs", type=int, default=64)
    tr.add_argument("--n-steps", type=int, default=64)
    tr.add_argument("--eval-every", type=int, default=65_536)
    tr.add_argument("--learning-rate", type=float, default=3e-4)
    tr.add_argument("--log-std-init", type=float, default=-0.5)
    tr.add_argument("--intruder", default="learned:crossing-kbar2")
    tr.add_argument("--resume", action="store_true", help="continue the run in --out up to --steps in all")
    for p in (tr, sub.add_parser("evaluate")):
        p.add_argument("--energy", type=float, default=0.002)
        p.add_argument("--eval-episodes", "--episodes", dest="eval_episodes", type=int, default=256)
        p.add_argument("--eval-seed", type=int, default=20240601)
        p.add_argument("--seed", type=int, default=0)
    ev = sub.choices["evaluate"]
    ev.add_argument("--policy", required=True)
    ev.add_argument("--intruder", nargs="+", default=["learned:crossing-kbar2", "optimal-max-k"])
    sh = sub.add_parser("ship")
    sh.add_argument("policy")
    sh.add_argument("name")
    cv = sub.add_parser("curve")
    cv.add_argument("run")
    cv.add_argument("--out", default="docs/learned_vehicle_curve.png")
    cv.add_argument("--reference-u", type=float, default=None, help="u*'s on-time rate, drawn as a line")
    cv.add_argument("--reference-vmax", type=float, default=None, help="the 25 m/s fallback's, drawn as a line")
    args = parser.parse_args()
    if args.command == "evaluate":
        args.episodes = args.eval_episodes
    {"train": train, "evaluate": evaluate, "ship": ship, "curve": curve}[args.command](args)


if __name__ == "__main__":
    main()

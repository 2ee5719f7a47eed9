"""Train the shipped learned intruder for ``town`` (k̄ = 2) and compare it with the random-Bezier intruder.

    python scripts/train_intruder.py train [--timesteps N] [--out runs/town-kbar2] [--ship]
    python scripts/train_intruder.py compare [--intruder town-kbar2] [--episodes 1000] [--out runs/compare]

``train`` runs :func:`stp_env.rl.train.train` with :data:`SHIPPED` (``--timesteps`` overrides the length) and
with ``--ship`` copies ``model.zip`` and ``intruder.npz`` to ``stp_env/data/intruders/town-kbar2.{zip,npz}``.
``compare`` runs full core episodes (:func:`stp_env.sim.rollout`, the vehicles on ``switching`` with the HJ safety
filter, the default ``EnvConfig``) on held-out seeds for the learned intruder and the scripted ones, and prints one
JSON line per intruder (:func:`stp_env.evaluation.summary.forced_summary`): mean ``|N^RP|`` with its 95 % interval,
max ``|N^RP|`` against k̄, collisions and guarantee violations, Clopper-Pearson bounds; a guarantee violation or
``|N^RP| > k̄`` is a finding, reported with its episode seed and a plot.

Reproducibility: a run is deterministic given the seed and the code (same config in two processes: identical
rollouts and weights). The shipped ``town-kbar2`` was trained from the tree of commit d1ce834 (06:35, 589 s); the
simulation core changed after that (commits 5231dfe, 0b2d824), and a 1 M-step re-run on 3bebeed diverges from the
shipped run's 1 M-step checkpoint from the first update (held-out mean ``|N^RP|`` 0.574 vs 0.531 at that point).
The shipped weights still give the same held-out numbers on 3bebeed (0.528, 95 % 0.497-0.559, 1,000 episodes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
import time
from pathlib import Path

import jax
import numpy as np

from stp_env import assembly, sim
from stp_env.baselines import INTRUDERS, switching
from stp_env.baselines.learned import load_intruder
from stp_env.evaluation.summary import forced_summary
from stp_env.rl.train import TrainConfig, train

# forced_reward 5: one forced vehicle outweighs the shaping of a whole approach (shaping_reward * d_sense = 3.7).
SHIPPED = TrainConfig(scenario="town", n_envs=256, n_steps=64, batch_size=4096, n_epochs=10, learning_rate=3e-4,
                      forced_reward=5.0, collision_reward=10.0, shaping_reward=0.01, net_arch=(64, 64),
                      total_timesteps=4_194_304, seed=0, eval_every=524_288, eval_episodes=256,
                      checkpoint_every=1_048_576, out_dir="runs/town-kbar2",
                      log_formats=("stdout", "csv", "tensorboard"))
HELD_OUT_KEY = 20_240_601  # compare's episodes use jax.random.fold_in(PRNGKey(HELD_OUT_KEY), i), not training's
DATA = Path(__file__).resolve().parents[1] / "stp_env" / "data" / "intruders"


def run_train(args) -> None:
    config = dataclasses.replace(SHIPPED, total_timesteps=args.timesteps or SHIPPED.total_timesteps,
                                 out_dir=args.out or SHIPPED.out_dir)
    _, history = train(config)
    print(json.dumps(history[-1]))
    if args.ship:
        DATA.mkdir(parents=True, exist_ok=True)
        shutil.copy(Path(config.out_dir) / "model.zip", DATA / "town-kbar2.zip")
        shutil.copy(Path(config.out_dir) / "intruder.npz", DATA / "town-kbar2.npz")


def plot_episode(params, trajectory, index: int, title: str, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.asarray(trajectory["x"][index])
    xi = np.asarray(trajectory["intruder_x"][index])
    present = np.asarray(trajectory["intruder_status"][index]) == sim.PRESENT
    status = np.asarray(trajectory["status"][index])
    fig, ax = plt.subplots(figsize=(7, 7))
    for j in range(x.shape[1]):
        fly = status[:, j] == sim.FLYING
        ax.plot(x[fly, j, 0], x[fly, j, 1], lw=1, label=f"vehicle {j}")
    ax.plot(xi[present, 0], xi[present, 1], "k--", lw=2, label="intruder")
    ax.scatter(*np.asarray(params.targets).T, marker="x", c="grey")
    ax.set_aspect("equal")
    ax.set_title(title)
    ax.legend(fontsize=7)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def run_compare(args) -> None:
    params = assembly.params_for("town", sim.EnvConfig(), progress=False)
    kbar = int(params.kbar)
    n_steps = sim.steps_for(params)
    key = jax.random.PRNGKey(HELD_OUT_KEY)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    intruders = {args.intruder: load_intruder(args.intruder)}
    intruders.update({name: INTRUDERS[name] for name in args.scripted})
    for name, policy in intruders.items():
        start = time.perf_counter()
        forced, collisions, violations = [], [], []
        findings = []
        for first in range(0, args.episodes, args.batch):
            batch = min(args.batch, args.episodes - first)
            k = jax.random.fold_in(key, first)
            final, _ = sim.rollout(k, params, switching, policy, batch, n_steps)
            nf = np.asarray(jax.vmap(sim.n_forced)(final))
            gv = np.asarray(final.guarantee_violation).sum(axis=1)
            forced.append(nf)
            collisions.append((np.asarray(final.status) == sim.COLLIDED).sum(axis=1))
            violations.append(gv)
            for i in np.flatnonzero((gv > 0) | (nf > kbar)):
                findings.append({"batch_key": [HELD_OUT_KEY, first], "episode": int(i), "n_forced": int(nf[i]),
                                 "guarantee_violations": int(gv[i])})
                _, traj = sim.rollout(k, params, switching, policy, batch, n_steps, record=True)
                png = out / f"finding-{name}-{first}-{i}.png"
                plot_episode(params, traj, int(i), f"{name}: |N^RP| = {nf[i]}, violations = {gv[i]}", png)
                findings[-1]["plot"] = str(png)
        forced, collisions, violations = (np.concatenate(v) for v in (forced, collisions, violations))
        s = forced_summary(forced, kbar, collisions, violations)
        mean, half = s["forced_mean"], s["forced_ci95"]
        print(json.dumps({
            "intruder": name, "episodes": s["episodes"], "mean_n_forced": round(mean, 4),
            "ci95": [round(mean - half, 4), round(mean + half, 4)], "max_n_forced": s["forced_max"], "kbar": kbar,
            "episodes_above_kbar": s["exceed"], "episodes_above_kbar_upper": s["exceed_upper"],
            "collisions": s["collisions"], "guarantee_violations": s["guarantee_violations"],
            "violation_episodes_upper": s["violation_upper"], "findings": findings,
            "seconds": round(time.perf_counter() - start, 1)}))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    tr = sub.add_parser("train")
    tr.add_argument("--timesteps", type=int, default=None, help=f"default {SHIPPED.total_timesteps}")
    tr.add_argument("--out", default=None, help=f"default {SHIPPED.out_dir}")
    tr.add_argument("--ship", action="store_true", help="copy the result to stp_env/data/intruders/")
    co = sub.add_parser("compare")
    co.add_argument("--intruder", default="town-kbar2", help="shipped name or .npz path")
    co.add_argument("--scripted", nargs="*", default=["bezier3", "greedy", "max-k"], choices=list(INTRUDERS))
    co.add_argument("--episodes", type=int, default=1000)
    co.add_argument("--batch", type=int, default=250, help="episodes per compiled rollout")
    co.add_argument("--out", default="runs/compare", help="folder for the plots of findings")
    args = parser.parse_args(argv)
    if args.command == "train":
        run_train(args)
    else:
        run_compare(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

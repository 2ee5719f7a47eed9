"""Train the shipped learned intruder for ``town`` (k̄ = 2) and compare it with the random-Bezier intruder.

    python examples/train_intruder.py train [--timesteps N] [--out runs/town-kbar2] [--ship]
    python examples/train_intruder.py compare [--intruder town-kbar2] [--episodes 1000] [--out runs/compare]

``train`` runs :func:`stp_env.rl.train.train` with :data:`SHIPPED` (``--timesteps`` overrides the length) and
with ``--ship`` copies ``model.zip`` and ``intruder.npz`` to ``stp_env/data/intruders/town-kbar2.{zip,npz}``.
``compare`` evaluates the learned intruder and the scripted ones with the package's evaluator
(:func:`stp_env.evaluation.pipeline.run`: the vehicles on ``switching`` with the HJ safety filter, every intruder
spawned outside the avoid regions, a held-out seed) and prints one JSON line per intruder: mean and max
``|N^RP|`` against k̄, collisions and guarantee violations with their Clopper-Pearson bounds; a guarantee violation
or ``|N^RP| > k̄`` is a finding, saved replayable in ``--out/events.json`` with the results and figures.

Reproducibility: a run is deterministic given the seed and the code (same config in two processes: identical
rollouts and weights). After ``train --ship``, ``stp-env data ship-intruder runs/town-kbar2 town-kbar2``
records the small check that ``tests/test_learned_intruders.py`` replays (the same weights). The model card and the
comparison with the earlier shipped policy (PPO from scratch, 4.2 M steps): ``docs/learned_intruders.md``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
from pathlib import Path

from stp_env.policies import INTRUDERS
from stp_env.rl.train import TrainConfig, train

# forced_reward 5: one forced vehicle outweighs the shaping of a whole approach (shaping_reward * d_sense = 3.7).
# Started from a clone of the buffer game's intruder (optimal-max-k; the teacher reads V^B while cloning, the
# policy sees the core observation, so running it needs no buffer table), then PPO near the clone.
SHIPPED = TrainConfig(scenario="town", n_envs=256, n_steps=64, batch_size=4096, n_epochs=10, learning_rate=1e-4,
                      log_std_init=-1.5, forced_reward=5.0, collision_reward=10.0, shaping_reward=0.01,
                      kbar_reward=5.0, observation="core", clone="optimal-max-k", net_arch=(64, 64),
                      total_timesteps=524_288, seed=0, eval_every=131_072, eval_episodes=1024,
                      checkpoint_every=0, out_dir="runs/town-kbar2", log_formats=("stdout", "csv"))
HELD_OUT_SEED = 20_240_601  # compare's episodes: the evaluator's seed, not training's
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


def run_compare(args) -> None:
    """The learned intruder and the scripted ones through the package's evaluator
    (:func:`stp_env.evaluation.pipeline.run`: results, events and figures in ``--out``), one JSON line each."""
    from stp_env.evaluation.config import Configuration
    from stp_env.evaluation.pipeline import run

    specs = [f"learned:{args.intruder}", *args.scripted]
    # the default EnvConfig's spawn for every intruder (outside the avoid regions), the held-out seed
    configs = [Configuration(scenario="town", intruder=spec, spawn_mode="outside") for spec in specs]
    out = run(configs, args.out, episodes=args.episodes, seed=HELD_OUT_SEED, batch_size=args.batch)
    for spec, s in zip(specs, out["summaries"]):
        print(json.dumps({
            "intruder": spec, "episodes": s["episodes"], "mean_n_forced": s["forced_mean"],
            "max_n_forced": s["forced_max"], "kbar": s["kbar"], "episodes_above_kbar": s["exceed"],
            "episodes_above_kbar_upper": s["exceed_upper"], "collisions": s["collisions"],
            "guarantee_violations": s["guarantee_violations"], "violation_episodes_upper": s["violation_upper"],
            "findings": s["events_saved"], "seconds": out["seconds"]}))


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
    co.add_argument("--out", default="runs/compare", help="folder of the evaluation's results, events and figures")
    args = parser.parse_args(argv)
    if args.command == "train":
        run_train(args)
    else:
        run_compare(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())

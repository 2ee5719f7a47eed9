"""Ship a trained intruder: copy a run's ``intruder.npz`` into ``stp_env/data/intruders/NAME.npz`` with a recorded
check (the forced counts of a small batch of held-out episodes on the run's own environment), which
``tests/test_learned_intruders.py`` replays.

    python scripts/ship_learned_intruder.py RUN_DIR NAME [--episodes 64] [--seed 20240601] [--n-envs 64]

The run's settings (scenario, k̄, vehicle policy, spawn mode, wind model, observation set) are read from its
``intruder.npz`` metadata; the check runs :func:`stp_env.rl.train.evaluate_on_vec_env` with the numpy copy of the
policy (:meth:`stp_env.policies.learned.MLPIntruder.action_numpy`), as the test does. Nothing is written unless
the whole check ran; the file is written atomically.
"""

from __future__ import annotations

import argparse
import json
import sys
from importlib import resources
from pathlib import Path

import numpy as np

from stp_env.files import atomic_open
from stp_env.loaders import read_npz
from stp_env.policies.learned import load_mlp
from stp_env.progress import note
from stp_env.rl.train import TrainConfig, build_params, evaluate_on_vec_env
from stp_env.rl.vec_env import IntruderVecEnv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a finished train-intruder run (its intruder.npz) or the .npz")
    ap.add_argument("name", help="the shipped name (stp_env/data/intruders/NAME.npz; learned:NAME loads it)")
    ap.add_argument("--episodes", type=int, default=64)
    ap.add_argument("--seed", type=int, default=20_240_601)
    ap.add_argument("--n-envs", type=int, default=64)
    args = ap.parse_args(argv)
    if not args.name.replace("-", "").isalnum():
        raise SystemExit(f"the name is letters, digits and '-'; got {args.name!r}.")
    path = args.run / "intruder.npz" if args.run.is_dir() else args.run
    mlp = load_mlp(path)
    meta = mlp.metadata
    config = TrainConfig(scenario=meta["scenario"], kbar=meta["kbar"], vehicle_policy=meta["vehicle_policy"],
                         spawn_mode=meta["spawn_mode"], wind_model=meta.get("wind_model", "uniform"),
                         backend=meta.get("backend", "jax"), control_dt=meta.get("control_dt"),
                         avoid_margin=meta.get("avoid_margin"),
                         observation=mlp.observation, n_envs=args.n_envs)
    note(f"checking {path} on {args.episodes} held-out {config.scenario} episodes", True)
    params = build_params(config, progress=True)
    venv = IntruderVecEnv(args.n_envs, params=params, horizon=meta["horizon"], vehicle_policy=meta["vehicle_policy"],
                          observation=mlp.observation)
    result = evaluate_on_vec_env(mlp.action_numpy, venv, args.episodes, args.seed)
    check = {"episodes": args.episodes, "seed": args.seed, "n_envs": args.n_envs,
             "n_forced": [int(v) for v in result["n_forced"]]}
    arrays = read_npz(path, "learned-policy")
    meta = {**meta, "check": check}
    target = Path(str(resources.files("stp_env") / "data" / "intruders" / f"{args.name}.npz"))
    with atomic_open(target, "wb") as fh:
        np.savez(fh, **{k: v for k, v in arrays.items() if k != "metadata"},
                 metadata=np.asarray(json.dumps(meta, sort_keys=True)))
    print(json.dumps({"shipped": str(target), "check_mean_n_forced": float(np.mean(check["n_forced"]))}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

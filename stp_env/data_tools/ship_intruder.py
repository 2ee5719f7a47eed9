"""``stp-env data ship-intruder``: ship a trained intruder: copy a run's ``intruder.npz`` into
``stp_env/data/intruders/NAME.npz`` (a source checkout), or to ``--out``, with a recorded check (the forced counts
of a small batch of held-out episodes on the run's own environment), which ``tests/test_learned_intruders.py``
replays for the shipped ones.

    stp-env data ship-intruder RUN_DIR NAME [--episodes 64] [--seed 20240601] [--n-envs 64]
    stp-env data ship-intruder RUN_DIR NAME --out checked/NAME.npz       # an installed package: a file of your own

The run's settings (scenario, k̄, vehicle policy, spawn mode, wind model, observation set) are read from its
``intruder.npz`` metadata; the check runs :func:`stp_env.rl.train.evaluate_on_vec_env` with the numpy copy of the
policy (:meth:`stp_env.policies.learned.MLPIntruder.action_numpy`), as the test does. Nothing is written unless
the whole check ran; the file is written atomically. Writing into the package (no ``--out``) is refused outside a
source checkout (:func:`stp_env.data_tools.shipping.checkout_data`); a file written to ``--out`` loads as
``learned:PATH``.
"""

from __future__ import annotations

import json
from pathlib import Path

from stp_env import cli_kit as kit
from stp_env.data_tools import description, shipping


def add_parser(sub) -> None:
    """Add ``ship-intruder`` to the ``stp-env data`` subcommands (building it imports no JAX)."""
    p = sub.add_parser("ship-intruder", help="check a trained intruder on held-out episodes and ship it (into "
                                             "stp_env/data/intruders, or to --out)",
                       formatter_class=kit.HelpFormatter, description=description(__doc__))
    p.add_argument("run_dir", metavar="RUN", type=Path,
                   help="a finished train-intruder run (its intruder.npz) or the .npz")
    p.add_argument("name", help="the shipped name (stp_env/data/intruders/NAME.npz; learned:NAME loads it)")
    p.add_argument("--episodes", type=kit.positive_int, default=64, help="held-out episodes of the check")
    p.add_argument("--seed", type=kit.seed(), default=20_240_601, help="seed of the check's episodes")
    p.add_argument("--n-envs", type=kit.positive_int, default=64, help="environments of the check's batched VecEnv")
    p.add_argument("--out", type=Path, default=None,
                   help="write the checked file here instead of into the package (which only a source checkout "
                        "does)")
    p.set_defaults(run=run, command="data ship-intruder")


def run(args) -> int:
    """Run ``stp-env data ship-intruder``: one JSON line naming the file written."""
    import numpy as np

    from stp_env.files import atomic_open
    from stp_env.loaders import read_npz
    from stp_env.policies.learned import load_mlp
    from stp_env.progress import note
    from stp_env.rl.train import TrainConfig, build_params, evaluate_on_vec_env
    from stp_env.rl.vec_env import IntruderVecEnv

    if not args.name.replace("-", "").isalnum():
        raise ValueError(f"the name is letters, digits and '-'; got {args.name!r}.")
    if args.out is None:
        target = shipping.checkout_data(shipping.INTRUDERS, "shipping a learned intruder",
                                        "write it elsewhere with --out FILE") / f"{args.name}.npz"
    else:
        target = args.out
        if target.is_dir() or not target.parent.is_dir():
            raise ValueError(f"--out {target}: expected a file name in an existing directory.")
    path = args.run_dir / "intruder.npz" if args.run_dir.is_dir() else args.run_dir
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
    with atomic_open(target, "wb") as fh:
        np.savez(fh, **{k: v for k, v in arrays.items() if k != "metadata"},
                 metadata=np.asarray(json.dumps(meta, sort_keys=True)))
    print(json.dumps({"shipped": str(target), "check_mean_n_forced": float(np.mean(check["n_forced"]))}))
    return 0

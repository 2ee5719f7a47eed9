"""The ``train-intruder`` subcommand: train a learned intruder (Stable-Baselines3's PPO on the native batched VecEnv,
or PPO in JAX) against vehicles running ``u*`` with the HJ safety filter (:mod:`stp_env.rl.train`,
:mod:`stp_env.rl.trainers`); one run, or a sweep over seeds and a grid of settings (:mod:`stp_env.rl.sweep`)."""

from __future__ import annotations

import argparse
import json

from stp_env import cli_kit as kit
from stp_env.resources import EPISODE_BYTES, MAX_N_ENVS


def backend(text: str) -> str:
    """A plant backend spec (:func:`stp_env.sim.backends.vehicle_model` checks it; imported only when given)."""
    from stp_env.sim.backends import vehicle_model

    try:
        vehicle_model(text)
    except (ValueError, ImportError) as err:
        raise argparse.ArgumentTypeError(str(err)) from None
    return text


def add_parser(sub) -> None:
    """Add the ``train-intruder`` subcommand to an argparse subparsers object (building it imports no JAX)."""
    from stp_env.seeds import MAX_SEED_32

    tr = sub.add_parser("train-intruder", help="train a learned intruder with Stable-Baselines3 (needs the rl extra)",
                        formatter_class=kit.HelpFormatter,
                        description="PPO (or A2C) on stp_env.rl.IntruderVecEnv: the vehicles run --vehicle-policy "
                                    "(u* with the HJ safety filter by default); the intruder is rewarded per vehicle "
                                    "forced to avoid (eq. 39), per collision, and by the avoid-region value "
                                    "(shaping).")
    kit.add_scenario(tr, "town")
    tr.add_argument("--kbar", type=kit.kbar, default=None,
                    help=f"k̄ of the scenario's plan (1-{kit.MAX_KBAR}; default: the scenario's own)")
    tr.add_argument("--trainer", choices=["sb3", "jax"], default="sb3",
                    help="sb3: Stable-Baselines3 on the batched VecEnv (the rl extra); jax: PPO in JAX on the gymnax "
                         "view, each iteration's rollout and updates one compiled program, one device per core by "
                         "default (the jax-rl extra; PPO from a fresh network only)")
    tr.add_argument("--resume", action="store_true",
                    help="with --trainer jax: continue from OUT/checkpoints/runner.npz if the same configuration "
                         "wrote it (a longer --timesteps continues the run)")
    tr.add_argument("--algo", choices=["ppo", "a2c"], default="ppo",
                    help="the Stable-Baselines3 algorithm: ppo (proximal policy optimisation) or a2c (advantage "
                         "actor-critic)")
    tr.add_argument("--timesteps", type=kit.positive_int, default=2_000_000,
                    help="total environment steps of training [steps]")
    tr.add_argument("--n-envs", type=kit.in_memory(EPISODE_BYTES, "environment", MAX_N_ENVS), default=64,
                    help="environments in the batched VecEnv (at most 2**20, and as many as the memory available "
                         "holds)")
    tr.add_argument("--n-steps", type=kit.positive_int, default=128,
                    help="steps per environment per rollout [steps]")
    tr.add_argument("--minibatch-size", dest="batch_size", type=kit.positive_int, default=2048, metavar="N",
                    help="PPO minibatch: transitions per gradient step (not the episodes of a batch as in "
                         "`evaluate`)")
    tr.add_argument("--n-epochs", type=kit.integer(1, 1000), default=10, help="PPO: passes over each rollout")
    tr.add_argument("--learning-rate", type=kit.real(1e-9, 1.0), default=3e-4, help="the optimiser's step size")
    tr.add_argument("--log-std-init", type=kit.real(-20.0, 5.0), default=0.0,
                    help="initial log standard deviation of the Gaussian actions (lower after --clone keeps PPO's "
                         "exploration near the clone)")
    kit.add_seed(tr, "torch, SB3 and the JAX environment keys", maximum=MAX_SEED_32)
    tr.add_argument("--horizon", choices=["intruder", "episode"], default="intruder",
                    help="intruder: appearance to departure; episode: the core's whole episode")
    tr.add_argument("--vehicle-policy", type=kit.vehicle_policy_spec, default="switching", metavar="POLICY",
                    help="the vehicles' policy (worst: the buffer game's worst vehicles, as in `evaluate`; "
                         "learned:NAME_OR_PATH: a learned vehicle policy inside the HJ filters)")
    tr.add_argument("--spawn-mode", choices=kit.spawn_modes(), default="outside",
                    help="where the intruder appears: outside every avoid region, on a vehicle's avoid boundary "
                         "(where the max-k intruders start), or either")
    kit.add_wind_model(tr, "uniform", "how each agent's wind in its disk is drawn")
    tr.add_argument("--backend", type=backend, default="jax", metavar="BACKEND[:PARAM=VALUE,...]",
                    help="the vehicles' plant: jax (the papers' Dubins model) or pymunk-dynamic[:param=value,...] "
                         "(a rigid body with actuator lag, where the tracking bound does not hold)")
    tr.add_argument("--avoid-margin", type=kit.real(0.0, 1e4), default=None,
                    help="the safety filter's avoid margin [m] (default: the certified one of the filter period; "
                         "below it is uncertified)")
    tr.add_argument("--control-dt", type=kit.real(1e-4, 1.0), default=None,
                    help="the vehicles' tracker and safety filter period [s] (default: the certified 0.02 s; "
                         "another value is uncertified: collisions then count as assumption failures)")
    tr.add_argument("--forced-reward", type=kit.real(-1e6, 1e6), default=5.0,
                    help="reward per vehicle newly forced to avoid")
    tr.add_argument("--collision-reward", type=kit.real(-1e6, 1e6), default=10.0,
                    help="reward per collision the intruder causes")
    tr.add_argument("--shaping-reward", type=kit.real(-1e6, 1e6), default=0.01,
                    help="reward times the decrease of min V^A over unforced vehicles [per m]")
    tr.add_argument("--kbar-reward", type=kit.real(-1e6, 1e6), default=0.0,
                    help="reward once when the k̄-th vehicle is forced (on top of --forced-reward)")
    tr.add_argument("--observation", choices=["core", "game"], default="core",
                    help="what the intruder sees: core (the nearest vehicles, their V^A and forced flags) or game "
                         "(and the buffer game's features: the unforced vehicles ranked by V^B, the hop heading to "
                         "each; loads V^B)")
    tr.add_argument("--clone", choices=kit.intruder_names(),
                    default=None, metavar="INTRUDER",
                    help="start from a scripted intruder (e.g. optimal-max-k): clone its actions (with DAgger "
                         "rounds) and fit the critic to its returns before PPO")
    tr.add_argument("--clone-steps", type=kit.positive_int, default=200,
                    help="with --clone: steps of every environment recorded per round [steps]")
    tr.add_argument("--clone-rounds", type=kit.count, default=2, help="with --clone: DAgger rounds after the first fit")
    tr.add_argument("--eval-every", type=kit.count, default=200_000,
                    help="environment steps between evaluations [steps]")
    tr.add_argument("--eval-episodes", type=kit.positive_int, default=256, help="held-out episodes per evaluation")
    tr.add_argument("--checkpoint-every", type=kit.count, default=500_000,
                    help="environment steps between checkpoints [steps] (0: none)")
    tr.add_argument("--tensorboard", action="store_true", help="also write TensorBoard logs")
    tr.add_argument("--seeds", type=kit.integer(0, MAX_SEED_32), nargs="+", default=None, metavar="SEED",
                    help="a sweep: one run per seed, into OUT/seed-SEED/, gathered in OUT/sweep.json (with --ray "
                         "the runs are Ray tasks; a killed sweep resumes); replaces --seed")
    tr.add_argument("--grid", action="append", default=None, metavar="FIELD=V1,V2",
                    help="with --seeds: also sweep a training setting (a TrainConfig field, e.g. "
                         "learning_rate=1e-4,3e-4; repeat for a product), runs in OUT/FIELD=V/seed-SEED/")
    kit.add_ray(tr, "the sweep's runs (with --seeds)")
    kit.add_cpu_devices(tr, unset=1, note=" (at the default 64 environments two devices gained nothing on 2 cores; "
                                          "PPO's data collection at 256-512 ran 1.2-1.4x as fast)")
    kit.add_out(tr, "runs/intruder")
    tr.set_defaults(run=run)


def run(args) -> int:
    """Run ``stp-env train-intruder`` (one training, or a sweep over seeds and a grid)."""
    missing = _missing_trainer_modules(args.trainer)
    if missing:
        extra = "rl" if args.trainer == "sb3" else "jax-rl"
        raise ValueError(f"train-intruder --trainer {args.trainer} needs the {extra} extra (pip install "
                         f"'stp-env[{extra}]'): {', '.join(missing)} not installed.")
    if args.resume and args.trainer != "jax":
        raise ValueError("--resume continues a --trainer jax run (SB3 runs keep checkpoints/ of their own).")
    if args.trainer == "jax" and args.cpu_devices is None:
        args.cpu_devices_unset = "auto"  # the JAX trainer shares its batch among the cores
    if (args.ray or args.ray_address or args.grid) and args.seeds is None:
        raise ValueError("--ray and --grid belong to a sweep: give the seeds with --seeds SEED [SEED ...].")
    from stp_env.rl import sweep

    grid = sweep.parse_grid(args.grid or [])
    if args.seeds is not None:
        sweep.check_sweep_size(args.seeds, grid)

    from stp_env.evaluation.pipeline import check_output_dir
    from stp_env.rl.train import TrainConfig
    from stp_env.rl.trainers import train

    check_output_dir(args.out)
    sweep.check_grid_fields(grid, TrainConfig)
    kit.apply_cpu_devices(args)  # before JAX's first computation
    executor = kit.executor(args) if args.seeds is not None else None  # --ray without ray installed fails here
    formats = ("stdout", "csv", "tensorboard") if args.tensorboard else ("stdout", "csv")
    config = TrainConfig(scenario=args.scenario, kbar=args.kbar, algo=args.algo, total_timesteps=args.timesteps,
                         n_envs=args.n_envs, n_steps=args.n_steps, batch_size=args.batch_size, seed=args.seed,
                         n_epochs=args.n_epochs, trainer=args.trainer,
                         learning_rate=args.learning_rate, log_std_init=args.log_std_init,
                         horizon=args.horizon, vehicle_policy=args.vehicle_policy, spawn_mode=args.spawn_mode,
                         wind_model=args.wind_model, backend=args.backend, control_dt=args.control_dt,
                         avoid_margin=args.avoid_margin,
                         forced_reward=args.forced_reward,
                         collision_reward=args.collision_reward, shaping_reward=args.shaping_reward,
                         kbar_reward=args.kbar_reward, observation=args.observation, clone=args.clone,
                         clone_steps=args.clone_steps, clone_rounds=args.clone_rounds,
                         eval_every=args.eval_every, eval_episodes=args.eval_episodes,
                         checkpoint_every=args.checkpoint_every, out_dir=args.out, log_formats=formats)
    if args.seeds is not None:
        from stp_env.rl.sweep import sweep

        histories = sweep(config, args.seeds, grid=grid, executor=executor)
        print(json.dumps({"final": {(k if isinstance(k, int) else f"{k[0]} seed {k[1]}"): h[-1]
                                    for k, h in histories.items()}, "out": f"{args.out}/sweep.json"}, default=str))
        return 0
    _, history = train(config, resume=args.resume)
    print(json.dumps({**history[-1], "out": args.out}))
    return 0


def _missing_trainer_modules(trainer: str) -> list[str]:
    import importlib.util

    names = ("stable_baselines3", "torch") if trainer == "sb3" else ("gymnax", "optax")
    return [name for name in names if importlib.util.find_spec(name) is None]

"""PPO training throughput, the whole loop (rollouts and updates): the JAX trainer against Stable-Baselines3, same
scenario, settings and machine, in one run.

    python benchmarks/jax_ppo_throughput.py --scenario town
    python benchmarks/jax_ppo_throughput.py --scenario crossing --kbar 2 --vehicle-policy worst \\
        --spawn-mode boundary --observation game

Each case runs in its own process (the CPU device count is fixed when JAX starts), ``--rounds`` times, alternating
``sb3`` and ``jax``, and prints one JSON line per case and round, then the ratio line (medians over rounds):

* ``sb3``: :func:`stp_env.rl.ppo.make_model` on :class:`stp_env.rl.IntruderVecEnv` (what ``stp-env
  train-intruder`` trains; torch on one thread, the VecEnv's batch on ``--sb3-cpu-devices`` devices, one by
  default as the command runs it), ``model.learn`` of ``--sb3-iterations`` rollouts after one warm-up rollout
  that compiles the VecEnv's programs;
* ``jax``: :mod:`stp_env.rl.jax_ppo` on :class:`stp_env.rl.gymnax_env.IntruderGymnaxEnv` (one device per core),
  ``--jax-iterations`` iterations after the first, which compiles;
* ``jax_env_only`` (``--env-only``): the JAX trainer's rollouts without the updates, the ceiling of its loop.

Both run PPO with the same numbers: ``--n-envs`` x ``--n-steps`` per rollout, ``--n-epochs`` passes in minibatches
of ``--batch-size``, a 64 x 64 tanh actor and critic. ``steps_per_s`` counts environment steps (one intruder
transition each) per second of the whole loop.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time


def config_of(args):
    from stp_env.rl.train import TrainConfig

    return TrainConfig(scenario=args.scenario, kbar=args.kbar, vehicle_policy=args.vehicle_policy,
                       spawn_mode=args.spawn_mode, observation=args.observation, wind_model=args.wind_model,
                       n_envs=args.n_envs, n_steps=args.n_steps, batch_size=args.batch_size, n_epochs=args.n_epochs,
                       eval_every=0, checkpoint_every=0, seed=0)


def run_sb3(args) -> dict:
    import torch

    torch.set_num_threads(1)
    from stable_baselines3.common.vec_env import VecMonitor

    from stp_env.rl.ppo import make_model
    from stp_env.rl.train import build_params
    from stp_env.rl.vec_env import IntruderVecEnv

    config = config_of(args)
    params = build_params(config)
    venv = VecMonitor(IntruderVecEnv(config.n_envs, params=params, horizon=config.horizon,
                                     vehicle_policy=config.vehicle_policy, observation=config.observation))
    model = make_model(config, venv)
    rollout = config.n_envs * config.n_steps
    t0 = time.perf_counter()
    model.learn(total_timesteps=rollout)  # compiles the VecEnv's reset and step
    warmup = time.perf_counter() - t0
    t0 = time.perf_counter()
    model.learn(total_timesteps=rollout * args.sb3_iterations, reset_num_timesteps=False)
    seconds = time.perf_counter() - t0
    return {"steps": rollout * args.sb3_iterations, "seconds": round(seconds, 2), "warmup_s": round(warmup, 1),
            "steps_per_s": round(rollout * args.sb3_iterations / seconds)}


def run_jax(args, env_only: bool) -> dict:
    import jax

    from stp_env.rl import jax_ppo
    from stp_env.rl.jax_train import make_env
    from stp_env.rl.train import build_params
    from stp_env.rl.vec_env import STAT_NAMES

    config = config_of(args)
    params = build_params(config)
    env = make_env(config, params)
    settings = jax_ppo.PPOSettings.of(config)
    if env_only:  # no update: the same rollout, the policy unchanged
        settings = jax_ppo.PPOSettings(**{**settings.__dict__, "n_epochs": 0})
    runner = jax_ppo.init_runner(jax.random.PRNGKey(0), env, params, settings, config.net_arch, config.log_std_init)
    step, runner = jax_ppo.compile_iteration(jax_ppo.make_iteration(env, settings, STAT_NAMES,
                                                                    kbar=int(params.intruder.kbar)),
                                             runner, config.n_envs)
    whole = jax_ppo.replicated(config.n_envs)
    env_params = params if whole is None else jax.device_put(params, whole)
    t0 = time.perf_counter()
    runner, m = step(runner, env_params)
    jax.block_until_ready(m)
    warmup = time.perf_counter() - t0
    t0 = time.perf_counter()
    for _ in range(args.jax_iterations):
        runner, m = step(runner, env_params)
    jax.block_until_ready((runner, m))
    seconds = time.perf_counter() - t0
    steps = settings.rollout * args.jax_iterations
    return {"steps": steps, "seconds": round(seconds, 2), "warmup_s": round(warmup, 1),
            "steps_per_s": round(steps / seconds), "devices": len(jax.devices())}


def child(args) -> None:
    from stp_env import set_cpu_devices
    from stp_env.cpu_threads import available_cores

    set_cpu_devices(args.sb3_cpu_devices if args.case == "sb3" else available_cores())
    out = run_sb3(args) if args.case == "sb3" else run_jax(args, args.case == "jax_env_only")
    print(json.dumps(out))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--kbar", type=int, default=None)
    parser.add_argument("--vehicle-policy", default="switching")
    parser.add_argument("--spawn-mode", default="outside")
    parser.add_argument("--wind-model", default="uniform")
    parser.add_argument("--observation", default="core", choices=["core", "game"])
    parser.add_argument("--n-envs", type=int, default=256)
    parser.add_argument("--n-steps", type=int, default=64)
    parser.add_argument("--batch-size", type=int, default=4096)
    parser.add_argument("--n-epochs", type=int, default=10)
    parser.add_argument("--sb3-iterations", type=int, default=4)
    parser.add_argument("--jax-iterations", type=int, default=20)
    parser.add_argument("--sb3-cpu-devices", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--env-only", action="store_true", help="also time the JAX rollouts without updates")
    parser.add_argument("--case", choices=["sb3", "jax", "jax_env_only"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        child(args)
        return
    passed = [a for a in sys.argv[1:]]
    cases = ["sb3", "jax", *(["jax_env_only"] if args.env_only else [])]
    rates = {c: [] for c in cases}
    common = {"scenario": args.scenario, "vehicle_policy": args.vehicle_policy, "observation": args.observation,
              "n_envs": args.n_envs, "n_steps": args.n_steps, "batch_size": args.batch_size,
              "n_epochs": args.n_epochs, "cpu_count": os.cpu_count()}
    for r in range(args.rounds):
        for case in cases:
            load = round(os.getloadavg()[0], 2)
            done = subprocess.run([sys.executable, __file__, *passed, "--case", case], capture_output=True,
                                  text=True, check=False)
            if done.returncode:
                sys.stderr.write(done.stderr[-4000:])
                raise SystemExit(f"case {case} failed")
            result = json.loads(done.stdout.strip().splitlines()[-1])
            rates[case].append(result["steps_per_s"])
            print(json.dumps({"case": case, "round": r, **result, **common, "load_avg_1min": load}), flush=True)
    median = {c: statistics.median(v) for c, v in rates.items()}
    line = {"case": "ratio", "jax_over_sb3": round(median["jax"] / median["sb3"], 2),
            "median_steps_per_s": median}
    if args.env_only:
        line["env_only_over_sb3"] = round(median["jax_env_only"] / median["sb3"], 2)
    print(json.dumps(line))


if __name__ == "__main__":
    main()

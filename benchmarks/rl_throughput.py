"""PPO data-collection throughput: the native batched VecEnv against the PettingZoo + SuperSuit route, same run.

    python benchmarks/rl_throughput.py [--n-envs 512] [--rollout-steps 64] [--peer-copies 4] [--repeats 3]
    python benchmarks/rl_throughput.py --scenario crossing --kbar 2 --vehicle-policy worst --spawn-mode boundary \
        --observation game --n-envs 256 --rollout-steps 64     # a training run's settings (docs/learned_intruders.md)

Times ``PPO.collect_rollouts`` (the policy forward pass, the env steps and the rollout buffer; no gradient
updates) after one warm-up rollout that compiles the JAX programs, and prints one JSON line per case:

* ``native``: :class:`stp_env.rl.IntruderVecEnv` (``n_envs`` intruder envs; the vehicles run ``switching``
  inside the core). One env step is one core step.
* ``supersuit``: ``stp_env.env.parallel_env()`` through ``pad_observations_v0``, ``black_death_v3``,
  ``pettingzoo_env_to_vec_env_v1``
  and ``concat_vec_envs_v1`` (``peer-copies`` copies, ``num_cpus=0``), i.e. one SB3 "env" per agent
  (7 vehicles + the intruder), all driven by PPO. One core step is ``n_agents`` agent-steps.
  Where SuperSuit cannot wrap the env (it refuses agents that come and go: ``docs/training.md``), or is not
  installed, the peer is ``DummyVecEnv`` over :class:`stp_env.rl.IntruderEnv` with the same settings, and a
  ``note`` line says why.
* ``native_core`` (with ``--observation game``): the native VecEnv with the core observation, to price the game
  features.

``--cpu-devices N``: JAX's CPU split into ``N`` devices before JAX starts (:func:`stp_env.set_cpu_devices`), the
native VecEnv's batch shared among them; ``--native-only`` skips the peer.

``env_steps_per_s`` counts core steps (one simulated step of one scenario copy), ``agent_steps_per_s`` the
transitions PPO stores. The ratio line compares env steps per second.
"""

from __future__ import annotations

import argparse
import json
import os
import time

import torch
from stable_baselines3 import PPO
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.utils import set_random_seed
from stable_baselines3.common.vec_env import DummyVecEnv

from stp_env.rl import IntruderEnv, IntruderVecEnv


def collection_rate(venv, rollout_steps: int, repeats: int, agents_per_env_step: int, seed: int | None) -> dict:
    """Steps per second of ``PPO.collect_rollouts`` on ``venv`` (best of ``repeats`` after a warm-up)."""
    set_random_seed(0)
    model = PPO("MlpPolicy", venv, n_steps=rollout_steps, batch_size=rollout_steps * venv.num_envs, seed=seed,
                device="cpu", policy_kwargs={"net_arch": [64, 64]})
    callback = CallbackList([])
    model._setup_learn(total_timesteps=10**9, callback=callback)
    callback.init_callback(model)
    times = []
    for _ in range(repeats + 1):
        start = time.perf_counter()
        model.collect_rollouts(model.env, callback, model.rollout_buffer, n_rollout_steps=rollout_steps)
        times.append(time.perf_counter() - start)
    best = min(times[1:])
    transitions = rollout_steps * venv.num_envs
    return {"agent_steps_per_s": round(transitions / best), "env_steps_per_s": round(transitions / best /
                                                                                       agents_per_env_step),
            "warmup_s": round(times[0], 1), "rollout_s": round(best, 3), "transitions_per_rollout": transitions}


def peer(params, copies: int, env_kwargs: dict):
    def dummy(why):
        print(json.dumps({"note": f"SuperSuit route unavailable ({why}); peer is DummyVecEnv over IntruderEnv"}))
        venv = DummyVecEnv([lambda: IntruderEnv(params=params, **env_kwargs) for _ in range(copies)])
        venv.seed(0)
        return "dummy_vec_env", venv, 1, 0

    try:
        import supersuit as ss

        from stp_env.env import parallel_env
    except ImportError as err:
        return dummy(err)
    try:
        env = ss.black_death_v3(ss.pad_observations_v0(parallel_env(params=params)))
        n_agents = len(env.possible_agents)
        venv = ss.concat_vec_envs_v1(ss.pettingzoo_env_to_vec_env_v1(env), copies, num_cpus=0,
                                     base_class="stable_baselines3")
        venv.venv.reset(seed=0)  # SB3 2.9: PPO(seed=...) and venv.reset(seed=...) call ConcatVecEnv.seed (missing)
    except Exception as err:  # SuperSuit's refusal is the finding to report, whatever its type
        return dummy(f"{type(err).__name__}: {err}")
    return "supersuit", venv, n_agents, None


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--n-envs", type=int, default=512)
    parser.add_argument("--rollout-steps", type=int, default=64)
    parser.add_argument("--peer-copies", type=int, default=4)
    parser.add_argument("--peer-rollout-steps", type=int, default=128)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--scenario", default="town")
    parser.add_argument("--kbar", type=int, default=None)
    parser.add_argument("--vehicle-policy", default="switching")
    parser.add_argument("--spawn-mode", default="outside")
    parser.add_argument("--wind-model", default="uniform")
    parser.add_argument("--observation", default="core", choices=["core", "game"])
    parser.add_argument("--cpu-devices", type=int, default=1)
    parser.add_argument("--native-only", action="store_true")
    args = parser.parse_args()
    from stp_env import set_cpu_devices

    set_cpu_devices(args.cpu_devices)  # before JAX's first computation
    torch.set_num_threads(1)
    from stp_env.rl.train import TrainConfig, build_params

    config = TrainConfig(scenario=args.scenario, kbar=args.kbar, vehicle_policy=args.vehicle_policy,
                         spawn_mode=args.spawn_mode, wind_model=args.wind_model, observation=args.observation)
    params = build_params(config)
    env_kwargs = {"vehicle_policy": args.vehicle_policy, "observation": args.observation}
    common = {"scenario": args.scenario, "vehicle_policy": args.vehicle_policy, "observation": args.observation,
              "cpu_count": os.cpu_count(), "cpu_devices": args.cpu_devices,
              "load_avg_1min": round(os.getloadavg()[0], 2)}
    native = collection_rate(IntruderVecEnv(args.n_envs, params=params, **env_kwargs), args.rollout_steps,
                             args.repeats, 1, 0)
    print(json.dumps({"case": "native", "n_envs": args.n_envs, **native, **common}))
    if args.observation != "core":
        core = collection_rate(IntruderVecEnv(args.n_envs, params=params, **{**env_kwargs, "observation": "core"}),
                               args.rollout_steps, args.repeats, 1, 0)
        print(json.dumps({"case": "native_core", "n_envs": args.n_envs, **core, **common}))
        print(json.dumps({"case": "ratio", "game_over_core_observation": round(native["env_steps_per_s"] /
                                                                               core["env_steps_per_s"], 2)}))
    if args.native_only:
        return
    name, venv, n_agents, seed = peer(params, args.peer_copies, env_kwargs)
    other = collection_rate(venv, args.peer_rollout_steps, args.repeats, n_agents, seed)
    print(json.dumps({"case": name, "copies": args.peer_copies, "agents_per_copy": n_agents, **other, **common}))
    print(json.dumps({"case": "ratio", "native_over_" + name: round(native["env_steps_per_s"] /
                                                                   other["env_steps_per_s"], 1),
                      "native_agent_steps_over_peer_agent_steps": round(native["agent_steps_per_s"] /
                                                                        other["agent_steps_per_s"], 1)}))


if __name__ == "__main__":
    main()

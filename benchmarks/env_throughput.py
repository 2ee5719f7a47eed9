"""Environment throughput: the PettingZoo adapter and the batched core, side by side with mpe2's simple_tag_v3.

    python benchmarks/env_throughput.py [--scenario city] [--adapter-steps 5000] [--envs 1024] [--long 100000]

Prints one JSON line. Measured in the same run:

* ``mpe2_env_steps_per_s``: mpe2 ``simple_tag_v3.parallel_env()`` (4 agents), random actions (the peer). It and
  the two adapter loops below take turns (``--rounds``, each time a share of the steps), so the load the machine
  had is shared among them; ``*_over_mpe2`` is the ratio of the rates over all rounds, ``*_over_mpe2_per_round``
  the ratio within each round.
* ``adapter_env_steps_per_s``: :func:`stp_env.env.parallel_env` on the scenario, the vehicles driven by the
  baseline controllers (``switching``, eq. 38, computed from the core state in one jitted call per step that also
  splits the key) and a random intruder, i.e. what a user's ``env.step`` loop with baseline agents costs.
* ``adapter_builtin_env_steps_per_s``: the same with the vehicles flown inside the step
  (``parallel_env(vehicle_policy="switching")``, one jitted call per step), as when training an intruder.
* ``core_env_steps_per_s`` / ``core_agent_steps_per_s``: :func:`stp_env.sim.rollout` over ``--envs`` episodes
  (``switching`` vehicles, HJ-pursuit intruder), compile excluded.
* ``--long N``: N adapter steps (zero actions, auto-reset), peak RSS growth and step-function traces.
* ``--cpu-threads N``: XLA's CPU thread pools sized ``N`` before JAX starts (:mod:`stp_env.cpu_threads`; default:
  one per core). One thread is the setting for a loop over one environment, every core the one for the batched
  core, so the adapter's and the core's figures are each read from the run with their setting
  (``cpu_threads`` in the output says which run it is).
* ``--state-reads``: a fourth runner, the built-in loop reading ``env.env_state`` before every step;
  ``env_state_read_us_per_step`` is what the read adds to a step (the median over the rounds of the difference of
  the two loops' step times within a round).
* ``--floors``: two more runners, the device calls of each adapter loop with nothing of PettingZoo around them
  (``outside_floor``: the user's policy call and the step returning the state; ``builtin_floor``: the step alone;
  each output fetched as ``env.step`` fetches it). ``*_floor_over_mpe2`` is the most the matching loop could reach
  here if the Python around its calls cost nothing: an aim above it is out of reach of the adapter's own code.
  A third, ``outside_python``, runs the outside-actions loop with both calls answered by stored results (its
  Python alone, ``outside_python_us_per_step``); ``outside_ceiling_over_mpe2`` adds the two per-step times: the
  loop's rate if the calls and the Python cost what they cost alone (in the loop they cost more: the host reads
  what the other core wrote, ``BENCHMARKS.md``). ``--floor-gap-us G``: the floor runners busy-wait ``G`` us after
  each step, standing in for the loop's Python between its calls (XLA's threads park in such a gap and the next
  call wakes them); ``outside_ceiling_over_mpe2`` is then the outside floor's own ratio (the wait included), the
  rate the loop reaches at best when its Python takes ``G`` us.
* ``--pin-core``: the process held to one core (``os.sched_setaffinity``, as ``taskset -c 0 python ...``), so
  that XLA's thread and the caller share it (``cores`` in the output).
* ``--sync-dispatch``: JAX's CPU computations run on the calling thread, the caller waiting for each
  (``jax_cpu_enable_async_dispatch`` off; ``cpu_async_dispatch`` in the output). By default a computation is
  handed to XLA's thread and the caller reads its outputs when they are ready; at batch one the outputs then come
  from another core's memory (``BENCHMARKS.md`` has what it changes).
* ``--cpu-devices N``: JAX's CPU backend split into ``N`` devices (:func:`stp_env.set_cpu_devices`); the core's
  batch is then shared among them (:func:`stp_env.sim.engine.across_devices`), the adapter runs on the first.

Both scenarios fly their shipped STP plans (``stp_env/data/plans``; the city's is BEACLS Case 0, 50 vehicles).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

import jax
import numpy as np


def _params(name: str):
    from stp_env import assembly, sim
    from stp_env.scenarios import make

    scenario = make(name)
    avoid, tracking = assembly.load_artifacts(scenario, progress=False)
    plan = assembly.load_plan(scenario, tracking_bound=tracking.bound, progress=False)  # the shipped plan
    return scenario, assembly.make_params(scenario, plan, avoid, tracking, sim.EnvConfig())


def mpe2_runner():
    """``run(n) -> seconds`` for ``n`` steps of mpe2's ``simple_tag_v3`` with random actions."""
    from mpe2 import simple_tag_v3

    env = simple_tag_v3.parallel_env(max_cycles=10**9)
    env.reset(seed=0)
    spaces = {a: env.action_space(a) for a in env.possible_agents}

    def run(n_steps: int) -> float:
        start = time.perf_counter()
        for _ in range(n_steps):
            env.step({a: spaces[a].sample() for a in env.agents})
        return time.perf_counter() - start

    run(20)
    return run


def policy_call():
    """The user's policy call of the outside-actions loop: one jitted call per step that splits the key and computes
    the baseline controllers (``switching``) from the core state, ``(key, state, params) -> (key, actions)``."""
    from stp_env.policies import switching

    @jax.jit
    def act(key, state, params):
        key, sub = jax.random.split(key)
        return key, switching(sub, state, params)

    return act


def adapter_runner(scenario, params, python_only: bool = False):
    """``run(n) -> seconds``: the adapter with the vehicles' actions computed outside the step: the user's loop
    makes one jitted call per step (the key split and ``switching`` from ``env.env_state`` together: an eager
    ``jax.random.split`` alone cost about 100 us per step in this loop, more than the policy) and a random
    intruder. ``python_only``: the same loop with both device calls (the policy and the environment's compiled
    step) answered by results stored from a real step (the host copies the step's output as it would fetch it):
    what the loop's Python costs around them."""
    from stp_env.env import STPParallelEnv

    env = STPParallelEnv(scenario, params=params, max_cycles=10**9)
    env.reset(seed=0)
    act = policy_call()
    if python_only:
        from stp_env.sim.stepping import advance_carry_jit

        zero = {a: np.zeros(2, np.float32) for a in env.agents}
        stored_key, stored_veh = act(jax.random.key(0), env.env_state, params)
        env.step(zero)  # compiles the step returning the state (the loop reads it before every step)
        env.env_state  # noqa: B018
        carry = env._carry
        stored_out = np.asarray(carry.advance(advance_carry_jit, env._actions.parse(zero, env.agents), env.params,
                                              vehicle_policy=None, intruder_policy=None, with_state=True))
        env.env_state  # noqa: B018 - the state is kept unpacked: reads return it without a call

        def advance(fn, *args, **static):  # the step's packed output, as the host would fetch it
            carry.was_read = False
            return stored_out

        carry.advance = advance
        stored_veh = np.asarray(stored_veh)

        def act(key, state, params):  # the stored policy output stands in for the call
            return stored_key, stored_veh

    rng = np.random.default_rng(0)
    names = env.possible_agents
    n = params.vehicles.n
    box = {"key": jax.random.key(0), "episode": 0}

    def run(n_steps: int) -> float:
        key = box["key"]
        start = time.perf_counter()
        for _ in range(n_steps):
            if not env.agents:
                box["episode"] += 1
                env.reset(seed=box["episode"])
            key, veh = act(key, env.env_state, params)
            veh = np.asarray(veh)
            live = set(env.agents)
            actions = {a: (veh[i] if i < n else rng.uniform(-1, 1, 2).astype(np.float32))
                       for i, a in enumerate(names) if a in live}
            env.step(actions)
        box["key"] = key
        return time.perf_counter() - start

    run(20)
    return run


def builtin_policy_runner(scenario, params, read_state: bool = False):
    """``run(n) -> seconds``: the adapter with the vehicles flown by the built-in switching controller
    (``vehicle_policy="switching"``: one jitted call per step, the vehicles' actions ignored) and a random
    intruder: what training an intruder runs. ``read_state``: ``env.env_state`` read before every step (what a
    loop that computes anything from the core state pays for it)."""
    from stp_env.env import STPParallelEnv

    env = STPParallelEnv(scenario, params=params, max_cycles=10**9, vehicle_policy="switching")
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    zero = np.zeros(2, np.float32)
    box = {"episode": 0}

    def run(n_steps: int) -> float:
        start = time.perf_counter()
        for _ in range(n_steps):
            if not env.agents:
                box["episode"] += 1
                env.reset(seed=box["episode"])
            if read_state:
                env.env_state  # noqa: B018 - the read is what is measured
            env.step({a: (rng.uniform(-1, 1, 2).astype(np.float32) if a == "intruder" else zero)
                      for a in env.agents})
        return time.perf_counter() - start

    run(20)
    return run


def _spin(seconds: float) -> None:
    """Busy-wait ``seconds`` (the caller's thread stays on its core, as Python code between two calls keeps it)."""
    end = time.perf_counter() + seconds
    while time.perf_counter() < end:
        pass


def floor_runners(scenario, params, gap_us: float = 0.0) -> dict:
    """``{"outside_floor": run, "builtin_floor": run}``: the device calls of the two adapter loops alone, with nothing
    of PettingZoo around them (the ceiling a loop over the adapter can reach on this machine and jaxlib). The
    outside-actions loop's are the user's policy call (key split and ``switching``, its output fetched) and the
    environment's compiled step returning the state (the variant a loop that reads ``env.env_state`` runs), the
    built-in loop's the compiled step alone; each step's packed output is fetched as ``env.step`` fetches it. The
    carry is threaded from step to step (same-shaped inputs, so no retrace); actions are the policy's (vehicles) and
    zero (intruder). ``gap_us``: a busy wait after each step, standing in for the Python a loop runs between its
    calls (XLA's threads park when no call comes for a while, and the next call then wakes them)."""
    from stp_env.env import STPParallelEnv
    from stp_env.sim.stepping import advance_carry_jit

    advance = advance_carry_jit
    runners = {}
    for name, vehicle_policy in (("outside_floor", None), ("builtin_floor", "switching")):
        env = STPParallelEnv(scenario, params=params, max_cycles=10**9, vehicle_policy=vehicle_policy)
        env.reset(seed=0)
        env.step({a: np.zeros(2, np.float32) for a in env.agents})
        box = {"env": env, "words": env._carry.words, "state": env.env_state, "key": jax.random.key(0),
               "actions": env._actions.parse({a: np.zeros(2, np.float32) for a in env.agents}, env.agents),
               "act": policy_call()}

        def run(n_steps: int, box=box, outside=vehicle_policy is None) -> float:
            env, words, state, key, actions = box["env"], box["words"], box["state"], box["key"], box["actions"]
            act = box["act"]
            layout, policy, p, n = env._carry.layout, env._vehicle_policy, env.params, env.params.vehicles.n
            start = time.perf_counter()
            for _ in range(n_steps):
                if outside:
                    key, veh = act(key, state, p)
                    actions[:n] = np.asarray(veh)
                    words, out, (_, state) = advance(words, actions, p, layout=layout, vehicle_policy=None,
                                                     intruder_policy=None, with_state=True)
                else:
                    words, out = advance(words, actions, p, layout=layout, vehicle_policy=policy,
                                         intruder_policy=None, with_state=False)
                np.asarray(out)
                if gap_us:
                    _spin(gap_us * 1e-6)
            box.update(words=words, state=state, key=key)
            return time.perf_counter() - start

        run(20)
        runners[name] = run
    return runners


def interleaved(runners: dict, steps: dict, rounds: int) -> dict:
    """Each runner ``rounds`` times in turn, ``steps[name] // rounds`` steps a round: rates over all rounds and,
    per round, each runner's rate and its rate over the first's (the machine's load changes within a run)."""
    seconds = dict.fromkeys(runners, 0.0)
    done = dict.fromkeys(runners, 0)
    ratios: dict = {name: [] for name in runners}
    round_rates: dict = {name: [] for name in runners}
    first = next(iter(runners))
    for _ in range(rounds):
        rate = {}
        for name, run in runners.items():
            n = max(1, steps[name] // rounds)
            dt = run(n)
            seconds[name] += dt
            done[name] += n
            rate[name] = n / dt
        for name in runners:
            ratios[name].append(rate[name] / rate[first])
            round_rates[name].append(rate[name])
    return {"rates": {name: done[name] / seconds[name] for name in runners}, "ratios": ratios,
            "round_rates": round_rates}


def core_rate(params, n_envs: int, n_steps: int) -> tuple[float, float]:
    from stp_env import sim
    from stp_env.policies import INTRUDERS, switching

    out = sim.rollout(jax.random.key(0), params, switching, INTRUDERS["hj"], n_envs, n_steps)
    jax.block_until_ready(out)
    start = time.perf_counter()
    out = sim.rollout(jax.random.key(1), params, switching, INTRUDERS["hj"], n_envs, n_steps)
    jax.block_until_ready(out)
    elapsed = time.perf_counter() - start
    env_steps = n_envs * n_steps / elapsed
    return env_steps, env_steps * (params.vehicles.n + 1)


def long_run(scenario, params, n_steps: int) -> dict:
    from stp_env.env import STPParallelEnv
    from stp_env.sim.stepping import TRACE_COUNTS

    env = STPParallelEnv(scenario, params=params)
    env.reset(seed=0)
    zero = np.zeros(2, np.float32)
    env.step(dict.fromkeys(env.agents, zero))
    traces = TRACE_COUNTS["step"]
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    episode, start = 0, time.perf_counter()
    for _ in range(n_steps):
        if not env.agents:
            episode += 1
            env.reset(seed=episode)
        env.step(dict.fromkeys(env.agents, zero))
    return {"long_steps": n_steps, "long_s": round(time.perf_counter() - start, 1), "long_episodes": episode + 1,
            "long_rss_growth_mb": round((resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024, 1),
            "long_retraces": TRACE_COUNTS["step"] - traces}


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenario", default="city")
    parser.add_argument("--adapter-steps", type=int, default=5000)
    parser.add_argument("--mpe-steps", type=int, default=5000)
    parser.add_argument("--rounds", type=int, default=5,
                        help="mpe2 and the two adapter loops take turns this many times (the steps split evenly)")
    parser.add_argument("--envs", type=int, default=1024)
    parser.add_argument("--core-steps", type=int, default=200)
    parser.add_argument("--long", type=int, default=0)
    parser.add_argument("--cpu-threads", type=int, default=None,
                        help="XLA's CPU thread-pool size (default: one thread per core)")
    parser.add_argument("--cpu-devices", type=int, default=1,
                        help="JAX CPU devices the core's batch is shared among (one per core: the batch setting)")
    parser.add_argument("--state-reads", action="store_true",
                        help="also the built-in loop reading env.env_state before every step (a fourth runner)")
    parser.add_argument("--floors", action="store_true",
                        help="also the two loops' device calls alone, without PettingZoo (their ceilings)")
    parser.add_argument("--floor-gap-us", type=float, default=0.0,
                        help="with --floors: a busy wait of this many us after each floor step (the loop's Python)")
    parser.add_argument("--pin-core", action="store_true",
                        help="the process (and so XLA's threads) held to one core, as `taskset -c <core>` would")
    parser.add_argument("--sync-dispatch", action="store_true",
                        help="JAX's CPU computations run on the calling thread (jax_cpu_enable_async_dispatch off)")
    args = parser.parse_args()
    from stp_env import set_cpu_devices, set_cpu_threads

    if args.sync_dispatch:
        jax.config.update("jax_cpu_enable_async_dispatch", False)
    if args.pin_core:  # before JAX starts its threads: they inherit the process's affinity
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    set_cpu_threads(args.cpu_threads)  # before JAX's first computation
    set_cpu_devices(args.cpu_devices)
    scenario, params = _params(args.scenario)
    result = {"case": "env_throughput", "scenario": args.scenario, "n_agents": params.vehicles.n + 1,
              "cpu_threads": args.cpu_threads, "cpu_async_dispatch": not args.sync_dispatch,
              "cores": sorted(os.sched_getaffinity(0)),
              "cpu_devices": args.cpu_devices, "loadavg_1min_before": round(os.getloadavg()[0], 2)}
    runners = {"mpe2": mpe2_runner(), "adapter": adapter_runner(scenario, params),
               "adapter_builtin": builtin_policy_runner(scenario, params)}
    steps = {"mpe2": args.mpe_steps, "adapter": args.adapter_steps, "adapter_builtin": args.adapter_steps}
    if args.floors:
        for name, run in floor_runners(scenario, params, args.floor_gap_us).items():
            runners[name], steps[name] = run, args.adapter_steps
        runners["outside_python"], steps["outside_python"] = adapter_runner(scenario, params, python_only=True), \
            args.adapter_steps
    if args.state_reads:
        runners["adapter_builtin_reading_state"] = builtin_policy_runner(scenario, params, read_state=True)
        steps["adapter_builtin_reading_state"] = args.adapter_steps
    measured = interleaved(runners, steps, args.rounds)
    for name in runners:
        result[f"{name}_env_steps_per_s"] = round(measured["rates"][name], 1)
    if args.state_reads:  # the read's cost per step: the two built-in loops' step times, paired within each round
        per_round = [1e6 / r - 1e6 / b for r, b in zip(measured["round_rates"]["adapter_builtin_reading_state"],
                                                       measured["round_rates"]["adapter_builtin"])]
        result["env_state_read_us_per_step"] = round(float(np.median(per_round)), 1)
        result["env_state_read_us_per_step_per_round"] = [round(x, 1) for x in per_round]
    for name in ("adapter", "adapter_builtin", *(("outside_floor", "builtin_floor") if args.floors else ())):
        result[f"{name}_over_mpe2"] = round(measured["rates"][name] / measured["rates"]["mpe2"], 2)
        result[f"{name}_over_mpe2_per_round"] = [round(r, 2) for r in measured["ratios"][name]]
    if args.floors:  # the outside-actions loop at best: its device calls plus its Python
        rates = measured["rates"]
        result["outside_python_us_per_step"] = round(1e6 / rates["outside_python"], 1)
        if args.floor_gap_us:  # the busy wait stood in for the Python: the floor's own rate is the ceiling
            result["floor_gap_us"] = args.floor_gap_us
            best = rates["outside_floor"]
        else:  # the calls alone and the Python alone, their step times added
            best = 1.0 / (1.0 / rates["outside_floor"] + 1.0 / rates["outside_python"])
        result["outside_ceiling_over_mpe2"] = round(best / rates["mpe2"], 2)
    env_steps, agent_steps = core_rate(params, args.envs, args.core_steps)
    result.update({"core_envs": args.envs, "core_env_steps_per_s": round(env_steps),
                   "core_agent_steps_per_s": round(agent_steps),
                   "core_over_mpe2_env_steps": round(env_steps / result["mpe2_env_steps_per_s"], 1)})
    if args.long:
        result.update(long_run(scenario, params, args.long))
    result["jax_devices"] = [str(d) for d in jax.devices()]
    print(json.dumps(result))


if __name__ == "__main__":
    main()

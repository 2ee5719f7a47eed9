"""The batched core's avoid-table reads, three ways: the library's (``two_reads``: ``tables.avoid_value``, then
``tables.avoidance_control``, each reading the same ``2 x 4 x 4 x 4`` block; XLA merges the two), and two
alternatives that are not in the library: ``one_read`` (value and gradient from one block read per vehicle, the
control from that gradient) and ``k_nearest`` (reads for only the ``K`` vehicles nearest the intruder, scattered
back; the others get ``FAR`` and no avoidance input, which is exact only while at most ``K`` vehicles are inside the
table's box; the rollout here does not check that, it measures the best case of the idea).

    python benchmarks/avoid_reads.py [--scenarios town city] [--envs 256] [--steps 50] [--reps 3] [--k 4]

Each variant runs in its own process (``--variant``, used internally): the scenario's shipped plan, ``switching``
vehicles, the HJ intruder, ``sim.rollout`` over ``--envs`` episodes of ``--steps`` steps; the compiled rollout's
run time is the fastest of three calls after a first (compiling) one. The variants are interleaved ``--reps`` times
and the fastest run of each is kept (the machine is noisy). ``one_read`` and ``two_reads`` must give the same
episodes: the outputs of their first call are compared (``same_as_two_reads``). Prints one JSON line per scenario.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys

VARIANTS = ("two_reads", "one_read", "k_nearest")


def run_one(scenario: str, variant: str, n_envs: int, n_steps: int, k: int) -> dict:
    import jax
    import jax.numpy as jnp

    sys.path.insert(0, os.path.dirname(__file__))
    import env_throughput
    from core_revisions import time_rollout

    from stp_env.sim import core, tables
    from stp_env.sim.physics import relative_state

    _, params = env_throughput._params(scenario)

    def _optimal(params, x_rel, p):
        dyn = params.tables.avoid_dynamics
        return jnp.stack(dyn.optimal_control((x_rel[0], x_rel[1], x_rel[2]), (p[0], p[1], p[2])))

    def value_and_control(params, tau, x_rel):
        """``tables.avoid_value`` and ``tables.avoidance_control`` from one block read."""
        grid = params.tables.avoid_grid
        v, p = tables._avoid_read(grid, params.tables.avoid_taus, params.tables.avoid_values, tau, x_rel)
        return jnp.where(tables._inside(grid, x_rel), v, tables.FAR), _optimal(params, x_rel, p)

    def one_read(params, state):
        tau = state.t - state.t_appear
        rel = relative_state(core.poses(params, state), state.intruder_x[None, :])
        vals, u = jax.vmap(lambda r: value_and_control(params, tau, r))(rel)
        ok = core.flying(state) & core.intruder_present(state)
        return (jnp.where(ok, vals, tables.FAR),
                params.vehicles.model.command_to_action(state.x, u[:, 0], u[:, 1], params.vehicles.bounds))

    def k_nearest(params, state):
        tau = state.t - state.t_appear
        pose = core.poses(params, state)
        d = jnp.where(core.flying(state), jnp.hypot(*(pose[:, :2] - state.intruder_x[None, :2]).T), jnp.inf)
        _, idx = jax.lax.top_k(-d, min(k, params.vehicles.n))
        rel = relative_state(pose[idx], state.intruder_x[None, :])
        v, u = jax.vmap(lambda r: value_and_control(params, tau, r))(rel)
        n = params.vehicles.n
        vals = jnp.full((n,), tables.FAR, v.dtype).at[idx].set(v)
        u = jnp.zeros((n, 2), u.dtype).at[idx].set(u)
        ok = core.flying(state) & core.intruder_present(state)
        return (jnp.where(ok, vals, tables.FAR),
                params.vehicles.model.command_to_action(state.x, u[:, 0], u[:, 1], params.vehicles.bounds))

    def patched_refresh(state, params):
        track_action, err = core.tracking_actions(params, state)
        avoid_value, avoid_action = reads(params, state)
        return core.replace(state, avoid_value=avoid_value, avoid_action=avoid_action, track_action=track_action,
                            tracking_error=err)

    reads = {"one_read": one_read, "k_nearest": k_nearest}.get(variant)
    if reads is not None:
        core.refresh_controllers = patched_refresh

    return time_rollout(params, n_envs, n_steps)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--scenarios", nargs="+", default=["town", "city"])
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=50)
    parser.add_argument("--reps", type=int, default=3)
    parser.add_argument("--k", type=int, default=4)
    parser.add_argument("--variant", choices=VARIANTS, help="run one variant in this process (used internally)")
    args = parser.parse_args()
    if args.variant:
        print(json.dumps(run_one(args.scenarios[0], args.variant, args.envs, args.steps, args.k)))
        return
    for scenario in args.scenarios:
        load = round(os.getloadavg()[0], 2)
        runs = {v: [] for v in VARIANTS}
        for _ in range(args.reps):
            for variant in VARIANTS:
                res = subprocess.run([sys.executable, __file__, "--scenarios", scenario, "--envs", str(args.envs),
                                      "--steps", str(args.steps), "--k", str(args.k), "--variant", variant],
                                     capture_output=True, text=True, check=True)
                runs[variant].append(json.loads(res.stdout.strip().splitlines()[-1]))
        best = {v: min(r["run_s"] for r in runs[v]) for v in VARIANTS}
        out = {"benchmark": "avoid_reads", "scenario": scenario, "envs": args.envs, "steps": args.steps,
               "reps": args.reps, "k": args.k, "loadavg_1min_before": load,
               "run_s": {v: round(best[v], 3) for v in VARIANTS},
               "run_s_all": {v: [round(r["run_s"], 3) for r in runs[v]] for v in VARIANTS},
               "first_call_s": {v: round(min(r["first_s"] for r in runs[v]), 1) for v in VARIANTS},
               "one_read_speedup": round(best["two_reads"] / best["one_read"], 2),
               "k_nearest_over_one_read": round(best["one_read"] / best["k_nearest"], 2),
               "same_as_two_reads": len({r["digest"] for v in ("two_reads", "one_read") for r in runs[v]}) == 1,
               "env_steps_per_s_one_read": round(args.envs * args.steps / best["one_read"])}
        print(json.dumps(out), flush=True)


if __name__ == "__main__":
    main()

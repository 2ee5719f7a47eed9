"""How many vehicles of a trail one intruder can force: the designed worst case on the ``corridor`` layout.

The intruder appears on the leader's *rear* avoid boundary (1 m above the simulator's avoid margin, heading back
along the trail), when the leader is 1.5 km down the route, and plays ``optimal-max-k``; the vehicles play
``worst`` (every unforced vehicle helps the intruder, the assumption behind ``V^B``) or ``switching`` (their plans
until forced). The trail spacing is free, so it can be set tighter than the planner allows (``--spacings``, STA
spacing in seconds; the trail is 13 m/s times that). Prints one JSON line per spacing: the avoid-start times after
the appearance, each untouched vehicle's smallest ``V^A`` (``null``: the intruder never came within its avoid
table), and the planner's disk clearance of the layout (negative: the planner would refuse it).

    python examples/trail_chain.py --kbar 3 --spacings 62 52 46 40 [--vehicle-policy worst] [--wind-model uniform]
"""

from __future__ import annotations

import argparse
import json
import math

import jax.numpy as jnp
import numpy as np

from stp_env import assembly, hj, sim
from stp_env.assembly import load_buffer, with_buffer
from stp_env.evaluation.worst_case import reproduce
from stp_env.planning.verify import obstacle_margin, planner_disks, straight_plan
from stp_env.policies import intruder_policy, vehicle_policy
from stp_env.scenarios import make

LEADER_ALONG = 1500.0  # [m] the leader's distance down the route when the intruder appears


def rear_boundary(avoid, level: float) -> float:
    """Distance [m] behind a vehicle, on its axis, where ``V^A(0, t_IAT) = level`` for an intruder heading away
    from it along the axis (relative heading pi): bisection on the interpolated table."""
    table = jnp.asarray(avoid.values[0])

    def value(d):
        return float(hj.interpolation.interpolate(avoid.grid, table, jnp.asarray([-d, 0.0, math.pi], jnp.float32)))

    lo, hi = 1.0, 0.99 * float(avoid.grid.hi[0])
    if not (value(lo) <= level < value(hi)):
        raise SystemExit("the avoid table does not cross the level behind the vehicle")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if value(mid) > level else (mid, hi)
    return hi


def run(kbar: int, spacing: float, n_vehicles: int, vehicles: str, wind_model: str) -> dict:
    scenario = make("corridor", kbar=kbar, n_vehicles=n_vehicles, sta_spacing=spacing)
    avoid, tracking = assembly.load_artifacts(scenario, progress=False)
    disks = planner_disks(scenario, tracking.bound)
    plan = straight_plan(scenario, tracking.bound, disks=disks, check=False)
    clearance = obstacle_margin(plan, disks)[0]
    t_app = LEADER_ALONG / scenario.planning_v[1]
    config = sim.EnvConfig(appear_window=(t_app, t_app), wind_model=wind_model)
    params = with_buffer(assembly.make_params(scenario, plan, avoid, tracking, config),
                         load_buffer(scenario, progress=False))
    behind = rear_boundary(avoid, float(params.tables.avoid_margin) + 1.0)
    lead = plan.vehicles[0].plan
    tq = lead.t_ldt + t_app
    spawn = np.asarray([np.interp(tq, lead.times, lead.states[:, 0]) - behind,
                        np.interp(tq, lead.times, lead.states[:, 1]), math.pi], np.float32)
    res = reproduce(params, vehicle_policy(vehicles), intruder_policy("optimal-max-k"), spawn=spawn)
    return {"kbar": kbar, "spacing_s": spacing, "trail_m": round(spacing * scenario.planning_v[1], 1),
            "planner_clearance_m": round(float(clearance), 1), "rear_boundary_m": round(behind, 1),
            "vehicles": vehicles, "wind_model": wind_model, "n_forced": res["n_forced"],
            "avoid_start_s": [t if math.isfinite(t) else None for t in res["avoid_start_s"]],
            "min_avoid_value_m": res["min_avoid_value_m"], "collisions": res["collisions"]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--kbar", type=int, default=3)
    parser.add_argument("--spacings", type=float, nargs="+", default=[62.0, 52.0, 46.0, 40.0])
    parser.add_argument("--n-vehicles", type=int, default=5)
    parser.add_argument("--vehicle-policy", default="worst", choices=["worst", "switching"])
    parser.add_argument("--wind-model", default="uniform")
    args = parser.parse_args()
    for spacing in args.spacings:
        print(json.dumps(run(args.kbar, spacing, args.n_vehicles, args.vehicle_policy, args.wind_model)),
              flush=True)


if __name__ == "__main__":
    main()

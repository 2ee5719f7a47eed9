"""Where on the way to the goal an alternative landing site is still within reach, with no traffic at all: per
cruise window, the share of the origin's goal trajectories whose state there could reach an alternative site
instead (:func:`stp_env.survivability.analysis.goal_corridor`). Where the share is 0, a mission that loses the goal
in that window has no site left: an emergency landing whatever the policy, which bounds how much survival can gain
over success.

    python examples/survivability_goal_corridor.py [--endurance 60 65 70 80] [--dv-max 10 20]

Prints one JSON line per mission variant (the paper's mission first: endurance 60 min, speed changes of at most
10 m/s per window).
"""

from __future__ import annotations

import argparse
import json
import time

from stp_env.survivability.analysis import goal_corridor
from stp_env.survivability.config import MissionConfig
from stp_env.survivability.mission import default_graph


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--endurance", type=float, nargs="+", default=[60.0, 65.0, 70.0, 80.0],
                    help="latest landing anywhere [min] (paper: 60)")
    ap.add_argument("--dv-max", type=float, nargs="+", default=[10.0, 20.0],
                    help="largest speed change per window [m/s] (paper: 10)")
    args = ap.parse_args()
    variants = [(e, args.dv_max[0]) for e in args.endurance] + [(args.endurance[0], d) for d in args.dv_max[1:]]
    for endurance, dv in variants:
        t0 = time.perf_counter()
        graph = default_graph(MissionConfig(endurance_min=endurance, dv_max=dv))
        rows = goal_corridor(graph)
        print(json.dumps({"endurance_min": endurance, "dv_max": dv, "graph_states": graph.n_states,
                          "share_of_goal_trajectories_that_can_divert": {r["window"]: round(r["trajectories"], 3)
                                                                          for r in rows},
                          "corridor_states": {r["window"]: [r["states"], r["states_alt"]] for r in rows},
                          "seconds": round(time.perf_counter() - t0, 1)}), flush=True)


if __name__ == "__main__":
    main()

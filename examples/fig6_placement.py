"""Place ``Q3`` and ``Q4`` of the ``fig6`` scenario by bisection on the simulated worst case: with the buffer game's
worst vehicles and the ``optimal-max-k`` intruder, ``Q3`` is forced at ``2 t_BRD`` and ``Q4`` is reached just
after ``t_IAT`` (one avoid margin beyond the last distance at which it is forced). ``Q2`` stays where the buffer
geometry puts it (stp_env/scenarios/catalog/fig6.py). Prints the positions for ``FIG6_TRAIL`` and writes the search log
to docs/fig6_placement.json.

    python examples/fig6_placement.py [--lateral 150]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--lateral", type=float, default=150.0, help="|y| of Q3 (south) and Q4 (north) [m]")
    ap.add_argument("--iterations", type=int, default=12)
    ap.add_argument("--x3", type=float, default=None, help="skip the Q3 search: use this x [m]")
    ap.add_argument("--q4-range", type=float, nargs=2, default=(150.0, 1300.0),
                    help="x range [m] of the Q4 search: forced (or collided) at the low end, untouched at the high")
    args = ap.parse_args()

    from tqdm.auto import tqdm

    from stp_env import assembly, sim
    from stp_env.assembly import load_buffer, with_buffer
    from stp_env.evaluation.worst_case import reproduce
    from stp_env.policies import optimal_max_k, worst
    from stp_env.scenarios import make
    from stp_env.scenarios.catalog.fig6 import FIG6_LEAD, FIG6_SPEED, fig6_plan

    base = make("fig6")
    avoid, tracking = assembly.load_artifacts(base, progress=False)
    buffer = load_buffer(base, progress=False)
    lo = FIG6_LEAD - 0.5 * 0.1
    config = sim.EnvConfig(appear_window=(lo, lo), lead=lo)
    t_brd = base.t_iat / base.kbar
    log = []

    def run(x3, x4):
        lead = FIG6_SPEED * FIG6_LEAD
        vehicles = list(base.vehicles)
        for k, (x, y) in ((2, (x3, -args.lateral)), (3, (x4, args.lateral))):
            vehicles[k] = dataclasses.replace(vehicles[k], start=(x + lead, y, -math.pi))
        scenario = base.with_overrides(vehicles=tuple(vehicles))
        plan = fig6_plan(scenario, tracking.bound, min_samples=600)
        params = with_buffer(assembly.make_params(scenario, plan, avoid, tracking, config), buffer)
        r = reproduce(params, worst, optimal_max_k, n_steps=160)
        log.append({"x3": x3, "x4": x4, "avoid_start_s": r["avoid_start_s"], "collisions": r["collisions"]})
        return r["avoid_start_s"]

    far = 1300.0
    a, b = 300.0, 900.0          # t_3(a) < 2 t_BRD < t_3(b)
    if args.x3 is None:
        for _ in tqdm(range(args.iterations), desc="Q3"):
            m = 0.5 * (a + b)
            t3 = run(m, far)[2]
            a, b = (m, b) if t3 < 2 * t_brd else (a, m)
    x3 = round(0.5 * (a + b), 2) if args.x3 is None else args.x3
    a, b = args.q4_range         # forced (or collided) at a, untouched at b
    for _ in tqdm(range(args.iterations), desc="Q4"):
        m = 0.5 * (a + b)
        run(x3, m)
        touched = math.isfinite(log[-1]["avoid_start_s"][3]) or log[-1]["collisions"] > 0
        a, b = (m, b) if touched else (a, m)
    x4 = round(b + 1.0, 2)
    final = run(x3, x4)
    out = {"command": "python examples/fig6_placement.py", "lateral_m": args.lateral, "x3": x3, "x4": x4,
           "final_avoid_start_s": final, "log": log}
    (ROOT / "docs" / "fig6_placement.json").write_text(
        json.dumps(out, indent=1, default=lambda v: None) .replace("Infinity", "null") + "\n")
    print(json.dumps({k: v for k, v in out.items() if k != "log"}, default=str))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

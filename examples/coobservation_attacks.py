"""Example attacks on the UAV formation, drawn: the same compromise (the left vehicle, right after an
observation) under the secured and the unsecured schedule, for each attacker (``docs/coobservation_attacks.png``).

``python examples/coobservation_attacks.py [--learned stp_env/data/coobservation/attacker.npz]``
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import jax
import numpy as np

from stp_env.coobservation import attackers, checkpoints, plots, threat
from stp_env.coobservation.env import UNSECURED_PERIOD
from stp_env.coobservation.uav import FormationScenario

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--learned", default=None, help="an exported attacker .npz to draw as well")
    ap.add_argument("--compromise-time", type=float, default=91.0, help="[s]")
    ap.add_argument("--out", default=str(ROOT / "docs" / "coobservation_attacks.png"))
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc = FormationScenario()
    params = sc.params()
    # the optimistic attacker flies in the tailwind it counts on (the ellipses' worst case)
    tail_params = dataclasses.replace(sc, wind_model="tailwind").params()
    secure = checkpoints.ellipse_test(sc.forbidden, sc.attacker_speed, sc.ellipse_radius)
    times = {"secured": sc.secured_times(secure), "unsecured": sc.uniform_times(UNSECURED_PERIOD)}
    m = max(len(sc.schedule(t)) for t in times.values())
    pols = {"reckless": (attackers.reckless, params), "opportunistic": (attackers.opportunistic(), params),
            "optimistic (tailwind)": (attackers.optimistic(), tail_params)}
    if args.learned:
        from stp_env.coobservation.learned import mlp_attacker

        pols["learned"] = (mlp_attacker(args.learned), params)
    n_steps = threat.steps_for(params)
    t_c = args.compromise_time
    fig, axes = plt.subplots(len(pols), 2, figsize=(10, 5 * len(pols)), squeeze=False)
    for col, (s_name, ts) in enumerate(times.items()):
        tp = threat.threat_params(sc.schedule(ts), sc.forbidden, sc.observation_radius, pad_to=m)
        for row, (a_name, (pol, params)) in enumerate(pols.items()):
            # the compromise time is pinned (a window of width 0); the first of 16 episodes whose draw compromised
            # vehicle 0 is drawn
            final, xs = threat.rollout(jax.random.key(0), params, tp, pol, 16, n_steps, (t_c, t_c), record=True)
            comp = np.asarray(final.compromised)
            k = int(np.flatnonzero(comp == 0)[0])
            o = threat.outcomes(jax.device_get(jax.tree.map(lambda a, k=k: a[k:k + 1], final)))
            path = np.asarray(xs[k])
            ax = axes[row, col]
            plots.draw_zones(ax, (), sc.forbidden, names=["zone A", "zone B"])
            for i in range(sc.n_vehicles):
                ax.plot(path[:, i, 0], path[:, i, 1], color=plots.COLORS[i], lw=1.5 if i == 0 else 0.8)
            for t in ts:
                j = min(round(t / sc.dt), len(path) - 1)
                ax.plot(*path[j, 0], "o", color="m", ms=4)
            jc = round(t_c / sc.dt)
            ax.plot(*path[jc, 0], "kx", ms=9, mew=2)
            tag = ("SUCCESS (entered, never missed)" if o["success"][0] else
                   "entered, detected" if o["entered"][0] else "detected, no entry" if o["detected"][0]
                   else "no attack")
            ax.set_title(f"{a_name} vs {s_name} schedule:\n{tag}", fontsize=10)
            ax.set_xlim(sc.domain_lo[0], sc.domain_hi[0])
            ax.set_ylim(sc.domain_lo[1], sc.domain_hi[1])
            ax.set_aspect("equal")
    fig.suptitle(f"The left vehicle (blue) compromised at t = {t_c:g} s (x); magenta: its positions at the scheduled "
                 "co-observations", fontsize=10)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 0.985))
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()

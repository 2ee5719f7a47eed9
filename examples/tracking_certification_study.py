"""Why the tracking-error bound is certified in closed loop: the value keeps rising, the closed loop does not.

    python examples/tracking_certification_study.py --wind 11 --horizon 150 --out tracking_study
    python examples/tracking_certification_study.py --wind 11 --grid 41 41 40 --out tracking_study_41

Solves the robust-tracking game (SPP eqs. 24-26) on the default grid of the wind (or ``--grid``) second by second to
``--horizon`` seconds, saving ``V(0)`` every second and the value every ``--every`` seconds (resumable: the file in
``--out`` is continued), and marks where the stopping rule alone fires (``V(0)`` changes by at most 0.25 % in a
second). Then every saved value's tracker is flown against every saved value's worst reference and wind
(:func:`stp_env.reach.tracking.certify`: both inner-period ends, the reference re-read every period and held per
0.1 s plan sample, from zero error and 15 perturbations of it), one JSON line per pair: ``V(0)`` of the tracker,
the largest error of the rollouts from zero, and the largest excess over the value at the start. ``docs/numerics.md``
quotes the 11 m/s run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.reach.tracking import certify, default_tracking_bound


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--wind", type=float, default=11.0, help="wind bound [m/s]")
    ap.add_argument("--horizon", type=int, default=150, help="seconds of horizon to solve")
    ap.add_argument("--every", type=int, default=10, help="save the value every this many seconds")
    ap.add_argument("--grid", type=int, nargs=3, default=None, help="grid points (default: the wind's default)")
    ap.add_argument("--out", type=Path, default=Path("tracking_study"), help="output directory")
    args = ap.parse_args(argv)
    vehicle = DubinsWind(v_min=0.0, v_max=25.0, omega_max=2.0, wind=args.wind)
    config = default_tracking_bound(vehicle, progress=True).config  # the box default_tracking_bound lands on
    if args.grid is not None:
        config = dataclasses.replace(config, grid_points=tuple(args.grid))
    grid = config.grid
    x = grid.broadcast_states()
    cost = jnp.broadcast_to(jnp.minimum(jnp.sqrt(x[0] ** 2 + x[1] ** 2), config.cap), grid.shape)
    settings = hj.SolverSettings.with_accuracy(config.accuracy)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "values.npz"
    saved, history, w = {}, [], -cost
    if path.is_file():
        with np.load(path, allow_pickle=False) as z:
            saved = {k: z[k] for k in z.files if k.startswith("v")}
            history = list(z["history"])
            w = jnp.asarray(z["last"])
    t0 = time.perf_counter()
    for k in range(len(history) + 1, args.horizon + 1):
        w = hj.solve(settings, config.error_dynamics, grid, [0.0, -1.0], -cost, initial_values=w, tube=True,
                     progress=False).values[-1]
        history.append(float(-hj.interpolation.interpolate(grid, w, jnp.zeros(3))))
        if k % args.every == 0:
            saved[f"v{k}"] = -np.asarray(w)
        tmp = args.out / ".values.tmp.npz"
        np.savez(tmp, history=np.asarray(history), last=np.asarray(w), **saved)
        tmp.replace(path)
        print(f"\rhorizon {k} s: V(0) = {history[-1]:.3f} m ({time.perf_counter() - t0:.0f} s)", end="",
              file=sys.stderr, flush=True)
    print(file=sys.stderr)
    h = np.asarray(history)
    rule = next((i + 1 for i in range(1, len(h)) if h[i] - h[i - 1] <= 0.0025 * h[i]), None)
    print(json.dumps({"wind_m_s": args.wind, "grid": list(config.grid_points), "half_width_m": config.half_width,
                      "rule_fires_s": rule, "V0_every_10_s": [round(float(v), 3) for v in h[9::10]]}), flush=True)
    names = sorted(saved, key=lambda s: int(s[1:]))
    for tracker in names:
        for attacker in names:
            cert = certify(config, saved[tracker], saved[attacker])
            v0 = float(hj.interpolation.interpolate(grid, jnp.asarray(saved[tracker]), jnp.zeros(3)))
            print(json.dumps({"tracker_horizon_s": int(tracker[1:]), "attacker_horizon_s": int(attacker[1:]),
                              "V0_m": round(v0, 3), "worst_from_zero_m": round(cert.worst_error, 3),
                              "excess_m": round(cert.excess, 3)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

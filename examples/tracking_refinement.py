"""Refinement study of the robust-tracking error bound (``docs/numerics.md``): ``V(0)`` and ``min V`` after every
second of horizon, for several grids, box sizes and winds.

    python examples/tracking_refinement.py --out tracking_refinement [--cases w6-n41 w6-n61 ...] [--horizon 60]

Each case writes ``<out>/<case>.jsonl`` (one line per second of horizon, appended as it goes: a killed run resumes
from its last saved value array, ``<case>.npz``, every 10 s) and the script prints one JSON line per finished case:
the bound where the default stopping rule (``TrackingConfig.rtol``) fires, ``V(0)`` at 30 and 60 s and the creep
rate at the end. The default grid is ``w6-n61`` (6 m/s) and, after the box growth of ``default_tracking_bound``,
about ``w11-hw59-n61`` (11 m/s).
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.dynamics import DubinsWind
from stp_env.reach.tracking import TrackingConfig

CASES = {
    # name: (wind [m/s], half-width [m], points in position, headings)
    "w6-n41": (6.0, 10.0, 41, 40),
    "w6-n61": (6.0, 10.0, 61, 60),
    "w6-n81": (6.0, 10.0, 81, 80),
    "w6-n61-th120": (6.0, 10.0, 61, 120),
    "w6-n101": (6.0, 10.0, 101, 100),
    "w11-hw50-n61": (11.0, 50.0, 61, 60),
    "w11-hw50-n81": (11.0, 50.0, 81, 80),
    "w11-hw59-n61": (11.0, 58.8, 61, 60),
}


def config_for(case: str) -> TrackingConfig:
    wind, half_width, n, n_theta = CASES[case]
    return TrackingConfig(vehicle=DubinsWind(wind=wind), half_width=half_width, grid_points=(n, n, n_theta))


def run_case(case: str, out: Path, horizon: int) -> list[dict]:
    cfg = config_for(case)
    grid = cfg.grid
    x = grid.broadcast_states()
    cost = -jnp.broadcast_to(jnp.minimum(jnp.sqrt(x[0] ** 2 + x[1] ** 2), cfg.cap), grid.shape)
    settings = hj.SolverSettings.with_accuracy(cfg.accuracy)
    log, snap = out / f"{case}.jsonl", out / f"{case}.npz"
    rows = [json.loads(line) for line in log.read_text().splitlines()] if log.exists() else []
    values, start = cost, 0
    if snap.exists():
        with np.load(snap, allow_pickle=False) as data:
            values, start = jnp.asarray(-data["value"]), int(data["t"])
        rows = rows[:start]
    else:
        rows = []
    log.write_text("".join(json.dumps(r) + "\n" for r in rows))
    t0 = time.perf_counter()
    with log.open("a") as fh:
        for k in range(start, horizon):
            res = hj.solve(settings, cfg.error_dynamics, grid, [0.0, -cfg.check_interval], cost,
                           initial_values=values, tube=True, progress=False)
            values = res.values[-1]
            v = -np.asarray(values)
            row = {"t": k + 1, "V0": round(float(hj.interpolation.interpolate(grid, jnp.asarray(v), jnp.zeros(3))), 4),
                   "minV": round(float(v.min()), 4), "s": round(time.perf_counter() - t0, 1)}
            rows.append(row)
            fh.write(json.dumps(row) + "\n")
            fh.flush()
            if (k + 1) % 10 == 0:
                tmp = snap.with_suffix(".tmp.npz")
                np.savez_compressed(tmp, value=v, t=k + 1)
                tmp.replace(snap)
    return rows


def summary(case: str, rows: list[dict]) -> dict:
    cfg = config_for(case)
    v0 = {r["t"]: r["V0"] for r in rows}
    vmin = {r["t"]: r["minV"] for r in rows}
    stop = next((t for t in sorted(v0)[1:] if max(abs(v0[t] - v0[t - 1]), abs(vmin[t] - vmin[t - 1]))
                 <= cfg.rtol * v0[t]), None)
    last = max(v0)
    return {"case": case, "wind": CASES[case][0], "half_width_m": CASES[case][1],
            "grid": list(cfg.grid_points), "spacing_m": round(cfg.grid.spacing[0], 3),
            "rule_stops_s": stop, "bound_at_stop_m": v0.get(stop), "V0_30s": v0.get(30), "V0_60s": v0.get(60),
            "creep_m_per_s_at_end": round((v0[last] - v0[last - 5]) / 5, 4) if last - 5 in v0 else None,
            "horizon_s": last}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="tracking_refinement")
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--horizon", type=int, default=60, help="seconds of horizon per case")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for case in args.cases:
        rows = run_case(case, out, args.horizon)
        print(json.dumps(summary(case, rows)), flush=True)


if __name__ == "__main__":
    main()

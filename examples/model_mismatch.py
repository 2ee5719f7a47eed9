"""Model mismatch: how much of the papers' guarantees survives when the vehicles are rigid bodies (mass, inertia,
drag, actuator lag) instead of the Dubins model the plans, the reachability sets and the controllers assume.

Every configuration runs through the evaluator (:func:`stp_env.evaluation.runner.evaluate`, the same episodes for
each: common random numbers) on the pymunk backend (:mod:`stp_env.sim.backends`); a ``jax`` row is the Dubins
reference. Sweeps: ``lag`` (speed and turn actuator time constants together), ``mass`` (the velocity time constant
``m / c_lin``), ``drag`` (the yaw time constant ``I / c_ang`` through ``c_ang``). For each configuration: episodes
with a guarantee violation (95% Clopper-Pearson interval), vehicles whose tracking error exceeded ``r_e``, the
largest tracking error (the ``r_e`` that would have held: the extra tracking margin the mismatch needs), and
``|N^RP|``. Results are appended to ``OUT/results.jsonl`` one configuration at a time (a rerun skips the ones done);
``--figure`` draws docs/model_mismatch.png from them.

    nice -n 10 python examples/model_mismatch.py --episodes 100 --out runs/model_mismatch
    python examples/model_mismatch.py --out runs/model_mismatch --figure docs/model_mismatch.png
"""

from __future__ import annotations

import argparse
import json
import os
import pathlib
import time

import numpy as np

from stp_env.evaluation.config import Configuration
from stp_env.evaluation.stats import clopper_pearson_interval

LAGS = (0.0, 0.1, 0.2, 0.3, 0.5)          # [s] actuator time constants (speed and turn rate)
MASSES = (0.5, 1.0, 2.0, 4.0)             # [kg] with c_lin = 20 N s/m: m / c_lin = 0.025 .. 0.2 s
ANGULAR_DRAGS = (0.4, 0.2, 0.1, 0.05)     # [N m s/rad] with I = 0.01 kg m^2: I / c_ang = 0.025 .. 0.2 s


def sweeps(which, lags=LAGS) -> list[tuple[str, float, str]]:
    """``(sweep, value, backend spec)`` rows; the other parameters stay at RigidBodyConfig's defaults, except
    that the lag sweep has no other lag and the mass and drag sweeps have no actuator lag."""
    rows = [("reference", 0.0, "jax")]
    if "lag" in which:
        rows += [("lag", t, f"pymunk-dynamic:speed_time_constant={t},turn_time_constant={t}") for t in lags]
    if "mass" in which:
        rows += [("mass", m, f"pymunk-dynamic:mass={m},speed_time_constant=0,turn_time_constant=0") for m in MASSES]
    if "drag" in which:
        rows += [("drag", c, f"pymunk-dynamic:angular_drag={c},speed_time_constant=0,turn_time_constant=0")
                 for c in ANGULAR_DRAGS]
    return rows


def run(out: pathlib.Path, which, episodes: int, batch_size: int, scenario: str, kbar: int, intruder: str,
        seed: int, lags=LAGS) -> None:
    from stp_env.evaluation.runner import evaluate

    out.mkdir(parents=True, exist_ok=True)
    path = out / "results.jsonl"
    done = {(r["sweep"], r["value"], r["episodes"]) for r in load(path)}
    for sweep, value, backend in sweeps(which, lags):
        if (sweep, value, episodes) in done:
            continue
        config = Configuration(scenario=scenario, kbar=kbar, intruder=intruder, backend=backend)
        start = time.perf_counter()
        result = evaluate([config], episodes=episodes, seed=seed, batch_size=batch_size, showcase=False,
                          progress=True)[0]
        s, ep = result.summary, result.episodes
        n = s["episodes"]
        tracked_err = np.where(ep["tracked"], ep["max_tracking_error"], 0.0).max(axis=1)
        row = {
            "sweep": sweep, "value": value, "backend": backend, "episodes": n, "seed": seed,
            "violation_episodes": s["violation_episodes"],
            "violation_ci95": clopper_pearson_interval(s["violation_episodes"], n, 0.95),
            "tracking_violation_episodes": int(np.any(ep["tracking_violation"], axis=1).sum()),
            "tracking_violation_ci95": clopper_pearson_interval(int(np.any(ep["tracking_violation"], axis=1).sum()),
                                                                n, 0.95),
            "collision_episodes": s["collision_episodes"], "intruder_collisions": s["intruder_collisions"],
            "collision_ci95": clopper_pearson_interval(s["collision_episodes"], n, 0.95),
            "max_tracking_error_m": s["max_tracking_error_m"], "tracking_bound_m": s["tracking_bound_m"],
            "tracking_error_p95_m": round(float(np.percentile(tracked_err, 95)), 3),
            "extra_r_e_needed_m": round(max(0.0, (s["max_tracking_error_m"] or 0.0) - s["tracking_bound_m"]), 3),
            "forced_mean": s["forced_mean"], "forced_max": s["forced_max"], "exceed": s["exceed"],
            "exceed_ci95": clopper_pearson_interval(s["exceed"], n, 0.95),
            "min_separation_m": s["min_separation_m"], "collision_radius_m": s["collision_radius_m"],
            "seconds": round(time.perf_counter() - start, 1),
        }
        print(json.dumps(row), flush=True)
        with open(path, "a") as f:
            f.write(json.dumps(row) + "\n")


def load(path: pathlib.Path) -> list[dict]:
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def figure(rows: list[dict], path: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ref = next((r for r in rows if r["sweep"] == "reference"), None)
    panels = [("lag", "actuator time constant [s]"), ("mass", "mass [kg] (m / c_lin = mass / 20 s)"),
              ("drag", "angular drag c_ang [N m s/rad] (I / c_ang = 0.01 / c_ang s)")]
    panels = [(k, label) for k, label in panels if any(r["sweep"] == k for r in rows)]
    fig, axes = plt.subplots(3, len(panels), figsize=(max(6.0, 4.6 * len(panels)), 9.5), squeeze=False)
    for col, (sweep, label) in enumerate(panels):
        rs = sorted((r for r in rows if r["sweep"] == sweep), key=lambda r: r["value"])
        x = np.asarray([r["value"] for r in rs])
        for row, (key, name) in enumerate((("violation", "guarantee-violation episodes"),
                                           ("tracking_violation", "episodes with tracking error > r_e"))):
            ax = axes[row, col]
            p = np.asarray([r[f"{key}_episodes"] / r["episodes"] for r in rs])
            ci = np.asarray([r[f"{key}_ci95"] for r in rs])
            ax.errorbar(x, p, yerr=[p - ci[:, 0], ci[:, 1] - p], marker="o", capsize=3, label="pymunk-dynamic")
            if ref is not None:
                ax.axhline(ref[f"{key}_episodes"] / ref["episodes"], color="k", ls="--", lw=1, label="Dubins (jax)")
            ax.set_ylim(-0.03, 1.03)
            ax.set_ylabel(f"{name}\n(95% Clopper-Pearson)")
            ax.legend(fontsize=7)
        ax = axes[2, col]
        ax.plot(x, [r["max_tracking_error_m"] for r in rs], "o-", label="max tracking error [m]")
        ax.plot(x, [r["tracking_error_p95_m"] for r in rs], "s-", label="95th pct. per-episode max [m]")
        ax.axhline(rs[0]["tracking_bound_m"], color="r", ls=":", label="r_e")
        if ref is not None:
            ax.axhline(ref["max_tracking_error_m"], color="k", ls="--", lw=1, label="Dubins (jax) max")
        ax2 = ax.twinx()
        ax2.plot(x, [r["forced_mean"] for r in rs], "^-", color="tab:green", label="mean |N^RP|")
        ax2.set_ylabel("mean |N^RP|", color="tab:green")
        ax2.set_ylim(0.0, 1.2 * max([2.0] + [r["forced_max"] for r in rs]))  # k̄ = 2 on town
        ax.set_xlabel(label)
        ax.set_ylabel("tracking error [m]")
        ax.legend(fontsize=7, loc="upper left")
        axes[0, col].set_title(f"{sweep} sweep ({rs[0]['episodes'] if rs else 0} episodes each)")
    fig.suptitle("Model mismatch on town (k̄ = 2, max-k intruder):\nDubins guarantees on rigid-body vehicles")
    fig.tight_layout()
    tmp = f"{path}.tmp.png"
    fig.savefig(tmp, dpi=110)
    os.replace(tmp, path)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="runs/model_mismatch", help="directory of results.jsonl")
    p.add_argument("--sweep", nargs="+", choices=["lag", "mass", "drag"], default=["lag", "mass", "drag"])
    p.add_argument("--lags", type=float, nargs="+", default=list(LAGS), help="actuator time constants [s]")
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--batch-size", type=int, default=50)
    p.add_argument("--scenario", default="town")
    p.add_argument("--kbar", type=int, default=2)
    p.add_argument("--intruder", default="max-k")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--figure", default=None, help="draw this PNG from the results instead of running")
    args = p.parse_args(argv)
    out = pathlib.Path(args.out)
    if args.figure:
        figure(load(out / "results.jsonl"), args.figure)
        return 0
    run(out, args.sweep, args.episodes, args.batch_size, args.scenario, args.kbar, args.intruder, args.seed,
        tuple(args.lags))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

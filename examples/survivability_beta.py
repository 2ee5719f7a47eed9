"""Sensitivity of the survivability study to the discount beta of the receding-horizon objective (eq. 5).

    python examples/survivability_beta.py [--betas 0.1 0.5 0.9] [--instances 100] [--out runs/survivability-beta]

Runs the study (``stp_env.survivability.study``) for each beta on three scenarios, (N_p, N_u) = (100, 100),
(100, 250) and (250, 100), on the same instances (seed 0: the study's first instances), and prints per scenario
and policy the survival rate with its 95 % Clopper-Pearson interval, the paired difference of pi_Nf and pi_S, and
each policy's paired survival difference against the first beta given (same instances, 95 % normal intervals).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from stp_env.survivability import analysis
from stp_env.survivability.config import PlannerConfig, StudyConfig, TrafficConfig
from stp_env.survivability.records import read_study
from stp_env.survivability.study import run_study

SCENARIOS = [(100, 100), (100, 250), (250, 100)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--betas", type=float, nargs="+", default=[0.5, 0.1, 0.9], help="the first is the reference")
    ap.add_argument("--instances", type=int, default=100)
    ap.add_argument("--out", default="runs/survivability-beta")
    args = ap.parse_args()
    result, outcomes = {}, {}
    for beta in args.betas:
        out = Path(args.out) / f"beta{beta:g}"
        results = {}
        for p, u in SCENARIOS:
            # the earlier model (local traffic, landing count), with which docs/survivability.md measured it
            config = StudyConfig(n_partial=(p,), n_unknown=(u,), n_instances=args.instances,
                                 traffic=TrafficConfig(model="local"),
                                 planner=PlannerConfig(beta=beta, nf_count="landing"))
            run_study(config, out / f"{p}-{u}")
            rows = read_study(out / f"{p}-{u}")
            summary = analysis.summarize(rows, config.policies)[(p, u)]
            table = analysis.outcome_table(rows, config.policies)[(p, u)]
            _, nf = analysis.indicators(table["Nf"], "survival")
            _, s = analysis.indicators(table["S"], "survival")
            results[f"{p},{u}"] = {q: summary[q]["survival"] for q in config.policies}
            results[f"{p},{u}"]["survival[Nf]-survival[S]"] = analysis.paired(nf, s)
            outcomes[(beta, p, u)] = table
        result[beta] = results
    ref = args.betas[0]
    for beta in args.betas[1:]:
        for p, u in SCENARIOS:
            for q in ("R", "Nf", "S", "AvgR"):
                a, b = outcomes[(beta, p, u)][q], outcomes[(ref, p, u)][q]
                common = sorted(set(a) & set(b))
                result[beta][f"{p},{u}"][f"survival[{q}] - survival at beta {ref:g}"] = analysis.paired(
                    np.array([a[i] in "GA" for i in common], float), np.array([b[i] in "GA" for i in common], float))
    print(json.dumps(result, indent=1, default=lambda o: float(o) if isinstance(o, np.floating) else str(o)))


if __name__ == "__main__":
    main()

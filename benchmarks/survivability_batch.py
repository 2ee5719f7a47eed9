"""Survivability study: missions in batches against one mission at a time, one JSON line.

    python benchmarks/survivability_batch.py [--groups 4] [--partial 175] [--batch-groups 1 4]

The slice: ``--groups`` groups of the study (instance ``i`` of the six scenarios ``(N_p, N_u)`` with the N_p of
``--partial``, every ``N_u`` of the grid, every policy; the study's unit of work), default configuration (the
paper's mission, traffic and planner). Peers, on the same slice and in the same process:

* ``per_mission``: :func:`stp_env.survivability.study.run_instance` group by group (instances of one group share
  their robustness and first tables), what ``run_study(..., batch_groups=0)`` runs;
* ``batched_k``: :func:`stp_env.survivability.study.run_groups` on ``k`` groups at a time (what ``run_study`` runs
  with ``batch_groups=k``; ``k = 1`` is the default): the instances' Monte Carlo robustness in one program, then
  every mission of the ``6 k`` instances and four policies in one compiled program
  (:mod:`stp_env.survivability.batch`).

Every path must give the same missions (``same_missions``; the timing columns aside). Times exclude compilation:
each path first flies a warm-up slice of the same shapes (other instances). ``instances_per_s`` is over the
slice's instances (six per group); ``ratio`` is the batched rate over the per-mission one; ``full_study_h`` the
projected wall time of the whole 86,436-instance study at that rate in one process (two processes on two cores
share it: about half, on an idle machine). ``cpu_s`` is this process's user + system time, ``loadavg`` the machine's
1-minute load average before the case (the machine is shared).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import time

FULL_STUDY_INSTANCES = 36 * 2401
KEYS = ("n_partial", "n_unknown", "instance", "policy", "outcome", "reveals", "omega_switch", "n_dp", "windows")


def cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--groups", type=int, default=4, help="groups in the timed slice (six instances each)")
    ap.add_argument("--partial", type=int, default=175, help="N_p of the slice's groups")
    ap.add_argument("--batch-groups", type=int, nargs="+", default=[1], help="groups per batch (each a peer)")
    ap.add_argument("--first-instance", type=int, default=50_000, help="instance index of the slice's first group")
    args = ap.parse_args()
    from stp_env.survivability.config import StudyConfig
    from stp_env.survivability.graph import build_graph
    from stp_env.survivability.names import LEVELS
    from stp_env.survivability.study import run_groups, run_instance

    graph = build_graph()
    config = StudyConfig()
    groups = [(args.first_instance + k, args.partial, LEVELS) for k in range(args.groups)]
    warm = [(args.first_instance + 10_000 + k, args.partial, LEVELS) for k in range(max(args.batch_groups))]
    n = sum(len(us) for _, _, us in groups)

    def per_mission(gs):
        rows = []
        for i, p, us in gs:
            shared: dict = {}
            rows += [r for u in us for r in run_instance(graph, config, p, u, i, shared)]
        return rows

    def batched(k):
        def run(gs):
            return [r for j in range(0, len(gs), k)
                    for r in run_groups(graph, config, gs[j:j + k], pad_instances=len(LEVELS) * k)]
        return run

    peers = {"per_mission": per_mission, **{f"batched_{k}": batched(k) for k in args.batch_groups}}
    out, missions = {}, {}
    for name, fn in peers.items():
        fn(warm)                                                          # compile every shape
        load = os.getloadavg()[0]
        c0, t0 = cpu(), time.perf_counter()
        rows = fn(groups)
        wall, c = time.perf_counter() - t0, cpu() - c0
        missions[name] = [tuple(r[key] for key in KEYS) for r in rows]
        out[name] = {"instances_per_s": round(n / wall, 3), "wall_s": round(wall, 2), "cpu_s": round(c, 2),
                     "full_study_h": round(FULL_STUDY_INSTANCES / (n / wall) / 3600, 2), "loadavg": load}
    base = out["per_mission"]["instances_per_s"]
    ratios = {name: round(v["instances_per_s"] / base, 2) for name, v in out.items() if name != "per_mission"}
    print(json.dumps({"case": "survivability_batch", "n_partial": args.partial, "n_unknown": list(LEVELS),
                      "instances": n, "missions": n * len(config.policies), **out, "ratio": ratios,
                      "same_missions": all(m == missions["per_mission"] for m in missions.values())}), flush=True)


if __name__ == "__main__":
    main()

"""``stp-env coobservation``: attacks on co-observation schedules in the UAV simulator.

Evaluates a UAV formation flying past two forbidden zones under a secured schedule (the fewest co-observation
times whose reachability ellipses miss the zones), an unsecured one (every --period seconds), the schedule
secured with the exact reachable sets of the Dubins vehicle in wind (--schedules exact) and one secured as if there
were no wind (--schedules windless, a control that must fail), against scripted
attackers (reckless, opportunistic, optimistic: the ellipses' own worst case, best with --wind-model tailwind), an
honest control (honest: nobody deviates), learned ones (learned:<path to attacker.npz>) and the searched attacker
(searched: a cross-entropy search over the departure time, entry point, return point and speed of a vehicle
compromised from the start, --search-budget attacks per schedule, whether or not the ellipse inequality says the
attack can succeed). Prints markdown tables (outcomes; entry attempts, undetected entries with exact bounds and
the attempts' time margins) and writes results.json, results.md and margins.png to --out.
"""

from __future__ import annotations

import json
import shutil
import time
from pathlib import Path

SCHEDULES = ("secured", "unsecured", "exact", "windless")
SEARCHED = "searched"


def add_parser(sub) -> None:
    """Register the ``coobservation`` subcommand on an argparse sub-parser collection."""
    from stp_env import cli_kit as kit

    p = sub.add_parser("coobservation", help="attack co-observation schedules in the UAV simulator (success rate "
                                             "with exact bounds, detection rate and delay)",
                       formatter_class=kit.HelpFormatter, description=__doc__.split("\n\n")[1])
    p.add_argument("--episodes", type=kit.positive_int, default=10_000, help="episodes per (schedule, attacker)")
    kit.add_batch_size(p, "episodes simulated in one batched rollout", default=1000)
    p.add_argument("--attackers", nargs="+", default=["honest", "reckless", "opportunistic", "optimistic"],
                   help="honest, reckless, opportunistic, optimistic, learned:<attacker.npz>, or searched (the "
                        "cross-entropy search of stp_env.falsify.search, --search-budget attacks per schedule)")
    p.add_argument("--search-budget", type=kit.positive_int, default=2000,
                   help="attacks the searched attacker evaluates per schedule")
    p.add_argument("--schedules", nargs="+", choices=SCHEDULES, default=["secured", "unsecured"],
                   help="which schedules to attack (exact: secured with the exact regions, a level-set solve on "
                        "first use, about 10 minutes on 2 cores; windless: secured with ellipses that leave the "
                        "wind out of the attacker's speed, deliberately unsound: the control showing that the "
                        "wind term is needed)")
    p.add_argument("--period", type=kit.real(0.0, 1e6, lo_open=True), default=90.0,
                   help="the unsecured schedule's period [s]")
    kit.add_wind_model(p, "uniform", "how each vehicle's wind (6 m/s disk) is drawn")
    kit.add_seed(p, "the episodes (the same for every pair)")
    kit.add_out(p, "coobservation-eval")
    kit.add_ray(p, "the batches of episodes of every (schedule, attacker) pair")
    kit.add_cpu_devices(p)
    kit.add_progress(p)
    p.set_defaults(run=run)


def resolve_attackers(names):
    """Attacker policies by name (``learned:<path>`` loads an exported MLP; raises ``ValueError`` otherwise)."""
    from stp_env.coobservation.attackers import ATTACKERS

    out = {}
    for name in names:
        if name == SEARCHED:
            continue  # not a policy: the search runs per schedule (evaluation.run_searched)
        if name.startswith("learned:"):
            path = Path(name.split(":", 1)[1])  # read under the loader contract (stp_env.policies.learned.load_mlp)
            from stp_env.coobservation.learned import mlp_attacker

            out[name] = mlp_attacker(path, name="learned")
        elif name in ATTACKERS:
            out[name] = ATTACKERS[name]
        else:
            raise ValueError(f"--attackers: unknown attacker {name!r}; allowed: {', '.join(ATTACKERS)}, {SEARCHED} "
                             "or learned:<path to attacker.npz>.")
    return out


def schedules_for(scenario, names, period: float, progress: bool = True) -> dict:
    """Observation times of the named schedules."""
    from stp_env.coobservation import checkpoints

    ell = checkpoints.ellipse_test(scenario.forbidden, scenario.attacker_speed, scenario.ellipse_radius)
    out = {}
    for name in names:
        if name == "secured":
            out[name] = scenario.secured_times(ell)
        elif name == "unsecured":
            out[name] = scenario.uniform_times(period)
        elif name == "windless":
            out[name] = scenario.secured_times(checkpoints.ellipse_test(scenario.forbidden, scenario.v_max,
                                                                        scenario.ellipse_radius))
        else:
            from stp_env.coobservation import exact

            cfg = exact.ExactRegionConfig(v_min=0.0, v_max=scenario.v_max, omega_max=scenario.omega_max,
                                          wind=scenario.wind, radius=scenario.ellipse_radius, horizon=90.0,
                                          spacing=25.0, n_headings=24)
            regions = exact.compute(cfg, progress=progress)
            out[name] = scenario.secured_times(regions.secure_fn(scenario.forbidden, fallback=ell))
    return out


def run(args) -> int:
    import jax
    import numpy as np

    from stp_env import cli_kit as kit
    from stp_env.coobservation import evaluation, threat
    from stp_env.coobservation.uav import FormationScenario
    from stp_env.evaluation.pipeline import PIECES, check_output_dir
    from stp_env.files import atomic_open

    attackers = resolve_attackers(args.attackers)  # bad names fail before any computation
    out = check_output_dir(args.out)  # so that the results are not lost at the end
    kit.apply_cpu_devices(args)       # before JAX's first computation
    executor = kit.executor(args)     # --ray without ray installed, or a cluster not reached, fails here
    scenario = FormationScenario(wind_model=args.wind_model)
    start = time.time()
    params = scenario.params(progress=not args.no_progress)
    times = schedules_for(scenario, args.schedules, args.period, progress=not args.no_progress)
    schedules = {k: scenario.schedule(v) for k, v in times.items()}
    m = max(len(s) for s in schedules.values())
    threats = {k: threat.threat_params(s, scenario.forbidden, scenario.observation_radius, pad_to=m)
               for k, s in schedules.items()}
    window = (0.0, scenario.duration - 10.0)
    # finished batches wait in OUT/pieces until the results are written: a killed evaluation resumes
    rows = evaluation.run(params, threats, attackers, args.episodes, t_window=window, batch=args.batch_size,
                          seed=args.seed, progress=not args.no_progress, executor=executor,
                          pieces_dir=out / PIECES,
                          fingerprint=evaluation.attackers_digest(list(attackers))) if attackers else []
    searches = {}
    if SEARCHED in args.attackers:
        found, searches = evaluation.run_searched(params, threats, args.search_budget, seed=args.seed,
                                                  progress=not args.no_progress, executor=executor)
        rows += found
    table = evaluation.markdown(rows) + "\n\nEntry attempts:\n\n" + evaluation.attempts_markdown(rows)
    print(table)
    result = {"scenario": repr(scenario), "schedules": times, "compromise_window_s": list(window),
              "episodes": args.episodes, "seed": args.seed, "rows": [r.as_dict() for r in rows],
              "searched": searches, "search_budget": args.search_budget if searches else None,
              "seconds": round(time.time() - start, 1), "jax": jax.__version__, "numpy": np.__version__}
    for name, text in (("results.json", json.dumps(result, indent=1, default=float)), ("results.md", table)):
        with atomic_open(out / name) as fh:
            fh.write(text + "\n")
    import matplotlib

    matplotlib.use("Agg")
    from stp_env.coobservation.plots import margin_histograms

    margin_histograms(rows, out / "margins.png")
    shutil.rmtree(out / PIECES, ignore_errors=True)
    return 0

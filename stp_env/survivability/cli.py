"""``stp-env survivability``: run (or resume) the scenario sweep of the survivability paper and write its results
and figures. Registered by :mod:`stp_env.cli` through :func:`add_parser` and :func:`run`."""

from __future__ import annotations

import json
from pathlib import Path


def add_parser(sub) -> None:
    """Add the ``survivability`` subcommand to an argparse subparsers object (the policies and levels come from
    :mod:`stp_env.survivability.names`: building the parser imports no JAX)."""
    from stp_env import cli_kit as kit
    from stp_env.survivability import names

    policies, traffic_models, nf_counts = names.POLICIES, names.TRAFFIC_MODELS, names.NF_COUNTS
    reveals, batch_groups = names.REVEAL_MODELS, names.BATCH_GROUPS
    levels = list(names.LEVELS)

    sp = sub.add_parser(
        "survivability", help="mission survivability under partially known and unknown intruders (scenario sweep)",
        formatter_class=kit.HelpFormatter,
        description="Fly the Bay-Area mission of the survivability paper (Santa Clara to UCSF, alternative sites SFO "
                    "and Stanford) under receding-horizon control with each policy through the same traffic "
                    "instances of every scenario (N_p partially known, N_u unknown intruders). Appends every "
                    "mission to OUT/missions.csv (an interrupted run resumes), then writes OUT/results.{json,csv,md} "
                    "(rates with 95 % Clopper-Pearson intervals, the switching thresholds phi and eta with "
                    "bootstrap intervals, the paper's findings next to ours) and the figures OUT/fig7..fig12*.png.")
    kit.add_out(sp, "survivability", "study directory (an earlier study there is resumed)")
    sp.add_argument("--instances", type=kit.positive_int, default=2401, help="traffic instances per scenario")
    sp.add_argument("--partial", type=kit.integer(0, 100_000), nargs="+", default=levels,
                    help="values of N_p, the partially known intruders")
    sp.add_argument("--unknown", type=kit.integer(0, 100_000), nargs="+", default=levels,
                    help="values of N_u, the unknown intruders")
    sp.add_argument("--policies", nargs="+", choices=policies, default=list(policies),
                    help="R: pi_R, Nf: pi_Nf, S: pi_S, AvgR: pi_Avg(R)")
    kit.add_seed(sp, "the study (traffic, Monte Carlo, tie-breaking)")
    sp.add_argument("--beta", type=kit.unit_interval, default=0.5,
                    help="discount of the objective's future term (eq. 5), in [0, 1]")
    sp.add_argument("--n-mc", type=kit.positive_int, default=2500,
                    help="Monte Carlo realisations per segment robustness")
    sp.add_argument("--traffic", choices=traffic_models, default=traffic_models[0],
                    help="intruder traffic model: paper (default; Section III-B: control points anywhere in the "
                         "area, times in (t_0, t_fu), hovering degree-1 intruders, realisations over the whole "
                         "uncertainty tube) or local (the earlier default: short hops around a uniform entry point, "
                         "entry times over the endurance); see docs/survivability.md")
    sp.add_argument("--hover-share", type=kit.real(0.0, 1.0), default=None,
                    help="with --traffic paper: probability that an intruder hovers (default 0.1, the project's "
                         "choice: the paper gives none)")
    sp.add_argument("--max-speed", type=kit.positive, default=None,
                    help="with --traffic paper: condition each intruder's nominal path on a mean ground speed of at "
                         "most this [m/s] (default: unbounded; 40 is the top of the paper's cruise speeds)")
    sp.add_argument("--nf-count", choices=nf_counts, default=nf_counts[0],
                    help="what pi_Nf counts: goal (default; the paper's Algorithm 1: trajectories to the terminal "
                         "set Omega, summed over the successor's cell) or landing (the earlier default: trajectories "
                         "from the successor state to any landing site)")
    sp.add_argument("--reveal", choices=reveals, default=reveals[0],
                    help="when an intruder's actual path becomes known: segment (default; a conflict anywhere on the "
                         "segment chosen at a decision point), step (a conflict in the next time step; one found "
                         "after the decision point ends the mission as an emergency landing) or radius (as step, "
                         "and any intruder within --sense-km of the ownship)")
    sp.add_argument("--sense-km", type=kit.positive, default=None,
                    help="with --reveal radius: the sensing radius [km] (required there)")
    sp.add_argument("--batch-groups", type=kit.integer(0, 100_000), default=batch_groups,
                    help="groups of instances (one instance of the scenarios with the same N_p) whose missions, every "
                         "policy's, fly in one compiled program (a piece of the study; the same missions; meant for "
                         "an accelerator: on a CPU about half as fast); 0 (default): one mission at a time")
    sp.add_argument("--max-hours", type=kit.real(0.0, 1e6, lo_open=True), default=None,
                    help="stop after this much wall time [h] (rerun the same command to resume; default: no limit)")
    kit.add_ray(sp, "the groups of instances (one instance of the scenarios with the same N_p)")
    sp.add_argument("--bootstrap", type=kit.positive_int, default=2000, help="bootstrap resamples for thresholds")
    sp.add_argument("--report-only", action="store_true", help="only (re)write results and figures from OUT")
    sp.add_argument("--no-figures", action="store_true", help="skip the figures")
    kit.add_progress(sp)
    sp.set_defaults(run=run)


def config_from_args(args):
    from stp_env.survivability.config import PlannerConfig, StudyConfig, TrafficConfig

    return StudyConfig(n_partial=tuple(args.partial), n_unknown=tuple(args.unknown), n_instances=args.instances,
                       seed=args.seed, policies=tuple(args.policies),
                       traffic=TrafficConfig(model=args.traffic, hover_share=args.hover_share,
                                             max_speed=args.max_speed),
                       planner=PlannerConfig(beta=args.beta, n_mc=args.n_mc, nf_count=args.nf_count,
                                             reveal=args.reveal, sense_km=args.sense_km))


def use_study_cache(out) -> Path | None:
    """Keep the study's compiled programs next to its results, in ``OUT/jax-cache`` (workers and restarts of a study
    reuse them), if the folder passes the check of every folder that holds executables
    (:func:`stp_env.compilation_cache.private_cache_dir`: created private, not another user's, not writable by
    others); the folder used, or ``None`` (a warning says why; the process keeps the compilation cache it had).
    ``STP_ENV_COMPILATION_CACHE=0`` turns this cache off too."""
    from stp_env import compilation_cache

    if not compilation_cache.enabled_by_environment():
        return None
    cache = compilation_cache.private_cache_dir(
        Path(out) / "jax-cache", what="the study's compilation cache",
        advice=f"Make it private (chmod 700) or remove it, or set {compilation_cache.ENV_VAR}=0 to silence this.")
    if cache is None:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    return cache


def run(args) -> int:
    """Run the subcommand (``ValueError`` for bad input: the caller prints it and exits with 2)."""
    from stp_env import cli_kit as kit
    from stp_env.survivability.records import check_study_metadata
    from stp_env.survivability.report import build_report, figures
    from stp_env.survivability.study import run_study

    config = config_from_args(args)
    if args.report_only:
        check_study_metadata(config, args.out)  # another configuration's study is not reported as this one
    else:
        use_study_cache(args.out)
        executor = kit.executor(args)  # --ray without ray installed, or a cluster not reached, fails here
        run_study(config, args.out, progress=not args.no_progress,
                  max_seconds=None if args.max_hours is None else 3600.0 * args.max_hours,
                  executor=executor, batch_groups=args.batch_groups)
    report = build_report(config, args.out, n_boot=args.bootstrap)
    if not args.no_figures:
        import matplotlib

        matplotlib.use("Agg")
        figures(config, args.out, report)
    print(json.dumps({"out": str(args.out), "timing": report["timing"], "findings": report["findings"]},
                     default=str)[:4000])
    return 0

"""``stp-env survivability``: run (or resume) the scenario sweep of the survivability paper and write its results
and figures. Registered by :mod:`stp_env.cli` through :func:`add_parser` and :func:`run`."""

from __future__ import annotations

import argparse
import json
from pathlib import Path


def _types():
    """The option types (built on the main CLI's checked-number factory)."""
    from stp_env.cli import _number, _positive

    return {"positive_int": _positive(int), "count": _number(int, "an integer", lambda v: v >= 0, ">= 0"),
            "unit": _number(float, "a number", lambda v: 0.0 <= v <= 1.0, "in [0, 1]"),
            "hours": _positive(float)}


def _worker(text: str) -> tuple[int, int]:
    try:
        i, n = (int(v) for v in text.split("/"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected I/N (e.g. 0/2), got {text!r}") from None
    if not 0 <= i < n:
        raise argparse.ArgumentTypeError(f"need 0 <= I < N, got {text}")
    return i, n


def add_parser(sub) -> None:
    """Add the ``survivability`` subcommand to an argparse subparsers object."""
    from stp_env.survivability.config import POLICIES
    from stp_env.survivability.study import LEVELS

    t = _types()

    sp = sub.add_parser(
        "survivability", help="mission survivability under partially known and unknown intruders (scenario sweep)",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        description="Fly the Bay-Area mission of the survivability paper (Santa Clara to UCSF, alternative sites SFO "
                    "and Stanford) under receding-horizon control with each policy through the same traffic "
                    "instances of every scenario (N_p partially known, N_u unknown intruders). Appends every "
                    "mission to OUT/missions.csv (an interrupted run resumes), then writes OUT/results.{json,csv,md} "
                    "(rates with 95 % Clopper-Pearson intervals, the switching thresholds phi and eta with "
                    "bootstrap intervals, the paper's findings next to ours) and the figures OUT/fig7..fig12*.png.")
    sp.add_argument("--out", default="survivability", help="study directory")
    sp.add_argument("--instances", type=t["positive_int"], default=2401, help="traffic instances per scenario")
    sp.add_argument("--partial", type=t["count"], nargs="+", default=list(LEVELS), help="values of N_p")
    sp.add_argument("--unknown", type=t["count"], nargs="+", default=list(LEVELS), help="values of N_u")
    sp.add_argument("--policies", nargs="+", choices=POLICIES, default=list(POLICIES),
                    help="R: pi_R, Nf: pi_Nf, S: pi_S, AvgR: pi_Avg(R)")
    sp.add_argument("--seed", type=t["count"], default=0, help="base seed (traffic, Monte Carlo, tie-breaking)")
    sp.add_argument("--beta", type=t["unit"], default=0.5, help="discount of the objective's future term (eq. 5)")
    sp.add_argument("--n-mc", type=t["positive_int"], default=2500,
                    help="Monte Carlo realisations per segment robustness")
    sp.add_argument("--max-hours", type=t["hours"], default=None,
                    help="stop after this much wall time (rerun the same command to resume)")
    sp.add_argument("--worker", type=_worker, default=(0, 1), metavar="I/N",
                    help="run every N-th group of instances (one instance of the scenarios with the same N_p) "
                         "starting at the I-th (I = 0 .. N-1), so that N processes with the same options share the "
                         "study")
    sp.add_argument("--bootstrap", type=t["positive_int"], default=2000, help="bootstrap resamples for thresholds")
    sp.add_argument("--report-only", action="store_true", help="only (re)write results and figures from OUT")
    sp.add_argument("--no-figures", action="store_true", help="skip the figures")
    sp.add_argument("--no-progress", action="store_true", help="hide the progress bar")


def config_from_args(args):
    from stp_env.survivability.config import PlannerConfig
    from stp_env.survivability.study import StudyConfig

    return StudyConfig(n_partial=tuple(args.partial), n_unknown=tuple(args.unknown), n_instances=args.instances,
                       seed=args.seed, policies=tuple(args.policies),
                       planner=PlannerConfig(beta=args.beta, n_mc=args.n_mc))


def run(args) -> int:
    """Run the subcommand (``ValueError`` for bad input: the caller prints it and exits with 2)."""
    from stp_env.survivability.report import build_report, figures
    from stp_env.survivability.study import run_study

    config = config_from_args(args)
    if not args.report_only:
        import jax

        # Compiled programs persist next to the results: workers and restarts of a study reuse them.
        cache = Path(args.out) / "jax-cache"
        cache.mkdir(parents=True, exist_ok=True)
        jax.config.update("jax_compilation_cache_dir", str(cache))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
        run_study(config, args.out, progress=not args.no_progress,
                  max_seconds=None if args.max_hours is None else 3600.0 * args.max_hours, worker=args.worker)
    report = build_report(config, args.out, n_boot=args.bootstrap)
    if not args.no_figures:
        import matplotlib

        matplotlib.use("Agg")
        figures(config, args.out, report)
    print(json.dumps({"out": str(args.out), "timing": report["timing"], "findings": report["findings"]},
                     default=str)[:4000])
    return 0

"""``stp-env falsify``: search for the inputs that break a claimed bound, and replay what was found."""

from __future__ import annotations

import argparse
import json
import math

from stp_env.falsify import targets


def _option(text: str):
    name, sep, value = text.partition("=")
    if not sep or not name.isidentifier():
        raise argparse.ArgumentTypeError(f"expected NAME=VALUE, got {text!r}")
    try:
        return name, int(value)
    except ValueError:
        pass
    try:
        number = float(value)
    except ValueError:
        return name, value
    if not math.isfinite(number):
        raise argparse.ArgumentTypeError(f"{name}: expected a finite number, got {value!r}")
    return name, number


def add_parser(sub) -> None:
    from stp_env import cli_kit as kit

    fa = sub.add_parser(
        "falsify", help="adversarial search against a claimed bound (tracking r_e, avoidance R_c, k̄)",
        formatter_class=kit.HelpFormatter,
        description="Search --attacks attacks through the simulator for the input that breaks a bound: "
                    "'tracking' (reference in U^p and wind against the tracker; bound r_e), 'avoidance' (intruder "
                    "start outside V^A, its controls and the winds against u^A; bound R_c), 'kbar' (intruder "
                    "appearance, spawn and path against a planned scenario; bound k̄). Prints one JSON line with "
                    "the worst value found, the bound and the margin (negative: broken), and writes a replayable "
                    "counterexample.json with a figure to --out. --replay FILE recomputes a saved one.")
    fa.add_argument("--target", choices=targets.names(), default="tracking",
                    help="the bound to attack (stp_env.falsify.targets: the built-in targets and any registered)")
    kit.add_scenario(fa, "town", "registered scenario (vehicle, tables, plan)")
    fa.add_argument("--kbar", type=kit.kbar, default=None,
                    help=f"the scenario's k̄ (1-{kit.MAX_KBAR}; default: the scenario's own)")
    fa.add_argument("--wind", type=kit.real(0.0, 1000.0), default=None,
                    help="the scenario's wind bound [m/s] (default: the scenario's own; e.g. --scenario tiny --wind 11 "
                         "for the tracking and avoidance attacks at 11 m/s)")
    kit.add_wind_model(fa, "worst", "the environment's wind model (kbar attack)")
    fa.add_argument("--control-dt", type=kit.real(0.0, 0.1, lo_open=True), default=0.02,
                    help="inner control period of the vehicles [s]; the guarantees are certified for 0.005-0.02 s")
    fa.add_argument("--option", type=_option, action="append", default=[], metavar="NAME=VALUE",
                    help="an attack option, e.g. wind=worst, intruder=hj, horizon=40, segment=0.5 (repeatable)")
    fa.add_argument("--attacks", type=kit.positive_int, default=10_000, help="attacks to simulate (the search budget)")
    fa.add_argument("--method", choices=("cem", "gradient", "both"), default="cem", help="search method")
    fa.add_argument("--population", type=kit.positive_int, default=250,
                    help="cross-entropy samples per iteration and restart")
    fa.add_argument("--restarts", type=kit.positive_int, default=4, help="independent cross-entropy searches")
    kit.add_batch_size(fa, "attacks simulated at once", default=1000)
    kit.add_seed(fa, "the search")
    fa.add_argument("--no-game-seed", action="store_true",
                    help="do not start the search from the game's own worst strategies (the attack's seeds)")
    kit.add_out(fa, "falsify")
    fa.add_argument("--replay", default=None, metavar="FILE",
                    help="recompute the value of a saved counterexample.json instead of searching")
    fa.add_argument("--no-figures", action="store_true", help="write no figure")
    kit.add_ray(fa, "the search's restarts")
    kit.add_cpu_devices(fa)
    kit.add_progress(fa)
    fa.set_defaults(run=run_cli)


def run_cli(args) -> int:
    import shutil

    from stp_env import cli_kit as kit
    from stp_env.evaluation.pipeline import PIECES, check_output_dir
    from stp_env.falsify.counterexample import AttackSpec, replay, run, save
    from stp_env.falsify.search import SearchConfig

    if args.replay is not None:
        recorded, recomputed = replay(args.replay)
        same = recorded == recomputed
        print(json.dumps({"file": args.replay, "recorded": recorded, "recomputed": recomputed, "identical": same}))
        return 0 if same else 1
    spec = AttackSpec(target=args.target, scenario=args.scenario, kbar=args.kbar, wind=args.wind,
                      wind_model=args.wind_model, control_dt=args.control_dt, options=tuple(args.option))
    config = SearchConfig(method=args.method, budget=args.attacks, population=args.population,
                          restarts=args.restarts, batch=args.batch_size)
    out = check_output_dir(args.out)  # before the search, so that its result is not lost at the end
    kit.apply_cpu_devices(args)       # before JAX's first computation
    executor = kit.executor(args)     # --ray without ray installed, or a cluster not reached, fails here
    # finished restarts wait in OUT/pieces until the counterexample is written: a killed search resumes
    outcome = run(spec, config, args.seed, progress=not args.no_progress, seeded=not args.no_game_seed,
                  executor=executor, pieces_dir=out / PIECES)
    path = save(outcome, out, plot=not args.no_figures)
    shutil.rmtree(out / PIECES, ignore_errors=True)
    summary = outcome.summary()
    summary["counterexample"] = str(path)
    print(json.dumps(summary))
    return 0

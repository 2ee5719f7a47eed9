"""The ``stp-env`` command line.

Subcommands:

* ``avoid-region``: compute the intruder avoid region ``V^A(0, t_IAT)`` of two Dubins vehicles in wind
  (intruder paper eqs. 13-16) and write a PNG.
* ``plan``: plan a registered scenario with robust trajectory tracking (intruder-aware when the scenario has a
  k̄) and write a PNG of the nominal trajectories.
* ``precompute``: build (or load from the cache) every reachability artifact of the default scenario (avoid
  region, tracking-error bound, relative buffer regions and disk radii for each k̄), print a JSON summary and
  write the figures.
* ``evaluate``: Monte Carlo evaluation of the k̄ bound (how many vehicles an intruder forces to avoid) over
  intruders, k̄ values and wind, with exact confidence bounds; prints a markdown table and writes results, replayable
  bad episodes and figures (:mod:`stp_env.evaluation`).
* ``render``: one episode (from a seed and an episode index, or a saved event) as an animated GIF.
* ``falsify``: adversarial search through the simulator against a claimed bound (the tracking-error bound, the
  danger zone under avoidance, k̄), with a replayable counterexample (:mod:`stp_env.falsify`).
* ``survivability``: the mission-survivability study (partially known and unknown intruders, four planning
  policies under receding-horizon control): a resumable scenario sweep, results and figures
  (:mod:`stp_env.survivability`).
* ``coobservation``: attacks on co-observation schedules by a compromised vehicle (:mod:`stp_env.coobservation.cli`).
* ``data``: make, check and repair plans, convert planning checkpoints, ship reachability artifacts and learned
  intruders (:mod:`stp_env.data_tools`).
* ``train-intruder``: train a learned intruder with Stable-Baselines3 (PPO by default) on the native batched
  VecEnv against vehicles running ``u*`` with the HJ safety filter (:mod:`stp_env.rl.train`; needs the ``rl``
  extra); prints the last evaluation as JSON and writes the model, logs and ``intruder.npz`` to ``--out``.

Exit codes: 0 on success, 2 on bad options, unreadable input files or unwritable outputs (with a one-line message
naming the option or file and saying what is wrong). Output locations are checked before any computation. The
options every subcommand shares (seed, batch sizes, output and cache directories, progress, wind model, scenario)
are defined once, in :mod:`stp_env.cli_kit`; building the parser, and ``--help``, import no JAX.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from stp_env import catalog
from stp_env import cli_kit as kit
from stp_env.falsify.cli import add_parser as add_falsify_parser
from stp_env.resources import (
    RESULT_BYTES,
    SOLVER_BYTES_PER_POINT,
    check_grid,
)
from stp_env.rl.cli import add_parser as add_train_intruder_parser
from stp_env.rl.cli import backend


def _check_output_file(path: str, option: str = "--out") -> None:
    """A one-line ``ValueError`` unless ``path`` can be written as a file (checked before computing)."""
    import os
    from pathlib import Path

    from stp_env.artifacts import probe_writable

    out = Path(path)
    if out.is_dir():
        raise ValueError(f"{option} {out}: is a directory; expected a file name.")
    parent = out.parent
    if not parent.is_dir():
        raise ValueError(f"{option} {out}: the directory {parent} does not exist.")
    try:
        probe_writable(parent)
    except OSError as err:
        raise ValueError(f"{option} {out}: cannot write in {parent} ({err.strerror or err}).") from None
    if out.exists() and not os.access(out, os.W_OK):
        raise ValueError(f"{option} {out}: exists and is not writable.")


def _solver_grid(text: str) -> int:
    """``avoid-region --grid``: points per position dimension in ``[3, 1001]`` whose grid (``g x g x`` the next even
    count) fits in the memory available at the solver's bytes per point (:func:`stp_env.resources.check_grid`)."""
    g = kit.integer(3, 1001)(text)
    try:
        check_grid(text, (g, g, g + g % 2))
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).rstrip(".")) from None
    return g


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stp-env", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    av = sub.add_parser("avoid-region", help="compute and plot the intruder avoid region V^A (eqs. 13-16)",
                        formatter_class=kit.HelpFormatter)
    kit.add_out(av, "avoid_region.png", "PNG file to write")
    av.add_argument("--wind", type=kit.real(0.0, 1000.0), default=6.0,
                    help="wind bound of each vehicle and of the intruder [m/s]")
    av.add_argument("--v-max", type=kit.real(0.0, 1000.0, lo_open=True), default=25.0,
                    help="maximum speed of both [m/s]")
    av.add_argument("--omega-max", type=kit.real(0.0, 100.0, lo_open=True), default=2.0,
                    help="maximum turn rate of both [rad/s]")
    av.add_argument("--collision-radius", type=kit.real(0.0, 1e5, lo_open=True), default=100.0,
                    help="R_c, the collision radius [m]")
    av.add_argument("--t-iat", type=kit.real(0.0, 1e4, lo_open=True), default=10.0,
                    help="t_IAT, the longest time the intruder stays [s]")
    av.add_argument("--half-width", type=kit.real(0.0, 1e6, lo_open=True), default=320.0,
                    help="half-width of the relative-position grid box [m]")
    av.add_argument("--grid", type=_solver_grid, default=51,
                    help="grid points per position dimension, 3-1001 (heading gets the next even count, so that "
                         "relative heading 0 is a node; the solver needs at least "
                         f"{SOLVER_BYTES_PER_POINT} bytes per point, checked against the memory available)")
    av.add_argument("--accuracy", choices=["low", "medium", "high", "very_high"], default="very_high",
                    help="solver preset (scheme + time integrator)")
    kit.add_progress(av)
    av.set_defaults(run=_avoid_region)

    pl = sub.add_parser("plan", help="plan a registered scenario (robust trajectory tracking) and plot it",
                        formatter_class=kit.HelpFormatter)
    kit.add_scenario(pl, "tiny")
    pl.add_argument("--kbar", type=kit.kbar, default=None,
                    help=f"plan intruder-aware for this k̄, the most vehicles the intruder may force to avoid "
                         f"(1-{kit.MAX_KBAR}; default: the scenario's own)")
    pl.add_argument("--sta-spacing", type=kit.real(0.0, 1e6), default=None,
                    help="time between consecutive scheduled arrivals [s] (scenarios that take it; default: the "
                         "scenario's own)")
    kit.add_out(pl, "plan.png", "PNG file to write")
    kit.add_cache_dir(pl)
    kit.add_progress(pl)
    pl.set_defaults(run=_plan)

    pre = sub.add_parser("precompute", help="build the reachability artifacts of the default scenario (cached)",
                         formatter_class=kit.HelpFormatter)
    pre.add_argument("--wind", type=kit.real(0.0, 1000.0), default=6.0,
                     help="wind bound of vehicles and intruder [m/s]")
    pre.add_argument("--kbar", type=kit.kbar, nargs="+", default=[1, 2, 3, 4],
                     help=f"values of k̄, the most vehicles the intruder may force to avoid (each 1-{kit.MAX_KBAR})")
    kit.add_cache_dir(pre)
    pre.add_argument("--figures", default="figures",
                     help="directory for the PNG figures (checked to be writable before anything is computed)")
    kit.add_progress(pre)
    pre.set_defaults(run=_precompute)

    _add_evaluate_parsers(sub)
    add_falsify_parser(sub)
    add_train_intruder_parser(sub)
    from stp_env.survivability.cli import add_parser as _add_survivability_parser

    _add_survivability_parser(sub)
    from stp_env.coobservation.cli import add_parser as _add_coobservation_parser

    _add_coobservation_parser(sub)
    from stp_env.data_tools.cli import add_parser as _add_data_parser

    _add_data_parser(sub)
    return parser


def _add_episode_options(p, *, many: bool) -> None:
    """Options shared by ``evaluate`` (lists) and ``render`` (one configuration)."""
    nargs = "+" if many else None
    suite = (" (none: the default suite, see the description; town when another configuration option is "
             "given)"
             if many else "")
    p.add_argument("--scenario", type=kit.scenario, default=None if many else "town", metavar="NAME",
                   help=f"registered scenario: one of {', '.join(kit.scenario_names())}" + suite)
    p.add_argument("--kbar", type=kit.kbar, nargs=nargs, default=None if many else 2,
                   help=f"k̄, the number of vehicles the intruder may force to avoid (1-{kit.MAX_KBAR}); each value "
                        "uses the scenario's plan for that k̄" + (" (several: one configuration each; default 1 2 3 "
                                                                "outside the default suite)" if many else ""))
    p.add_argument("--intruder", nargs=nargs, default=None,
                   help=f"intruder policy: one of {', '.join(kit.intruder_names())}; 'learned:NAME_OR_PATH' for a "
                        "learned intruder (a shipped name or an .npz from stp_env.policies.learned.export_mlp); or "
                        "'package.module:policy' / 'package.module:factory=ARG' for any jittable policy "
                        "(key, state, params) -> (2,)" + ("" if many else
                        " (default: max-k; with --events: the record's intruder, and a plug-in spec in the record "
                        "is only used when typed here)"))
    p.add_argument("--wind", type=kit.real(0.0, 1000.0), default=None,
                   help="wind bound d_r of vehicles and intruder [m/s] (default: the scenario's, 6 m/s for town; "
                        "another value computes its own reachability artifacts and plan on first use)")
    kit.add_wind_model(p, "uniform", "how each agent's wind in its disk is drawn")
    p.add_argument("--spawn-mode", choices=("auto", *kit.spawn_modes()), default="auto",
                   help="where the intruder appears: outside every avoid region (Assumption 3), on a vehicle's "
                        "avoid boundary (Observation 1), or auto (boundary for max-k and optimal-max-k, else "
                        "outside)")
    p.add_argument("--vehicle-policy", type=kit.vehicle_policy_spec, default=None if many else "switching",
                   metavar="POLICY",
                   help="switching: u* (eq. 38) with the safety filter; nominal: u^PP, the filter off; worst: "
                        "every unforced vehicle flies the buffer game's control toward the intruder (the assumption "
                        "behind V^B), forced ones u^A; learned:NAME_OR_PATH: a learned vehicle policy inside the HJ "
                        "filters (kappa where the tracking tube leaves no room, u^A while forced)"
                        + "".join(f"; {name}: a plug-in" for name in kit.vehicle_policy_names()
                                  if name not in catalog.VEHICLE_POLICIES)
                        + (" (default: switching outside the default suite)" if many else ""))
    p.add_argument("--episode", choices=catalog.EPISODE_CHOICES,
                   default="window",
                   help="window: from 5 s before the intruder's appearance window to 10 s after it can leave; "
                        "full: first departure to the last STA (slower)")
    p.add_argument("--backend", type=backend, default="jax",
                   help="what moves the vehicles: jax (the papers' Dubins model in the jitted core), pymunk (the same "
                        "motion in the pymunk physics engine, host side: slower) or pymunk-dynamic[:param=value,...] "
                        "(rigid bodies with mass, drag, actuator lag; parameters of "
                        "stp_env.sim.vehicle_models.rigid_body.RigidBodyConfig); needs the pymunk extra")
    kit.add_seed(p, "the run; episode i replays from (seed, i)")
    kit.add_cache_dir(p)
    kit.add_progress(p)


def _add_evaluate_parsers(sub) -> None:
    ev = sub.add_parser("evaluate", help="Monte Carlo evaluation of the k̄ bound with exact confidence bounds",
                        formatter_class=kit.HelpFormatter,
                        description="Run episodes of a scenario for every (intruder, k̄) configuration and report "
                                    "|N^RP| (vehicles forced to avoid, eq. 39), P(|N^RP| > k̄) with an exact "
                                    "Clopper-Pearson upper bound, collisions, guarantee violations, on-time "
                                    "arrivals and the smallest separation. Prints a markdown table; writes "
                                    "results.{json,csv,md}, events.{json,npz} (replayable bad episodes) and PNG "
                                    "figures to --out. The default suite (none of --scenario, --kbar, --intruder, "
                                    "--vehicle-policy given): town at k̄ = 1, 2, 3 with the max-k intruder and "
                                    "the vehicles on u*, and the crossing at k̄ = 2 with the optimal-max-k "
                                    "intruder and the worst vehicles, where the bound binds.")
    _add_episode_options(ev, many=True)
    ev.add_argument("--episodes", type=kit.in_memory(RESULT_BYTES, "episode"), default=500,
                    help="episodes per configuration (the default suite: 4 configurations x 500 episodes; every "
                         "episode's final state is kept, so their number is checked against the memory available)")
    kit.add_batch_size(ev, "episodes simulated in one compiled batch (memory grows with it; every batch has this "
                           "size)", default=250)
    ev.add_argument("--confidence", type=kit.probability, default=0.95,
                    help="confidence level of the one-sided upper bounds (0 < c < 1)")
    kit.add_out(ev, "evaluation")
    ev.add_argument("--no-figures", action="store_true", help="write the results only")
    kit.add_ray(ev, "the batches of episodes")
    kit.add_cpu_devices(ev)
    ev.add_argument("--whole-fleet", action="store_true",
                    help="simulate every vehicle of the plan, not only those that can fly in the episode window "
                         "(the same episodes up to float rounding, 2-4x slower; for comparison)")
    ev.set_defaults(run=_evaluate)

    rd = sub.add_parser("render", help="render one episode as an animated GIF",
                        formatter_class=kit.HelpFormatter,
                        description="Replay episode --index of the run with --seed (the same episode as in "
                                    "`stp-env evaluate` with the same options), or a saved bad episode "
                                    "(--events FILE --event N), and write it as a GIF (PNG frames if pillow "
                                    "is missing).")
    _add_episode_options(rd, many=False)
    rd.add_argument("--index", type=kit.count, default=0, help="episode index within the run")
    kit.add_batch_size(rd, "episodes of the compiled batch that held the episode in `stp-env evaluate` (a saved "
                           "event from --events replays bit for bit in its own batch; a --seed/--index episode is "
                           "the same episode, computed by a program with this config's own step count)",
                       default=250)
    rd.add_argument("--events", default=None, help="an events.json written by `stp-env evaluate`")
    rd.add_argument("--event", type=kit.count, default=0, help="which record of --events (from 0)")
    rd.add_argument("--frame-dt", type=kit.real(0.0, 1e4, lo_open=True), default=0.5,
                    help="simulated time between frames [s]")
    rd.add_argument("--fps", type=kit.integer(1, 1000), default=8, help="frames per second of the GIF")
    kit.add_out(rd, "episode.gif", "GIF file to write")
    rd.set_defaults(run=_render)


def _avoid_region(args) -> int:
    from stp_env.dynamics import DubinsWind
    from stp_env.reach.avoid import AvoidRegionConfig, compute_avoid_region
    from stp_env.reach.plots import plot_avoid_region

    _check_output_file(args.out)
    vehicle = DubinsWind(v_min=0.0, v_max=args.v_max, omega_max=args.omega_max, wind=args.wind)
    config = AvoidRegionConfig(vehicle=vehicle, intruder=vehicle, collision_radius=args.collision_radius,
                               t_iat=args.t_iat, half_width=args.half_width,
                               grid_points=(args.grid, args.grid, args.grid + args.grid % 2), accuracy=args.accuracy)
    start = time.perf_counter()
    region = compute_avoid_region(config, progress=not args.no_progress)
    seconds = time.perf_counter() - start
    margin = region.boundary_margin
    path = plot_avoid_region(region, args.out)
    summary = {
        "png": path,
        "detection_range_m": round(region.detection_range(), 1),
        "behind_extent_exact_m": config.behind_extent(),
        "boundary_margin_m": round(margin, 1),
        "grid": list(config.grid.shape),
        "time_steps": region.n_steps,
        "seconds": round(seconds, 1),
    }
    print(json.dumps(summary))
    return 0


def _plan(args) -> int:
    from stp_env.artifacts import ArtifactStore
    from stp_env.planning.plots import plot_plan
    from stp_env.planning.stp import plan_scenario
    from stp_env.scenarios import make

    overrides = {}
    if args.kbar is not None:
        overrides["kbar"] = args.kbar
    if args.sta_spacing is not None:
        overrides["sta_spacing"] = args.sta_spacing
    _check_output_file(args.out)
    scenario = make(args.scenario, **overrides)
    if scenario.method != "rtt":
        scenario = scenario.with_overrides(method="rtt")
    start = time.perf_counter()
    plan = plan_scenario(scenario, store=ArtifactStore(args.cache_dir), progress=not args.no_progress)
    seconds = time.perf_counter() - start
    path = plot_plan(plan, scenario, args.out)
    print(json.dumps({
        "scenario": scenario.name, "png": path, "seconds": round(seconds, 1),
        "tracking_bound_m": round(plan.tracking_bound, 3), "kbar": plan.kbar,
        "t_ldt_s": [round(float(v.plan.t_ldt), 3) for v in plan.vehicles],
        "arrival_s": [round(float(v.plan.arrival_time), 3) for v in plan.vehicles],
        "sta_s": [float(s.sta) for s in scenario.vehicles],
    }))
    return 0


def _precompute(args) -> int:
    from stp_env.artifacts import ArtifactStore
    from stp_env.evaluation.pipeline import check_output_dir
    from stp_env.reach.defaults import build_reach_artifacts
    from stp_env.reach.plots import plot_buffer_regions, plot_sets

    out = check_output_dir(args.figures, "--figures")
    start = time.perf_counter()
    arts = build_reach_artifacts(args.wind, tuple(sorted(set(args.kbar))), store=ArtifactStore(args.cache_dir),
                                 progress=not args.no_progress)
    summary = arts.summary()
    summary["seconds"] = round(time.perf_counter() - start, 1)
    k_show = 3 if 3 in arts.buffers else max(arts.buffers)
    summary["figures"] = [
        plot_sets(arts.avoid, arts.tracking.bound, arts.buffers[k_show], str(out / f"sets_wind{args.wind:g}.png")),
        plot_buffer_regions(arts.avoid, arts.tracking.bound, arts.buffers, arts.radii,
                            str(out / f"buffer_regions_wind{args.wind:g}.png")),
    ]
    print(json.dumps(summary))
    return 0


SUITE_OPTIONS = ("scenario", "kbar", "intruder", "vehicle_policy")
"""The options that choose configurations: with none of them ``evaluate`` runs the default suite."""


def _evaluation_configs(args):
    """The configurations of ``evaluate``: the default suite (:data:`stp_env.evaluation.config.DEFAULT_SUITE`)
    when none of :data:`SUITE_OPTIONS` is given, else every (intruder, k̄) of the one scenario, with the defaults
    town, k̄ = 1 2 3, max-k, switching for the options not given. The common options (wind, wind model, spawn
    mode, episode, backend) apply to every configuration."""
    from stp_env.evaluation.config import default_suite

    if all(getattr(args, name) is None for name in SUITE_OPTIONS):
        return default_suite(**_common_options(args))
    return _configurations(args, args.scenario or "town", args.kbar or [1, 2, 3], args.intruder or ["max-k"],
                           args.vehicle_policy or "switching")


def _common_options(args) -> dict:
    return {"wind": args.wind, "wind_model": args.wind_model, "spawn_mode": args.spawn_mode,
            "episode": args.episode, "backend": args.backend}


def _configurations(args, scenario, kbars, intruders, vehicle_policy):
    """Every (intruder, k̄) of one scenario, checked before any work (an unknown scenario or intruder fails)."""
    from stp_env.evaluation import Configuration, resolve_intruder
    from stp_env.scenarios import make

    make(scenario)
    for spec in intruders:
        resolve_intruder(spec)
    return [Configuration(scenario=scenario, kbar=k, intruder=i, vehicle_policy=vehicle_policy,
                          **_common_options(args))
            for i in dict.fromkeys(intruders) for k in dict.fromkeys(kbars)]


def _evaluate(args) -> int:
    from stp_env.artifacts import ArtifactStore
    from stp_env.evaluation import pipeline

    configs = _evaluation_configs(args)
    for config in configs:
        config.make_scenario()               # a k̄ the scenario does not allow fails here
    kit.apply_cpu_devices(args)              # before JAX's first computation
    executor = kit.executor(args)            # --ray without ray installed, or a cluster not reached, fails here
    result = pipeline.run(configs, args.out, episodes=args.episodes, seed=args.seed, batch_size=args.batch_size,
                          confidence=args.confidence, store=ArtifactStore(args.cache_dir),
                          progress=not args.no_progress, figures=not args.no_figures,
                          airborne_only=not args.whole_fleet, executor=executor)
    print(result["markdown"])
    print(f"\n{len(configs)} configuration(s) x {args.episodes} episodes in {result['seconds']} s; wrote "
          f"{', '.join(result['files'])}")
    return 0


def _render(args) -> int:
    from stp_env.artifacts import ArtifactStore
    from stp_env.evaluation import build_params, replay
    from stp_env.evaluation.render import render_episode
    from stp_env.sim import COLLIDED, steps_for

    _check_output_file(args.out)
    store = ArtifactStore(args.cache_dir)
    if args.events is not None:
        config, params, vehicle_policy, intruder_policy, record = _event_to_render(args, store)
        seed, index = record["seed"], record["index"]
        n_steps, batch_size, recorded = record["n_steps"], record["batch_size"], record["recorded"]
        airborne_only, episodes = record.get("airborne_only", False), record.get("episodes")
        devices = record.get("devices") if recorded else None
    else:
        intruder = "max-k" if args.intruder is None else args.intruder
        config = _configurations(args, args.scenario, [args.kbar], [intruder], args.vehicle_policy)[0]
        seed, index = args.seed, args.index
        params = build_params([config], store=store, progress=not args.no_progress)[0]
        n_steps, batch_size, recorded = steps_for(params), args.batch_size, True
        vehicle_policy, intruder_policy = config.policies()
        airborne_only, episodes, devices = True, None, None
    start = time.perf_counter()
    # An evaluation without recording (evaluate(..., showcase=False)) ran another program: drawing needs the
    # trajectory, so such an episode is replayed alone (the same episode up to float rounding).
    final, traj = replay(seed, index, params, vehicle_policy, intruder_policy, n_steps,
                         batch_size=batch_size if recorded else 1, airborne_only=airborne_only,
                         episodes=episodes if recorded else None, devices=devices)
    title = (f"{config.scenario}, k̄ = {config.kbar}, {config.intruder} intruder\nseed {seed}, episode {index}: "
             f"|N^RP| = {int(final['n_forced'])}")
    files, n_frames = render_episode(traj, final, params, config.make_scenario(), args.out, frame_dt=args.frame_dt,
                           fps=args.fps, title=title)
    print(json.dumps({
        "files": files if len(files) == 1 else [files[0], "...", files[-1]], "frames": n_frames,
        "seed": seed, "index": index, "label": config.label, "n_forced": int(final["n_forced"]),
        "collided": int((final["status"] == COLLIDED).sum()),
        "guarantee_violations": int(final["guarantee_violation"].sum()),
        "seconds": round(time.perf_counter() - start, 1)}))
    return 0


def _event_to_render(args, store):
    """The configuration, params and policies of record ``--event`` of ``--events`` (untrusted data: see
    :mod:`stp_env.evaluation.events`). A plug-in intruder spec in the record is only imported when the user typed
    the same spec as ``--intruder``."""
    from stp_env.evaluation import resolve_intruder
    from stp_env.evaluation.events import is_plugin_spec, load_events
    from stp_env.evaluation.replays import prepare_event

    records = load_events(args.events)
    if not 0 <= args.event < len(records):
        raise ValueError(f"--event {args.event}: {args.events} has {len(records)} record(s).")
    record = records[args.event]
    where = f"{args.events}, record {args.event}"
    recorded_intruder = record["config"].get("intruder", "hj")
    intruder_policy = None
    if args.intruder is not None:
        if args.intruder != recorded_intruder:
            raise ValueError(f"--intruder {args.intruder!r} differs from the intruder of {where} "
                             f"({recorded_intruder!r}); a saved event replays with its own intruder.")
        if is_plugin_spec(args.intruder):
            intruder_policy = resolve_intruder(args.intruder)  # typed by the user: trusted
    if record["recorded"] and record.get("devices", 1) != 1:
        kit.follow_cpu_devices(record["devices"])  # the evaluation's program, if JAX has not started yet
    config, params, vehicle_policy, intruder_policy = prepare_event(
        record, store=store, progress=not args.no_progress, intruder_policy=intruder_policy, where=where)
    return config, params, vehicle_policy, intruder_policy, record


def _select_figure_backend() -> None:
    """The command line writes figures to files: select matplotlib's non-interactive Agg backend (here, not at
    library import, so that programs using the library keep their own backend)."""
    try:
        import matplotlib
    except ImportError:  # figures are optional
        return
    matplotlib.use("Agg")


def main(argv=None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    _select_figure_backend()
    from stp_env.progress import command_started

    command_started(args.command, False if getattr(args, "no_progress", False) else None)  # in a terminal
    try:
        return args.run(args)  # every subcommand's parser names its handler (set_defaults(run=...))
    except (ValueError, OSError) as err:  # bad options, unreadable inputs, unwritable outputs: one line, no traceback
        message = " ".join(str(err).split())
        print(f"stp-env {args.command}: error: {message}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

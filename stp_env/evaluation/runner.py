"""Monte Carlo evaluation on the batched core: episodes in fixed-size batches, one compiled program per set of
static arguments (policies, batch size, step count), replayable episodes.

Seeding: episode ``i`` of a run with seed ``s`` is ``sim.rollout(fold_in(key(s), i), ..., n_envs=1)``, so any
episode replays alone from ``(seed, index)`` (:func:`replay`). Every configuration of a run uses the same seed:
configurations with the same static structure see the same random draws (common random numbers), which makes
their differences less noisy.

The k̄ values of one scenario have plans with slightly different sample counts; :func:`pad_plan` pads them to a
common length (the padding is never read: ``nominal_reference`` clamps at ``nominal_len``), and all configurations
of a run use the longest step count among them (an episode's state is frozen once it ends), so that the k̄ values
share one compiled program.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import assembly, requirements, sim
from stp_env.evaluation.config import Configuration
from stp_env.evaluation.summary import forced_summary
from stp_env.seeds import check_seed, prng_key
from stp_env.sim import core, engine, fleet, fleet_expand
from stp_env.sim.bounds import WIND
from stp_env.sim.jit import sim_jit
from stp_env.sim.metrics import largest_tracking_error, tracked_flights
from stp_env.sim.metrics import n_forced as count_forced
from stp_env.sim.rollout import rollout_keys
from stp_env.sim.types import ARRIVED, COLLIDED, OUT_OF_BOUNDS

MAX_EPISODES = 2**30  # episode indices are int32 (the last batch runs past the last episode)
EVENT_KINDS = ("bound_exceeded", "collision", "guarantee_violation", "assumption_failed")


@functools.partial(sim_jit, static_argnames=("vehicle_policy", "intruder_policy", "n_steps", "record", "active"))
def run_batch(key, indices, params, vehicle_policy, intruder_policy, n_steps: int, record: bool = False,
              active: tuple[int, ...] | None = None):
    """Episodes ``indices`` (B,) of the run keyed by ``key``: ``(final states, trajectories)`` batched over ``B``
    (trajectories ``None`` unless ``record``; fields as in :func:`stp_env.sim.rollout`), of the whole fleet.

    ``active``: simulate only these vehicles (:func:`stp_env.sim.fleet.airborne`: every other vehicle stays on
    the ground or in its target for the whole episode) and put the others back with
    :func:`stp_env.sim.fleet_expand.expand`: the same episodes (the same random numbers) at a fraction of the cost;
    ``None``: the whole fleet."""
    keys = jax.vmap(lambda i: episode_key(key, i))(indices)
    if active is None or len(active) == params.vehicles.n:
        return rollout_keys(keys, params, vehicle_policy, intruder_policy, n_steps, record=record)
    ids = np.asarray(active)
    final, traj = rollout_keys(keys, fleet.select(params, ids), vehicle_policy, intruder_policy, n_steps,
                               record=record)
    parked = fleet_expand.parked_state(params, np.setdiff1d(np.arange(params.vehicles.n), ids))
    final = jax.vmap(lambda s: fleet_expand.expand(s, params, ids, parked))(final)
    return final, (None if traj is None else fleet_expand.expand_trajectory(traj, params, ids, parked))


def simulated_vehicles(params, airborne_only: bool) -> tuple[int, ...] | None:
    """The ``active`` argument of :func:`run_batch`: the vehicles that can fly in the episode window
    (:func:`stp_env.sim.fleet.airborne`) when ``airborne_only``, else ``None`` (the whole fleet)."""
    if not airborne_only:
        return None
    return tuple(int(i) for i in fleet.airborne(params))


def episode_order(seed: int, episodes: int, params) -> np.ndarray:
    """Episodes ``0 .. episodes - 1`` of the run with ``seed`` in the order the evaluator batches them: by the time
    their intruder appears (ties by index). The intruder's avoid reads and decisions are skipped in every step in
    which no episode of a batch has it present (:func:`stp_env.sim.gates.when_any`), so batches of episodes whose
    intruders come together skip most of them; an episode's outcome does not depend on its batch
    (``tests/test_gates.py``). The order depends only on the seed, the count and the appearance window."""
    key = prng_key(seed)
    times = _appear_times(key, jnp.arange(episodes, dtype=jnp.int32), params)
    return np.lexsort((np.arange(episodes), np.asarray(times))).astype(np.int32)


@sim_jit
def _appear_times(key, indices, params):
    return jax.vmap(lambda i: core.appear_time(engine.reset_key(episode_key(key, i)), params))(indices)


def episode_key(key, index):
    """The key of episode ``index`` of the run keyed by ``key`` (``fold_in(fold_in(key, index), 0)``)."""
    return jax.random.fold_in(jax.random.fold_in(key, index), 0)


def batch_indices(order: np.ndarray, first: int, batch_size: int) -> np.ndarray:
    """The episode indices of the batch at positions ``first .. first + batch_size - 1`` of ``order``; a last
    batch past the end is filled with the indices after the run's last episode (their results are dropped)."""
    chosen = np.asarray(order[first:first + batch_size], np.int32)
    extra = len(order) + np.arange(batch_size - len(chosen), dtype=np.int32)
    return np.concatenate([chosen, extra]).astype(np.int32)


def _showcase_of(ep: dict) -> int:
    """The position in ``ep`` of the episode with the most forced vehicles, the lowest index among them."""
    most = ep["n_forced"] == np.max(ep["n_forced"])
    return int(np.flatnonzero(most)[np.argmin(ep["index"][most])])


def pad_plan(params, n_samples: int):
    """``params`` with the nominal trajectories padded (repeating the last sample) to ``n_samples``."""
    k = params.vehicles.nominal_states.shape[1]
    if k == n_samples:
        return params
    if k > n_samples:
        raise ValueError(f"cannot pad a plan of {k} samples to {n_samples}.")
    widths = ((0, 0), (0, n_samples - k), (0, 0))
    return params.replace(vehicles=dict(nominal_states=jnp.pad(params.vehicles.nominal_states, widths, mode="edge"),
                                        nominal_controls=jnp.pad(params.vehicles.nominal_controls, widths,
                                                                 mode="edge")))


def host_state(state) -> dict[str, np.ndarray]:
    """A (batched) :class:`EnvState` as numpy arrays (the PRNG key as its raw data)."""
    out = {}
    for f in dataclasses.fields(state):
        value = getattr(state, f.name)
        if jnp.issubdtype(value.dtype, jax.dtypes.prng_key):
            value = jax.random.key_data(value)
        out[f.name] = np.asarray(value)
    return out


@dataclasses.dataclass
class ConfigResult:
    """The outcome of one configuration.

    ``episodes``: per-episode final-state arrays (``host_state``) plus ``n_forced`` and ``index``; ``summary``:
    the numbers of the report (:func:`summarize`); ``events``: the replayable bad episodes (the first
    ``max_events``; ``summary`` counts them all); ``showcase``: the recorded trajectory of the first episode with
    the most forced vehicles (for the figures); ``params``: the simulator constants used.
    """

    config: Configuration
    seed: int
    n_steps: int
    plan_samples: int
    episodes: dict
    summary: dict
    events: list
    showcase: dict | None
    params: object = dataclasses.field(repr=False, default=None)
    airborne_only: bool = True


def _events(config: Configuration, seed: int, n_steps: int, plan_samples: int, batch_size: int, recorded: bool,
            ep: dict, kbar: int, airborne_only: bool, episodes: int, devices: int | None) -> list[dict]:
    n_forced = ep["n_forced"]
    kinds = {
        "bound_exceeded": n_forced > kbar,
        "collision": np.any(ep["status"] == COLLIDED, axis=1),
        "guarantee_violation": np.any(ep["guarantee_violation"], axis=1),
        "assumption_failed": ~np.all(ep["assumption_ok"], axis=1),
    }
    bad = np.flatnonzero(np.any(np.stack(list(kinds.values())), axis=0))
    out = []
    for j in bad:
        collided = np.flatnonzero(ep["status"][j] == COLLIDED)
        out.append({
            "label": config.label, "config": dataclasses.asdict(config), "seed": seed, "index": int(ep["index"][j]),
            "n_steps": n_steps, "plan_samples": plan_samples, "batch_size": batch_size, "episodes": episodes,
            "recorded": recorded, **({} if devices is None else {"devices": devices}),
            "airborne_only": airborne_only, "kinds": [k for k, v in kinds.items() if v[j]],
            "n_forced": int(n_forced[j]),
            "collided_vehicles": collided.tolist(),
            "collision_times_s": [round(float(ep["collision_time"][j, i]), 2) for i in collided],
            "with_intruder": [bool(ep["collided_with_intruder"][j, i]) for i in collided],
            "violating_vehicles": np.flatnonzero(ep["guarantee_violation"][j]).tolist(),
            "tracking_violating_vehicles": np.flatnonzero(ep["tracking_violation"][j]).tolist(),
            "t_appear_s": round(float(ep["t_appear"][j]), 2),
            "state": {k: v[j] for k, v in ep.items() if k not in ("index",)},
        })
    return out


def summarize(config: Configuration, ep: dict, params, *, confidence: float = 0.95) -> dict:
    """The report's numbers for one configuration from its per-episode arrays (those about ``|N^RP|``, collisions
    and violations from :func:`stp_env.evaluation.summary.forced_summary`).

    * ``forced_hist[m]``: episodes with ``|N^RP| = m`` (eq. 39), ``m = 0 .. N``; ``forced_mean``, ``forced_max``.
    * ``exceed``: episodes with ``|N^RP| > k̄``; ``exceed_rate`` and its exact one-sided Clopper-Pearson upper bound
      ``exceed_upper`` at ``confidence``.
    * ``collision_episodes`` (episodes with any collision), ``collisions`` (vehicles), ``intruder_collisions``
      (vehicles hit by the intruder), ``guarantee_violations`` (vehicles that collided although the intruder
      appeared outside their avoid region and they applied ``u^A`` throughout, i.e. a failure of the theory or
      the numerics; a vehicle that tracked its plan with ``kappa`` and still got farther than ``r_e`` from it counts
      too), ``violation_episodes`` and its upper bound; ``assumption_failures``: episodes where the intruder
      appeared inside a vehicle's avoid region (Assumption 3 failed; no guarantee applies).
    * ``tracking_violations``: vehicles farther than ``r_e`` (``tracking_bound_m``) from their nominal position
      while tracking their plan (SPP eqs. 24-26); ``max_tracking_error_m``: the largest such distance of any
      vehicle that tracked its plan (``None`` when none flew with ``kappa``, e.g. under the ``worst`` policy).
    * ``due``: vehicle-episodes whose STA falls within the simulated time (``<= t_end``), not counting vehicles
      already in their target when the episode starts; ``on_time_rate``: the fraction of them that arrived by their
      STA; ``arrived_rate``: that arrived at all within the episode. A ``"window"`` episode has few due vehicles
      (one per town episode); ``"full"`` episodes measure every vehicle.
    * Tightness of the bound: ``kbar_reached`` / ``kbar_reached_rate``: episodes (fraction) with ``|N^RP| >= k̄``
      (the bound reached, or exceeded); ``avoid_start_kth_min_s`` / ``avoid_start_kth_median_s``: for ``k = 1 ..
      k̄ + 1``, the earliest and the median over the episodes that forced at least ``k`` vehicles of the ``k``-th
      avoid start, relative to the intruder's appearance (``None`` when no episode forced ``k``); the worst case of
      the intruder paper's Fig. 6 has them at ``(k - 1) t_IAT / k̄``.
    * ``min_separation_m``: the smallest distance between a vehicle and another vehicle or the intruder over all
      episodes (``R_c`` is the collision radius); ``min_separation_p5_m`` / ``..._median_m``: percentiles of the
      per-episode minimum.
    """
    n_ep = len(ep["n_forced"])
    kbar = config.kbar
    n_forced = ep["n_forced"]
    n_veh = ep["status"].shape[1]
    hist = np.bincount(n_forced, minlength=n_veh + 1)
    collided = ep["status"] == COLLIDED
    base = forced_summary(n_forced, kbar, collided, ep["guarantee_violation"], confidence=confidence)
    sta = np.asarray(params.vehicles.sta)
    # vehicles already in their target at the episode start are not simulated (reset gives them arrival_time =
    # t_start, not their real arrival), so they do not count
    done_at_start = ep["arrival_time"] <= float(params.episode.t_start) + 1e-6
    due = (sta[None, :] <= float(params.episode.t_end) + 1e-6) & ~done_at_start
    on_time = (ep["arrival_time"] <= sta[None, :] + 1e-6) & due
    arrived = (ep["status"] == ARRIVED) & due
    n_due = int(due.sum())
    kth_min, kth_median = avoid_start_order_stats(ep, kbar + 1)
    per_episode_sep = np.min(ep["min_separation"], axis=1)
    # a vehicle still waiting, or already in its target at the start, has tracked nothing in the episode
    largest_error = largest_tracking_error(ep["max_tracking_error"],
                                           tracked_flights(ep["tracked"], ep["status"], done_at_start))
    finite = per_episode_sep[np.isfinite(per_episode_sep)]
    return {
        "label": config.label,
        "scenario": config.scenario, "kbar": kbar, "intruder": config.intruder,
        "wind_mps": None if config.wind is None else float(config.wind),
        "scenario_wind_mps": round(float(params.vehicles.bounds[WIND]), 3),
        "wind_model": config.wind_model, "spawn_mode": config.effective_spawn_mode,
        "vehicle_policy": config.vehicle_policy, "episode": config.episode,
        "episodes": n_ep, "vehicles": n_veh,
        "forced_hist": hist.tolist(),
        "forced_mean": round(base["forced_mean"], 4), "forced_max": base["forced_max"],
        "exceed": base["exceed"], "exceed_rate": base["exceed_rate"], "exceed_upper": base["exceed_upper"],
        "confidence": confidence,
        "kbar_reached": base["kbar_reached"], "kbar_reached_rate": float(np.mean(n_forced >= kbar)),
        "avoid_start_kth_min_s": kth_min, "avoid_start_kth_median_s": kth_median,
        "collision_episodes": base["collision_episodes"],
        "collisions": base["collisions"],
        "intruder_collisions": int(np.sum(collided & ep["collided_with_intruder"])),
        "out_of_bounds": int(np.sum(ep["status"] == OUT_OF_BOUNDS)),
        "guarantee_violations": base["guarantee_violations"],
        "violation_episodes": base["violation_episodes"],
        "violation_upper": base["violation_upper"],
        "assumption_failures": int(np.sum(~np.all(ep["assumption_ok"], axis=1))),
        "tracking_violations": int(ep["tracking_violation"].sum()),
        "max_tracking_error_m": None if largest_error is None else round(largest_error, 3),
        "tracking_bound_m": round(float(params.tables.tracking_bound), 3),
        "due": n_due,
        "on_time_rate": float(on_time.sum() / n_due) if n_due else None,
        "arrived_rate": float(arrived.sum() / n_due) if n_due else None,
        "collision_radius_m": float(params.episode.collision_radius),
        "min_separation_m": round(float(finite.min()), 2) if finite.size else None,
        "min_separation_p5_m": round(float(np.percentile(finite, 5)), 2) if finite.size else None,
        "min_separation_median_m": round(float(np.median(finite)), 2) if finite.size else None,
        "t_window_s": [round(float(params.episode.t_start), 2), round(float(params.episode.t_end), 2)],
    }


def avoid_start_order_stats(ep: dict, n: int) -> tuple[list, list]:
    """For ``k = 1 .. n``: the earliest and the median ``k``-th avoid start (relative to the intruder's appearance,
    rounded to 0.01 s) over the episodes that forced at least ``k`` vehicles (``None`` where none did)."""
    rel = np.sort(np.asarray(ep["avoid_start"], float) - np.asarray(ep["t_appear"], float)[:, None], axis=1)
    lows, meds = [], []
    for k in range(n):
        col = rel[:, k] if k < rel.shape[1] else np.full(rel.shape[0], np.inf)
        col = col[np.isfinite(col)]
        lows.append(round(float(col.min()), 2) if col.size else None)
        meds.append(round(float(np.median(col)), 2) if col.size else None)
    return lows, meds


def required_tables(config: Configuration) -> tuple[str, ...]:
    """The tables ``config``'s policies read beyond the scenario's (``"buffer"``: ``V^B``): the vehicles', and the
    intruder's by its record (:func:`stp_env.policies.intruders.capabilities`, plug-ins included); see
    :func:`stp_env.requirements.required_tables` (``ValueError`` for an unknown table)."""
    return requirements.required_tables(config.vehicle_policy, config.intruder)


def build_params(configs, *, store=None, progress: bool = True) -> list:
    """``EnvParams`` for each configuration (cached reachability artifacts and plans; computed on first use), with
    every table its policies read built for its k̄ (:func:`required_tables`: the relative buffer table ``V^B`` of a
    buffer-game policy, a plug-in's table), each once per scenario and configuration. Every configuration's tables
    are checked before any is built."""
    needs = [required_tables(config) for config in configs]
    cache = {}
    out = []
    for config, tables in zip(configs, needs):
        scenario, env_config = config.make_scenario(), config.env_config()
        key = (scenario, env_config, tables)
        if key not in cache:
            params = assembly.params_for(scenario, env_config, store=store, progress=progress)
            cache[key] = requirements.with_required_tables(params, scenario, tables=tables, kbar=config.kbar,
                                                           store=store, progress=progress)
        out.append(cache[key])
    return out


def evaluate(configs, *, episodes: int = 1000, seed: int = 0, batch_size: int = 250, confidence: float = 0.95,
             max_events: int = 50, store=None, progress: bool = True, params=None,
             showcase: bool = True, airborne_only: bool = True, executor=None, pieces_dir=None) -> list[ConfigResult]:
    """Evaluate each :class:`Configuration` on ``episodes`` episodes (the same seeds for each).

    Episodes run ``batch_size`` at a time (the last batch padded with extra episodes whose results are dropped),
    so that each set of static arguments compiles once. ``params``: optional prebuilt ``EnvParams`` per
    configuration (default :func:`build_params`). ``showcase``: record the batches' trajectories to keep the
    episode with the most forced vehicles for the figures (memory ``batch_size x steps x vehicles``: about 45 MB
    per batch of 250 town episodes; off: ``ConfigResult.showcase`` is ``None``). ``airborne_only``: simulate only
    the vehicles that can fly in the episode window (:func:`run_batch`; the same episodes, 2-5x faster on the
    shipped scenarios); off: the whole fleet, for comparison.

    The batches are the pieces of one job (:mod:`stp_env.execution`, :func:`evaluation_job`): ``executor`` runs
    them (default :class:`~stp_env.execution.LocalExecutor`, in this process and in order; a
    :class:`~stp_env.execution.RayExecutor` on a cluster), with the same results whatever runs them. Each batch's
    episodes are keyed by ``(seed, episode index)`` alone. ``pieces_dir``: write every finished batch there and
    reuse those already written by an earlier run of the same job (a killed run resumes). A configuration's
    ``seconds`` is the sum of its batches' compute times.
    """
    from stp_env.execution import check_executor

    configs = list(configs)
    if not configs:
        raise ValueError("no configuration to evaluate.")
    for name, value in (("episodes", episodes), ("batch_size", batch_size)):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_EPISODES:
            raise ValueError(f"{name} must be an integer in [1, {MAX_EPISODES}]; got {value!r}.")
    if isinstance(confidence, bool) or not isinstance(confidence, (int, float)) or not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1); got {confidence!r}.")
    check_seed(seed)
    for config in configs:
        if not isinstance(config, Configuration):
            raise ValueError(f"configurations must be Configuration objects; got {type(config).__name__}.")
    executor = check_executor(executor)
    batch_size = min(batch_size, episodes)
    all_params = build_params(configs, store=store, progress=progress) if params is None else list(params)
    if len(all_params) != len(configs):
        raise ValueError(f"params: one per configuration ({len(configs)}); got {len(all_params)}.")
    plan_samples = max(p.vehicles.nominal_states.shape[1] for p in all_params)
    n_steps = max(sim.steps_for(p) for p in all_params)
    all_params = [pad_plan(p, plan_samples) for p in all_params]
    job = evaluation_job(configs, all_params, seed=seed, episodes=episodes, batch_size=batch_size, n_steps=n_steps,
                         record=showcase, airborne_only=airborne_only, resumable=pieces_dir is not None)
    pieces = _run_job(executor, job, configs, episodes, pieces_dir, progress)
    results = []
    for c, (config, params_i) in enumerate(zip(configs, all_params)):
        mine = [r for (i, _), r in zip(job.arguments, pieces) if i == c]
        results.append(_combine_batches(config, params_i, mine, seed, episodes, batch_size, n_steps, plan_samples,
                                        confidence, max_events, showcase, airborne_only, job.context.active[c]))
    return results


@dataclasses.dataclass(frozen=True)
class EvaluationContext:
    """What every batch of an evaluation shares (the context of :func:`evaluation_job`): the configurations, their
    padded ``EnvParams`` as host arrays (:func:`stp_env.execution.to_host`), the simulated vehicles of each, and
    the run's numbers."""

    token: str
    seed: int
    configs: tuple
    params: tuple
    active: tuple
    orders: tuple
    episodes: int
    batch_size: int
    n_steps: int
    record: bool


def evaluation_job(configs, params, *, seed: int, episodes: int, batch_size: int, n_steps: int, record: bool,
                   airborne_only: bool, resumable: bool = False):
    """The batches of an evaluation as a :class:`stp_env.execution.Job`: piece ``(c, first)`` runs the episodes at
    positions ``first .. first + batch_size - 1`` of configuration ``c``'s :func:`episode_order`
    (:func:`evaluation_piece`); ``params`` already padded to one plan length. ``resumable``: give the job its
    fingerprint (the configurations, the numbers, every array of the params and the package's source), which names
    the folder its pieces are written to."""
    from stp_env import execution

    host = tuple(execution.to_host(p) for p in params)
    active = tuple(simulated_vehicles(p, airborne_only) for p in params)
    orders = tuple(episode_order(seed, episodes, p) for p in params)
    context = EvaluationContext(token=execution.new_token(), seed=seed, configs=tuple(configs), params=host,
                                active=active, orders=orders, episodes=episodes, batch_size=batch_size,
                                n_steps=n_steps, record=record)
    arguments = tuple((c, first) for c in range(len(configs)) for first in range(0, episodes, batch_size))
    fingerprint = None
    if resumable:
        from stp_env.evaluation.report import source_hash

        shares = engine.shares(batch_size)  # another count is another program (left out at one: older runs resume)
        fingerprint = execution.digest("evaluate", [dataclasses.asdict(c) for c in configs], seed, episodes,
                                       batch_size, n_steps, record, active, list(host), source_hash(),
                                       *([shares] if shares > 1 else []))
    return execution.Job(name="evaluate", function=evaluation_piece, context=context, arguments=arguments,
                         fingerprint=fingerprint, units=tuple(min(batch_size, episodes - f) for _, f in arguments))


def evaluation_piece(context: EvaluationContext, argument) -> dict:
    """One batch of an evaluation (a piece of :func:`evaluation_job`): its kept episodes' final states
    (``ep/<field>``, with ``n_forced`` and ``index``), with ``record`` the trajectory of its episode with the most
    forced vehicles (the lowest index among them; ``show/<field>``), and its compute time (``seconds``). Episode
    ``i``'s key is ``fold_in(fold_in(key(seed), i), 0)``, as in every evaluation, whatever batch it runs in."""
    from stp_env import execution

    start = time.perf_counter()  # the piece's own compute time
    c, first = (int(a) for a in argument)
    if not 0 <= c < len(context.configs) or not 0 <= first < context.episodes:
        raise ValueError(f"no batch {argument!r} in this evaluation.")
    params, vehicle_policy, intruder_policy = execution.memo(
        context.token, ("configuration", c),
        lambda: (execution.to_device(context.params[c]), *context.configs[c].policies()))
    batch_size = context.batch_size
    indices = batch_indices(context.orders[c], first, batch_size)
    final, traj = run_batch(prng_key(context.seed), jnp.asarray(indices), params, vehicle_policy, intruder_policy,
                            context.n_steps, record=context.record, active=context.active[c])
    keep = min(batch_size, context.episodes - first)
    ep = {k: v[:keep] for k, v in host_state(final).items()}
    ep["n_forced"] = count_forced(ep["avoid_start"], axis=1)
    ep["index"] = indices[:keep]
    out = {f"ep/{k}": v for k, v in ep.items()}
    if context.record:
        j = _showcase_of(ep)
        out.update({f"show/{k}": np.asarray(v[j]) for k, v in traj.items()})
    out["seconds"] = np.float64(time.perf_counter() - start)
    out["devices"] = np.int64(engine.shares(batch_size))  # where it ran: a Ray worker may have another count
    return out


def _run_job(executor, job, configs, episodes, pieces_dir, progress):
    from tqdm.auto import tqdm

    from stp_env.progress import compiling_until_first_update

    desc = configs[0].label if len(configs) == 1 else f"{len(configs)} configurations"
    with tqdm(total=episodes * len(configs), desc=desc, unit="ep", disable=not progress, leave=True) as bar:
        compiling_until_first_update(bar, "compiling the simulator's batch (once per machine)...")
        return executor.run(job, out_dir=pieces_dir, progress=bar.update)


def _combine_batches(config, params, pieces, seed, episodes, batch_size, n_steps, plan_samples, confidence,
                     max_events, record, airborne_only, active) -> ConfigResult:
    """A configuration's result from its batches: the episodes in index order, the showcase the episode with the
    most forced vehicles (the lowest index among them)."""
    chunks: list[dict] = []
    showcase, best = None, (-1, 0)
    for piece in pieces:
        ep = {k[3:]: v for k, v in piece.items() if k.startswith("ep/")}
        j = _showcase_of(ep)
        rank = (int(ep["n_forced"][j]), -int(ep["index"][j]))
        if record and rank > best:
            best = rank
            showcase = {k[5:]: v for k, v in piece.items() if k.startswith("show/")}
            showcase.update(index=int(ep["index"][j]), final={k: v[j] for k, v in ep.items()})
        chunks.append(ep)
    seconds = max(float(sum(float(p["seconds"]) for p in pieces)), 1e-9)
    counts = sorted({int(p["devices"]) for p in pieces})
    devices = counts[0] if len(counts) == 1 else None   # batches run on different counts: no single program
    ep = {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}
    by_index = np.argsort(ep["index"], kind="stable")   # the batches ran in appearance order; report index order
    ep = {k: v[by_index] for k, v in ep.items()}
    summary = summarize(config, ep, params, confidence=confidence)
    summary.update(seed=seed, n_steps=n_steps, batch_size=batch_size, devices=counts if devices is None else devices,
                   seconds=round(seconds, 2), episodes_per_s=round(episodes / seconds, 2),
                   simulated_vehicles=params.vehicles.n if active is None else len(active))
    events = _events(config, seed, n_steps, plan_samples, batch_size, record, ep, config.kbar, airborne_only,
                     episodes, devices)
    summary["events_saved"] = min(len(events), max_events)
    return ConfigResult(config=config, seed=seed, n_steps=n_steps, plan_samples=plan_samples, episodes=ep,
                        summary=summary, events=events[:max_events], showcase=showcase, params=params,
                        airborne_only=airborne_only)

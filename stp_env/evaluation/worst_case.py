"""The intruder paper's worst case on the core: the ``fig6`` scenario with a fixed intruder spawn, played by the
buffer game's worst vehicles (Fig. 6) or by the vehicles' own controller ``u*`` (Fig. 7); and the same attack
designed on a planned layout, one wave of the ``pinwheel`` (:func:`pinwheel_run`).

:func:`fig6_params` builds the simulator constants (straight-line plan, the intruder appearing ``FIG6_LEAD`` s after
departure, the ``V^B`` table for the buffer-game policies); :func:`run_fixed_spawn` runs one episode from a given
intruder state (the core's spawner draws a random one), recording the trajectories.
"""

from __future__ import annotations

import functools
import math

import jax.numpy as jnp
import numpy as np

from stp_env import assembly, sim
from stp_env.assembly import load_buffer, with_buffer
from stp_env.sim import core, engine
from stp_env.sim.jit import sim_jit
from stp_env.sim.rollout import episode_step, over
from stp_env.sim.tables import FAR
from stp_env.sim.types import replace

FIG6_PAPER_TIMES = (0.0, 10 / 3, 20 / 3, math.inf)
"""Avoid-start times of ``Q1``-``Q4`` in the intruder paper's Fig. 6 [s] (``inf``: never forced)."""
FIG7_PAPER_TIMES = (0.0, 6.4, math.inf, math.inf)
"""The same in Fig. 7 (vehicles flying ``u^PP`` until forced)."""


def fig6_params(scenario=None, *, config: sim.EnvConfig | None = None, store=None, progress: bool = False):
    """``EnvParams`` of the ``fig6`` scenario (default ``make("fig6")``) with its straight-line plan and the
    ``V^B`` table; the intruder appears ``FIG6_LEAD`` s after departure (``config.appear_window`` overridden)."""
    from stp_env.scenarios import make
    from stp_env.scenarios.catalog.fig6 import FIG6_LEAD, fig6_plan

    scenario = make("fig6") if scenario is None else scenario
    config = sim.EnvConfig() if config is None else config
    # The episode starts at the departure (t = 0, steps at k dt) and the window is half a step before FIG6_LEAD: the
    # intruder appears at the first step time >= the window, i.e. at FIG6_LEAD, even when the float32 step times
    # fall a hair short of it.
    lo = FIG6_LEAD - 0.5 * config.dt
    config = config.with_overrides(appear_window=(lo, lo), lead=lo)
    avoid, tracking = assembly.load_artifacts(scenario, store=store, progress=progress)
    plan = fig6_plan(scenario, tracking.bound)
    params = assembly.make_params(scenario, plan, avoid, tracking, config)
    return with_buffer(params, load_buffer(scenario, store=store, progress=progress))


def fig6_spawn() -> np.ndarray:
    """The intruder's state at appearance: 1 m north of the origin, heading east (on ``Q1``'s avoid boundary, at
    ``Q2``). The metre keeps ``V^A`` of ``Q1`` above the avoid margin despite ``Q1``'s tracking error (up to
    ``r_e``) and float32 rounding, so that Assumption 3 holds; the hops to ``Q2``-``Q4`` (on ``y = 0``) are 1 m
    off-axis, which changes their lengths by under 0.01 m."""
    return np.asarray([0.0, 1.0, 0.0], np.float32)


@functools.partial(sim_jit, static_argnames=("vehicle_policy", "intruder_policy", "n_steps"))
def run_fixed_spawn(key, params, spawn, vehicle_policy, intruder_policy, n_steps: int):
    """One episode with the intruder appearing at ``spawn`` (3,): ``(final state, trajectory)``, the trajectory a
    dict of per-step arrays ``t``, ``x``, ``mode``, ``status``, ``intruder_x``, ``intruder_status``,
    ``avoid_value`` (``V^A`` of each vehicle against the intruder, ``FAR`` when absent)."""

    def init(k_reset):
        s0 = core.reset(k_reset, params)
        memory = jnp.concatenate([jnp.asarray(spawn, s0.intruder_memory.dtype),
                                  jnp.zeros((1,), s0.intruder_memory.dtype)])
        return replace(s0, intruder_memory=memory)

    def record(new, _):
        return {"t": new.t, "x": new.x, "mode": new.mode, "status": new.status, "intruder_x": new.intruder_x,
                "intruder_status": new.intruder_status, "avoid_value": new.avoid_value}

    return engine.episode(key, init, lambda state, k: episode_step(k, state, params, vehicle_policy, intruder_policy),
                          n_steps, stop=lambda state: over(state, params), record=record)


def reproduce(params, vehicle_policy, intruder_policy, *, seed: int = 0, spawn=None, n_steps: int | None = None):
    """Run the fixed-spawn episode and summarise it: ``{"avoid_start_s": [t_i - t_ per vehicle, inf if never],
    "min_avoid_value_m" and "min_avoid_value_time_s": each vehicle's smallest ``V^A`` against the intruder and
    when (how close an untouched vehicle came to being forced; ``None`` when the intruder never came within the
    avoid table of it), "n_forced", "collisions", "assumption_ok",
    "trajectory", "final"}`` (times relative to the appearance)."""
    from stp_env.seeds import prng_key

    spawn = fig6_spawn() if spawn is None else np.asarray(spawn, np.float32)
    n_steps = sim.steps_for(params) if n_steps is None else n_steps
    final, traj = run_fixed_spawn(prng_key(seed), params, jnp.asarray(spawn), vehicle_policy, intruder_policy,
                                  n_steps)
    t_appear = float(final.t_appear)
    starts = np.asarray(final.avoid_start) - t_appear
    values = np.asarray(traj["avoid_value"])
    closest = values.min(axis=0)
    return {
        "avoid_start_s": [round(float(t), 3) if np.isfinite(t) else math.inf for t in starts],
        "min_avoid_value_m": [round(float(v), 2) if v < FAR else None for v in closest],
        "min_avoid_value_time_s": [round(float(np.asarray(traj["t"])[int(np.argmin(values[:, i]))] - t_appear), 2)
                                   if closest[i] < FAR else None for i in range(values.shape[1])],
        "n_forced": int(np.sum(np.isfinite(starts))),
        "collisions": int(np.sum(np.asarray(final.status) == sim.COLLIDED)),
        "assumption_ok": np.asarray(final.assumption_ok).tolist(),
        "t_appear_s": t_appear,
        "trajectory": {k: np.asarray(v) for k, v in traj.items()},
        "final": final,
    }


def boundary_spawn(avoid, margin: float, vehicle, bearing: float, heading_offset: float = 0.0, *,
                   level_above: float = 1.0) -> np.ndarray:
    """An intruder state ``(x, y, theta)`` on a vehicle's avoid boundary: along the ray at ``bearing`` [rad, relative
    to the vehicle's heading] from ``vehicle = (x, y, theta)``, where ``V^A(0, t_IAT)`` equals ``margin +
    level_above`` (bisection in the avoid table: just outside the simulator's avoid margin, so that Assumption 3
    holds and the vehicle is forced within the first inner steps), heading ``heading_offset`` [rad] off the outward
    ray. Raises ``ValueError`` when the ray never leaves the region inside the table."""
    import jax.numpy as jnp

    from stp_env import hj

    grid, taus, values = avoid.grid, jnp.asarray(avoid.taus), jnp.asarray(avoid.values)
    x0, y0, th0 = (float(v) for v in vehicle)
    rel_heading = bearing + heading_offset

    def value(r):
        rel = jnp.asarray([r * math.cos(bearing), r * math.sin(bearing), rel_heading], jnp.float32)
        return float(hj.interpolation.interpolate_slices(grid, taus, values, 0.0, rel))

    level = margin + level_above
    lo, hi = 0.0, 0.99 * min(float(grid.hi[0]), float(grid.hi[1]))
    if value(hi) <= level:
        raise ValueError(f"the avoid region reaches the table's edge at bearing {bearing:.3f} rad.")
    if value(lo) > level:
        raise ValueError("the intruder is outside the avoid region even at the vehicle's position.")
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if value(mid) <= level else (lo, mid)
    world = th0 + bearing
    return np.asarray([x0 + hi * math.cos(world), y0 + hi * math.sin(world), th0 + rel_heading], np.float32)


PINWHEEL_SPAWN = (math.pi / 2, 0.0, -3.0)
"""The designed attack on a ``pinwheel`` wave: ``(bearing, heading offset, appearance)``: the intruder appears on
the avoid boundary of the wave's stream-0 vehicle straight to its left (toward the centre, where the other two are
equally far), heading outward along that ray, 3 s before the wave's triangle (the three at their tangent points);
``examples/pinwheel_worst_case.py`` searches the neighbourhood."""


def pinwheel_params(kbar: int = 3, *, wind_model="converging", appear: float = PINWHEEL_SPAWN[2],
                    config: sim.EnvConfig | None = None, store=None, progress: bool = False):
    """``(EnvParams, avoid region, plan)`` of one ``pinwheel`` wave (3 vehicles, ``make("pinwheel", kbar=kbar,
    n_waves=1)``, its straight plan) with the ``V^B`` table, the intruder appearing ``appear`` s after the wave's
    triangle (negative: before), and ``wind_model`` (default ``converging``: the buffer game's helping winds)."""
    from stp_env.planning.verify import straight_plan
    from stp_env.scenarios import make
    from stp_env.scenarios.catalog.pinwheel import PINWHEEL_BEFORE

    scenario = make("pinwheel", kbar=kbar, n_waves=1)
    avoid, tracking = assembly.load_artifacts(scenario, store=store, progress=progress)
    plan = straight_plan(scenario, tracking.bound, check=False)
    config = sim.EnvConfig() if config is None else config
    # on the step grid from the departure; the window half a step early (as fig6_params) against float32 step times
    at = config.dt * round((PINWHEEL_BEFORE / float(scenario.planning_v[1]) + appear) / config.dt)
    if at <= config.dt:
        raise ValueError(f"appear = {appear} s puts the appearance before the wave departs.")
    lo = at - 0.5 * config.dt
    config = config.with_overrides(wind_model=wind_model, appear_window=(lo, lo), lead=lo)
    params = assembly.make_params(scenario, plan, avoid, tracking, config)
    return with_buffer(params, load_buffer(scenario, store=store, progress=progress)), avoid, plan


def pinwheel_run(kbar: int = 3, bearing: float = PINWHEEL_SPAWN[0], heading_offset: float = PINWHEEL_SPAWN[1],
                 appear: float = PINWHEEL_SPAWN[2], *, wind_model="converging", vehicle_policy=None,
                 intruder_policy=None, seed: int = 0, setup=None, store=None):
    """One designed episode on a ``pinwheel`` wave (:func:`pinwheel_params`): the intruder appears on vehicle 0's
    avoid boundary (:func:`boundary_spawn`) and by default the ``worst`` vehicles play against ``optimal-max-k``;
    returns :func:`reproduce`'s summary. ``setup`` reuses a :func:`pinwheel_params` result, which must have been made
with the same ``kbar``, ``wind_model`` and ``appear`` (they are not read again)."""
    from stp_env.policies import optimal_max_k, worst

    params, avoid, plan = pinwheel_params(kbar, wind_model=wind_model, appear=appear, store=store) \
        if setup is None else setup
    single = plan.vehicles[0].plan
    t = float(params.intruder.appear_window[0]) + 0.5 * float(params.episode.dt)  # the step the intruder appears at
    vehicle = [np.interp(t, single.times, single.states[:, i]) for i in range(2)] + [float(single.states[0, 2])]
    spawn = boundary_spawn(avoid, float(params.tables.avoid_margin), vehicle, bearing, heading_offset)
    return reproduce(params, worst if vehicle_policy is None else vehicle_policy,
                     optimal_max_k if intruder_policy is None else intruder_policy, seed=seed, spawn=spawn)

"""Replanning after the intruder leaves (SPP Algorithm 4) in a one-episode environment: ``parallel_env(...,
replan=True)`` (:mod:`stp_env.env`). Without it (the default, and in the batched core) a forced vehicle flies the
jittable fallback of eq. 40 to its target, with no new STA.

The planning runs on the host (:func:`stp_env.planning.replan.replan`, level-set solves, about 15-25 s per event on
``town`` on 2 cores); the simulator's nominal tables are replaced with the new plan's
(:func:`stp_env.assembly.with_plan`: the same shapes, so the step is not traced again). It lives beside the adapter,
not in :mod:`stp_env.planning`, because it needs the assembly's tables, a layer above the planner
(docs/architecture.md).
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import assembly
from stp_env.angles import wrap_angle
from stp_env.sim.stepping import observe_jit
from stp_env.sim.types import AFTER_AVOIDANCE, FLYING, NOMINAL, replace


class Replanner:
    """Algorithm 4 for one environment: its scenario's plan (``None`` when replanning is off: then it only reports
    each vehicle's STA and ``replanned`` False), one attempt per vehicle and episode, and ``log`` (one dict per
    event: time, vehicles, new and old STAs, seconds; or the error)."""

    def __init__(self, scenario, params, *, enabled: bool, store=None, progress: bool = False):
        self.scenario = scenario
        self.enabled = bool(enabled)
        self._plan0 = None
        if self.enabled:
            from stp_env.planning.replan import obstacle_pads

            plan0 = assembly.load_plan(scenario, tracking_bound=float(params.tables.tracking_bound), store=store,
                                       progress=progress)
            # the windows of the plan's disks (derived once here for plan files that do not record them)
            self._plan0 = dataclasses.replace(plan0, obstacle_pads=obstacle_pads(plan0, scenario, store=store))
        self.reset(params)

    def reset(self, params) -> None:
        """A new episode on the scenario's own plan (``params`` its tables)."""
        self.base_params = params
        self.plan = self._plan0
        self.tried = np.zeros(params.vehicles.n, bool)
        self.replanned = np.zeros(params.vehicles.n, bool)
        self.sta = np.asarray(params.vehicles.sta, np.float64)
        self.log: list[dict] = []

    def after_step(self, carry, params, obs_of, info):
        """Replans every flying vehicle in the after-avoidance mode not tried yet, once the intruder has left: a new
        STA and plan, the nominal mode again (set in the packed ``carry``). Returns the env's params (new tables
        when a plan changed), and the observations (``obs_of(obs_vehicles, obs_intruder)``) and ``info`` of the
        updated state, or ``None`` for both when nothing changed."""
        need = (info.mode == AFTER_AVOIDANCE) & (info.status == FLYING) & ~self.tried
        if not self.enabled or not need.any():
            return params, None, None
        from stp_env.planning.replan import replan  # host-side level-set planning: imported on first use

        idx = [int(i) for i in np.nonzero(need)[0]]
        self.tried[idx] = True  # one attempt per vehicle and episode
        key, state = carry.unpacked()
        x = np.asarray(state.x, np.float64)
        t_bar = float(state.t)
        affected = {i: (x[i, 0], x[i, 1], wrap_angle(float(x[i, 2]))) for i in idx}
        start = time.perf_counter()
        try:
            new_plan = replan(self.plan, self.scenario, affected, t_bar)
        except ValueError as err:
            warnings.warn(f"replanning vehicles {idx} at t = {t_bar:.1f} s failed ({err}); they keep the fallback "
                          "control of eq. 40.", stacklevel=3)
            self.log.append({"time": t_bar, "vehicles": idx, "error": str(err)})
            return params, None, None
        self.plan = new_plan
        params = assembly.with_plan(params, new_plan)
        state = replace(state, mode=state.mode.at[jnp.asarray(idx)].set(NOMINAL))
        carry.set((key, state))
        self.replanned[idx] = True
        self.sta = np.asarray(params.vehicles.sta, np.float64)
        self.log.append({"time": t_bar, "vehicles": idx,
                         "sta": [float(new_plan.vehicles[i].plan.sta) for i in idx],
                         "old_sta": [float(self.base_params.vehicles.sta[i]) for i in idx],
                         "seconds": round(time.perf_counter() - start, 2)})
        obs = obs_of(*jax.device_get(observe_jit(state, params)))
        mode = np.array(info.mode)
        mode[idx] = NOMINAL
        return params, obs, info._replace(mode=mode)

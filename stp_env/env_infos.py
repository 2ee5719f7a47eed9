"""The infos of the PettingZoo adapter (:mod:`stp_env.env`) and its ``env.episode`` record, built on the host from
a step's :class:`stp_env.sim.stepping.StepInfo` (the keys and their meaning: docs/environment.md, "Infos").

Numbers only (ints, floats, bools; no NaN), the same keys for every vehicle at every step, so that tensors can hold
them; the episode's results are flat ``stp_episode_<name>`` entries in every agent's info (not ``episode``, the key
Stable-Baselines3's monitors own). The episode metrics are those of :mod:`stp_env.sim.metrics`, the evaluator's.
"""

from __future__ import annotations

import math

import numpy as np

from stp_env.sim.metrics import largest_tracking_error, tracked_flights
from stp_env.sim.types import COLLIDED, INTRUDER_STATUS_NAMES


class InfoBuilder:
    """Infos of the agents of one environment: ``names`` the vehicles' agent names (index order), ``in_episode``
    which of them fly in the episode (not in their target at its start), ``kbar`` and the tracking bound ``r_e``."""

    def __init__(self, names, in_episode, kbar: int, tracking_bound: float):
        self.names = list(names)
        self.done_at_start = ~np.asarray(in_episode, bool)
        self.kbar = int(kbar)
        self.tracking_bound = float(tracking_bound)

    def episode(self, info) -> dict:
        """The episode's results so far, numbers only (the infos' ``stp_episode_*``)."""
        status, avoid_start = info.status.astype(int), info.avoid_start
        n_forced = int(np.isfinite(avoid_start).sum())
        largest = largest_tracking_error(info.max_tracking_error,
                                         tracked_flights(info.tracked, status, self.done_at_start))
        return {
            "n_forced": n_forced,
            "kbar": self.kbar,
            "kbar_exceeded": bool(self.kbar > 0 and n_forced > self.kbar),
            "collisions": int((status == COLLIDED).sum()),
            "guarantee_violations": int(info.guarantee_violation.sum()),
            "tracking_violations": int(info.tracking_violation.sum()),
            # no NaN in the infos (NaN != NaN: PettingZoo's seed tests compare infos): the maximum over no vehicle
            "max_tracking_error": -math.inf if largest is None else largest,
            "tracking_bound": self.tracking_bound,
            "intruder_status": int(info.intruder_status),
            "time": float(info.t),
        }

    @staticmethod
    def readable(episode: dict) -> dict:
        """``env.episode``: the same record to read, with names (``intruder_status`` ``"gone"``) and ``None`` (no
        vehicle tracked its plan)."""
        return {**episode, "intruder_status": INTRUDER_STATUS_NAMES[episode["intruder_status"]],
                "max_tracking_error": (None if episode["max_tracking_error"] == -math.inf
                                       else episode["max_tracking_error"])}

    def infos(self, info, live, episode: dict, replanned, sta) -> dict:
        """The infos of the agents ``live`` (in that order); ``replanned`` and ``sta`` per vehicle (Algorithm 4)."""
        status, mode, avoid_start = info.status.astype(int), info.mode.astype(int), info.avoid_start
        forced = np.isfinite(avoid_start)
        collided = status == COLLIDED
        new_collision = collided & (info.prev_status != COLLIDED)
        n_forced, kbar, t = episode["n_forced"], self.kbar, episode["time"]
        # Only the live agents' dicts are built (the city's finished vehicles are most of its agents late in an
        # episode), each from Python lists (one tolist() per column): no per-element numpy scalars
        live_set = set(live)
        columns = zip(self.names, status.tolist(), mode.tolist(), avoid_start.tolist(), forced.tolist(),
                      collided.tolist(), info.guarantee_violation.tolist(), info.tracking_error.tolist(),
                      info.max_tracking_error.tolist(), info.tracked.tolist(), info.tracking_violation.tolist(),
                      info.used_filter.tolist(), replanned.tolist(), sta.tolist(), info.min_separation.tolist(),
                      new_collision.tolist())
        record = {f"stp_episode_{k}": v for k, v in episode.items()}  # flat: a tensor per entry
        built = {}
        for (agent, st, md, start, frc, col, viol, err, max_err, tracked, track_viol, used_i, replanned_i, sta_i,
             sep, new_col) in columns:
            if agent not in live_set:
                continue
            built[agent] = {
                "status": st,
                "mode": md,
                "avoid_start_time": start,  # inf: never forced (the core's own convention)
                "forced": frc,
                "n_forced": n_forced,
                "kbar": kbar,
                "collision": col,
                "guarantee_violation": viol,
                "tracking_error": err,
                "max_tracking_error": max_err,
                "tracked": tracked,
                "tracking_violation": track_viol,
                "used_filter": used_i,
                "replanned": replanned_i,
                "sta": sta_i,
                "min_separation": sep,
                "cost": float(new_col),
                "time": t,
                **record,
            }
        if "intruder" in live_set:
            built["intruder"] = {
                "status": episode["intruder_status"],
                "n_forced": n_forced,
                "kbar": kbar,
                "kbar_exceeded": episode["kbar_exceeded"],
                "collisions": episode["collisions"],
                "guarantee_violations": episode["guarantee_violations"],
                "tracking_violations": episode["tracking_violations"],
                "cost": 0.0,
                "time": t,
                **record,
            }
        return {agent: built[agent] for agent in live}

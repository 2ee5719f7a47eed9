"""Episode metrics that the one-episode adapter (:mod:`stp_env.env`, its infos and ``env.episode``) and the batched
evaluator (:func:`stp_env.evaluation.runner.summarize`) both report, defined once: NumPy on host arrays, one
episode ``(N,)`` or a batch ``(episodes, N)`` alike.

* ``|N^RP|`` (intruder paper eq. 39): the vehicles forced to avoid, those with a finite avoid start ``t_i``.
* The tracking record (SPP eqs. 24-26): a vehicle counts when it flew in the episode (not still waiting, not in its
  target when the episode started) and applied the tracker ``kappa`` at every inner step while flying its plan.
"""

from __future__ import annotations

import numpy as np

from stp_env.sim.types import WAITING


def n_forced(avoid_start, axis: int = -1):
    """``|N^RP|``: the vehicles with a finite avoid start (eq. 39), over ``axis``."""
    return np.sum(np.isfinite(avoid_start), axis=axis)


def tracked_flights(tracked, status, done_at_start):
    """The vehicles whose tracking error counts: they tracked their plan, flew in the episode (``status`` not
    ``WAITING``) and were not in their target at its start (``done_at_start``)."""
    return np.asarray(tracked, bool) & (np.asarray(status) != WAITING) & ~np.asarray(done_at_start, bool)


def largest_tracking_error(max_tracking_error, flew) -> float | None:
    """The largest tracking error [m] of the vehicles ``flew`` (:func:`tracked_flights`); ``None`` when none did
    (e.g. every vehicle flown by the ``worst`` policy)."""
    flew = np.asarray(flew, bool)
    if not flew.any():
        return None
    return float(np.max(np.where(flew, max_tracking_error, -np.inf)))

"""The one summary of a set of episodes against the k̄ bound: ``|N^RP|`` (intruder paper eq. 39), collisions and
guarantee violations, with exact Clopper-Pearson bounds (:mod:`stp_env.evaluation.stats`) on the rates of episodes
above k̄ and of episodes with a violation.

Every evaluator reads its numbers here: the batched evaluation (:func:`stp_env.evaluation.runner.summarize`, which
adds what only it measures), the evaluations during intruder training (:func:`stp_env.rl.train.summarize`) and the
scripts that compare intruders or replanning modes.
"""

from __future__ import annotations

import math

import numpy as np

from stp_env.evaluation.stats import clopper_pearson_upper


def mean_interval(values) -> tuple[float, float]:
    """Mean and the half-width of its 95 % normal interval (``1.96 s / sqrt(n)``; ``nan`` below two values)."""
    values = np.asarray(values, np.float64)
    if values.size < 2:
        return float(values.mean()) if values.size else math.nan, math.nan
    return float(values.mean()), float(1.96 * values.std(ddof=1) / math.sqrt(values.size))


def forced_summary(n_forced, kbar: int, collisions, violations, *, confidence: float = 0.95) -> dict:
    """The summary of ``E >= 1`` episodes from per-episode counts.

    Args:
        n_forced: ``(E,)`` vehicles forced to avoid (``|N^RP|``, eq. 39) in each episode.
        kbar: the bound k̄ the episodes are checked against.
        collisions: ``(E,)`` or ``(E, N)``: vehicles that collided in each episode (a ``(E, N)`` array of flags or
            counts is summed over vehicles).
        violations: ``(E,)`` or ``(E, N)``: guarantee violations in each episode (as ``collisions``).
        confidence: of the one-sided upper bounds.

    Returns:
        ``episodes``; ``forced_mean``, ``forced_ci95`` (half-width of the normal 95 % interval of the mean),
        ``forced_max``; ``exceed`` (episodes with ``|N^RP| > k̄``), ``exceed_rate``, ``exceed_upper`` (its exact
        one-sided Clopper-Pearson bound at ``confidence``); ``kbar_reached`` (episodes with ``|N^RP| >= k̄``);
        ``collision_episodes``, ``collisions`` (vehicles); ``guarantee_violations`` (vehicles),
        ``violation_episodes`` and ``violation_upper``; ``confidence``.
    """
    n_forced = np.asarray(n_forced)
    if n_forced.ndim != 1 or n_forced.size == 0:
        raise ValueError(f"n_forced must be a non-empty (episodes,) array; got shape {n_forced.shape}.")
    e = n_forced.size
    per_episode = {}
    for name, value in (("collisions", collisions), ("violations", violations)):
        value = np.asarray(value)
        if value.shape[:1] != (e,) or value.ndim > 2:
            raise ValueError(f"{name} must be ({e},) or ({e}, vehicles); got shape {value.shape}.")
        per_episode[name] = value.reshape(e, -1).sum(axis=1, dtype=np.int64)
    mean, half = mean_interval(n_forced)
    exceed = int(np.sum(n_forced > kbar))
    violation_eps = int(np.sum(per_episode["violations"] > 0))
    return {
        "episodes": e,
        "forced_mean": mean, "forced_ci95": half, "forced_max": int(n_forced.max()),
        "exceed": exceed, "exceed_rate": exceed / e, "exceed_upper": clopper_pearson_upper(exceed, e, confidence),
        "kbar_reached": int(np.sum(n_forced >= kbar)),
        "collision_episodes": int(np.sum(per_episode["collisions"] > 0)),
        "collisions": int(per_episode["collisions"].sum()),
        "guarantee_violations": int(per_episode["violations"].sum()),
        "violation_episodes": violation_eps,
        "violation_upper": clopper_pearson_upper(violation_eps, e, confidence),
        "confidence": confidence,
    }

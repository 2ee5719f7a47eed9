"""Rates, intervals and policy-switching thresholds of a survivability study (survivability paper, Section VI).

* Success and survival rates per scenario and policy with exact two-sided 95 % Clopper-Pearson intervals
  (:mod:`stp_env.evaluation.stats`).
* Differences between two policies (or between survival and success of one policy) on the same instances: the
  mean of the paired differences with a normal 95 % interval (``1.96 s / sqrt(n)``).
* The switching thresholds: ``phi(N_p)``, the number of unknown intruders at which ``pi_Nf``'s survival rate
  overtakes ``pi_S``'s for ``N_p`` partially known intruders (Figs. 9-10), and ``eta(N_total)``, the fraction of
  unknown intruders at which it does so for ``N_total`` intruders (Figs. 11-12): the first zero crossing, from
  below, of the survival difference, interpolated linearly between scenarios. Their 95 % intervals are percentile
  bootstrap intervals over instances (instance ``i`` is resampled in every scenario at once, since it shares its
  traffic across scenarios); a crossing missing from a bootstrap sample counts as beyond the grid.
"""

from __future__ import annotations

import math

import numpy as np

from stp_env.evaluation.stats import clopper_pearson_interval

Z95 = 1.959963984540054


def outcome_table(rows, policies):
    """``{(n_p, n_u): {policy: {instance: outcome}}}``, keeping only instances flown by every policy."""
    table: dict = {}
    for r in rows:
        table.setdefault((r["n_partial"], r["n_unknown"]), {}).setdefault(r["policy"], {})[r["instance"]] = r["outcome"]
    for key, per in table.items():
        common = set.intersection(*(set(per.get(p, {})) for p in policies))
        table[key] = {p: {i: per[p][i] for i in sorted(common)} for p in policies}
    return table


def rate(k: int, n: int) -> dict:
    lo, hi = clopper_pearson_interval(k, n) if n else (0.0, 1.0)
    return {"k": k, "n": n, "rate": k / n if n else math.nan, "ci95": [lo, hi]}


def paired(a: np.ndarray, b: np.ndarray) -> dict:
    """Mean of ``a - b`` (paired 0/1 outcomes) with a normal 95 % interval."""
    d = np.asarray(a, float) - np.asarray(b, float)
    n = len(d)
    if n == 0:
        return {"diff": math.nan, "ci95": [math.nan, math.nan], "n": 0}
    m = float(d.mean())
    h = Z95 * float(d.std(ddof=1)) / math.sqrt(n) if n > 1 else math.inf
    return {"diff": m, "ci95": [m - h, m + h], "n": n}


def indicators(outcomes: dict, what: str) -> tuple[np.ndarray, np.ndarray]:
    """(instances, 0/1 array) of success (``G``) or survival (``G`` or ``A``)."""
    ids = np.array(sorted(outcomes), int)
    ok = ("G",) if what == "success" else ("G", "A")
    return ids, np.array([outcomes[i] in ok for i in ids], float)


def summarize(rows, policies) -> dict:
    """Per scenario and policy: success and survival rates with Clopper-Pearson intervals."""
    out = {}
    for key, per in sorted(outcome_table(rows, policies).items()):
        out[key] = {}
        for p in policies:
            _, s = indicators(per[p], "success")
            _, v = indicators(per[p], "survival")
            out[key][p] = {"success": rate(int(s.sum()), len(s)), "survival": rate(int(v.sum()), len(v)),
                           "emergency": rate(int(len(v) - v.sum()), len(v))}
    return out


def first_crossing(x, d) -> float | None:
    """Where ``d(x)`` first crosses from ``< 0`` to ``>= 0`` (linear interpolation; ``x`` increasing); ``None`` if
    it never does. If ``d(x[0]) >= 0`` the crossing is at or below ``x[0]`` and ``x[0]`` is returned."""
    x, d = np.asarray(x, float), np.asarray(d, float)
    if d[0] >= 0:
        return float(x[0])
    for i in range(1, len(x)):
        if d[i] >= 0 > d[i - 1]:
            return float(x[i - 1] + (x[i] - x[i - 1]) * (-d[i - 1]) / (d[i] - d[i - 1]))
    return None


def _survival_matrix(table, keys, policy, instances):
    return np.array([[table[k][policy][i] in ("G", "A") for i in instances] for k in keys], float)


def threshold(table, keys, x, a: str = "Nf", b: str = "S", n_boot: int = 2000, seed: int = 0) -> dict:
    """The crossing of ``survival(a) - survival(b)`` along the scenarios ``keys`` at abscissae ``x``, with a
    bootstrap interval over the instances common to all of them."""
    instances = sorted(set.intersection(*(set(table[k][a]) for k in keys)))
    if not instances:
        return {"value": None, "ci95": [None, None], "n": 0}
    sa = _survival_matrix(table, keys, a, instances)
    sb = _survival_matrix(table, keys, b, instances)
    diff = sa - sb                                                       # (n_keys, n_instances)
    value = first_crossing(x, diff.mean(axis=1))
    rng = np.random.default_rng(seed)
    n = len(instances)
    boots = []
    for _ in range(n_boot):
        idx = rng.integers(0, n, n)
        c = first_crossing(x, diff[:, idx].mean(axis=1))
        boots.append(np.inf if c is None else c)
    boots = np.array(boots)
    lo, hi = np.quantile(boots, [0.025, 0.975], method="inverted_cdf")     # no interpolation: inf stays inf
    return {"value": value, "ci95": [None if np.isinf(lo) else float(lo), None if np.isinf(hi) else float(hi)],
            "n": n, "at_or_below_grid": bool(value is not None and value == float(x[0])),
            "no_crossing_fraction": float(np.isinf(boots).mean()),
            "differences": [float(v) for v in diff.mean(axis=1)], "x": [float(v) for v in x]}


def thresholds(rows, policies, n_partial, n_unknown, n_boot: int = 2000) -> dict:
    """``phi(N_p)`` for every ``N_p`` and ``eta(N_total)`` for every total on the grid's anti-diagonals."""
    table = outcome_table(rows, policies)
    out = {"phi": {}, "eta": {}}
    if not {"Nf", "S"} <= set(policies):
        return out
    for p in n_partial:
        keys = [(p, u) for u in n_unknown if (p, u) in table]
        if len(keys) >= 2:
            out["phi"][p] = threshold(table, keys, [k[1] for k in keys], n_boot=n_boot)
    totals = sorted({p + u for p in n_partial for u in n_unknown})
    for tot in totals:
        keys = sorted(((p, u) for p in n_partial for u in n_unknown if p + u == tot and (p, u) in table),
                      key=lambda k: k[1])
        if len(keys) >= 2:
            out["eta"][tot] = threshold(table, keys, [k[1] / tot for k in keys], n_boot=n_boot)
    return out


def comparisons(rows, policies) -> dict:
    """Paired differences behind the paper's findings: survival of each policy against ``pi_S`` and ``pi_Nf``,
    and survival minus success of every policy, per scenario."""
    table = outcome_table(rows, policies)
    out = {}
    for key, per in sorted(table.items()):
        entry = {}
        for p in policies:
            _, succ = indicators(per[p], "success")
            _, surv = indicators(per[p], "survival")
            entry[f"survival-success[{p}]"] = paired(surv, succ)
            for ref in ("S", "Nf"):
                if ref in policies and p != ref:
                    _, other = indicators(per[ref], "survival")
                    entry[f"survival[{p}]-survival[{ref}]"] = paired(surv, other)
        out[key] = entry
    return out


def conflicts(rows, policies) -> dict:
    """Conflicts per mission (intruders revealed by a conflict, the ``reveals`` column), per scenario and policy:
    ``{(n_p, n_u): {policy: {"mean": m, "max": k, "n": n}}}`` over the instances flown by every policy."""
    flown = {key: {p: set(per[p]) for p in policies} for key, per in outcome_table(rows, policies).items()}
    counts: dict = {}
    for r in rows:
        key, p = (r["n_partial"], r["n_unknown"]), r["policy"]
        if p in policies and r["instance"] in flown.get(key, {}).get(p, ()):
            counts.setdefault(key, {}).setdefault(p, []).append(int(r["reveals"]))
    return {key: {p: {"mean": float(np.mean(v)), "max": int(np.max(v)), "n": len(v)} for p, v in sorted(per.items())}
            for key, per in sorted(counts.items())}


def goal_loss(rows, policies) -> dict:
    """When the goal was lost, and what followed, per scenario and policy: the missions whose terminal set was
    widened to the alternative sites (``omega_switch >= 0``: no known-feasible trajectory reached the goal any
    more), counted by the cruise window of the loss and split by outcome: ``A`` (landed at an alternative site),
    ``L_at_loss`` (an emergency landing in the window of the loss: no site was reachable, or the conflicts revealed
    in that window closed every way to one) and ``L_later`` (a site was reachable for at least one more window).
    Knowledge only grows, so a mission that lost the goal cannot land there: such a row is refused. Only instances flown
    by every policy count (as :func:`outcome_table`). Returns ``{(n_p, n_u): {policy: {"missions": n, "lost": k,
    "by_window": {window: {"A": a, "L_at_loss": b, "L_later": c}}}}}``."""
    flown = {key: {p: set(per[p]) for p in policies} for key, per in outcome_table(rows, policies).items()}
    out: dict = {}
    for key, per in flown.items():
        out[key] = {p: {"missions": len(per[p]), "lost": 0, "by_window": {}} for p in policies}
    for r in rows:
        key, p = (r["n_partial"], r["n_unknown"]), r["policy"]
        if p not in policies or r["instance"] not in flown.get(key, {}).get(p, ()) or r["omega_switch"] < 0:
            continue
        if r["outcome"] == "G":
            raise ValueError(f"mission {key} instance {r['instance']} ({p}) lost the goal and then landed there.")
        entry = out[key][p]
        entry["lost"] += 1
        kind = "A" if r["outcome"] == "A" else ("L_at_loss" if r["windows"] == r["omega_switch"] else "L_later")
        cell = entry["by_window"].setdefault(int(r["omega_switch"]), {"A": 0, "L_at_loss": 0, "L_later": 0})
        cell[kind] += 1
    for per in out.values():
        for entry in per.values():
            entry["by_window"] = dict(sorted(entry["by_window"].items()))
    return out


def goal_corridor(graph) -> list[dict]:
    """With no traffic: per cruise window ``k``, the states on the way to the goal (reachable from the origin, some
    trajectory from them reaches the goal) and how many of them could still reach an alternative site instead,
    counted as states and weighted by the goal trajectories through them (``trajectories``: the share of the
    origin's goal trajectories whose state at window ``k`` can reach an alternative site). Where that share is 0,
    losing the goal in that window leaves no landing site at all: an emergency landing, whatever the policy.
    Terminal states of the goal absorb; the alternative sites do not (a goal trajectory may pass one)."""
    from stp_env.survivability import dp

    feasible = np.ones(graph.n_segments, bool)
    n_goal = np.asarray(dp.counts(graph, feasible, "goal"), float)
    n_alt = np.asarray(dp.counts(graph, feasible, "alt"), float)
    forward = np.zeros(graph.n_states)
    forward[graph.origin] = 1.0
    n_windows = len(graph.window_start) - 1
    for k in range(n_windows):
        states = np.arange(graph.window_start[k], graph.window_start[k + 1])
        states = states[(forward[states] > 0) & ~graph.term_goal[states]]
        for a in range(graph.succ.shape[1]):
            nxt = graph.succ[states, a]
            ok = nxt >= 0
            np.add.at(forward, nxt[ok], forward[states[ok]])
    out = []
    for k in range(n_windows):
        sl = slice(graph.window_start[k], graph.window_start[k + 1])
        on = (n_goal[sl] > 0) & (forward[sl] > 0) & ~graph.term_goal[sl]
        if not on.any():
            continue
        weight = forward[sl] * n_goal[sl] * on
        alt = n_alt[sl] > 0
        out.append({"window": k, "states": int(on.sum()), "states_alt": int((on & alt).sum()),
                    "trajectories": float((weight * alt).sum() / weight.sum())})
    return out

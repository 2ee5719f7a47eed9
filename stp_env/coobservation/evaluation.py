"""Monte Carlo evaluation of co-observation schedules against attackers in the UAV simulator.

For each (schedule, attacker) pair, ``n`` episodes of :func:`stp_env.coobservation.threat.rollout` (batched with
``vmap``), each with a random compromised vehicle and compromise time, summarised as:

* **success rate** (the compromised vehicle entered a forbidden zone and no observation of it was missed) with the
  exact one-sided 95 % Clopper-Pearson upper bound (:func:`stp_env.evaluation.stats.clopper_pearson_upper`);
* **entry rate**, **detection rate** (episodes in which the compromised vehicle missed an observation) and the
  detection rate among entries, with the mean and largest **detection delay** (detection time minus entry time);
* honest vehicles: missed observations not caused by the compromised vehicle's own absence (``other misses``: an
  honest vehicle knocked out of the formation, e.g. by a collision with the attacker), entries into a zone
  (should be 0) and the largest distance of an honest vehicle from its nominal position (the margin the
  schedule's ellipses allow for);
* **entry attempts** (:func:`stp_env.coobservation.threat.attempts`: the compromised vehicle left its plan and
  entered a zone or was detected trying), their rate per episode, the **undetected entries** among them with the
  Clopper-Pearson bound, and the quantiles of each attempt's **time margin** to the observation that would detect
  it (:func:`stp_env.coobservation.threat.attempt_margin`, >= 0: undetected), over the attempts whose observers
  were not lost (``lost attempts``: a vehicle of an observation pair collided, margin ``-inf``).

The searched attacker (:mod:`stp_env.coobservation.searched`, :func:`run_searched`) is not drawn per episode: the
cross-entropy search chooses its attacks, and its row counts every attack the search evaluated (``episodes`` are
evaluations, not independent draws, so its bound describes the search's samples, not a random attacker).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import numpy as np
from tqdm.auto import tqdm

from stp_env.arguments import check_int
from stp_env.coobservation import threat
from stp_env.evaluation.stats import clopper_pearson_upper
from stp_env.seeds import prng_key


@dataclasses.dataclass(frozen=True)
class Row:
    schedule: str
    attacker: str
    episodes: int
    successes: int
    success_upper95: float
    entries: int
    detections: int
    detected_entries: int
    mean_delay: float
    max_delay: float
    other_misses: int
    honest_entries: int
    collisions: int
    max_tracking_error: float
    unchecked: int
    attempts: int = 0
    undetected_entries: int = 0
    undetected_upper95: float = math.nan
    lost_attempts: int = 0
    margin_quantiles: dict = dataclasses.field(default_factory=dict)
    margins: np.ndarray | None = dataclasses.field(default=None, repr=False, compare=False)

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        del d["margins"]
        d["success_rate"] = self.success_rate
        d["attempt_rate"] = self.attempts / self.episodes
        d["detection_rate"] = self.detections / self.episodes
        d["detection_rate_given_entry"] = self.detected_entries / self.entries if self.entries else None
        return d


def run(params, threats: dict, attackers: dict, n_episodes: int, *, t_window, batch: int = 1000, seed: int = 0,
        progress: bool = True) -> list[Row]:
    """Every (schedule, attacker) pair: ``threats`` maps schedule names to :class:`ThreatParams` (padded to one
    length, so that each attacker compiles once), ``attackers`` names to jittable attackers. Episode ``i`` of a
    pair uses the same key for every pair (common random numbers: the same compromises and winds)."""
    check_int(n_episodes, "n_episodes", 1)
    check_int(batch, "batch", 1)
    base = prng_key(seed)  # [0, 2**63 - 1], every seed its own episodes
    n_steps = threat.steps_for(params)
    rows = []
    jobs = [(s, a) for a in attackers for s in threats]
    bar = tqdm(total=len(jobs) * n_episodes, desc="co-observation evaluation", unit="episode", disable=not progress)
    try:
        for s_name, a_name in jobs:
            outs = []
            done = 0
            b = 0
            while done < n_episodes:
                size = min(batch, n_episodes - done)
                key = jax.random.fold_in(base, b)
                final, _ = threat.rollout(key, params, threats[s_name], attackers[a_name], batch, n_steps,
                                          tuple(float(t) for t in t_window))
                final = jax.device_get(final)
                o = threat.outcomes(final)
                o.update({f"attempt_{k}": v for k, v in threat.attempts(final, params, threats[s_name]).items()})
                outs.append({k: v[:size] for k, v in o.items()})
                done += size
                b += 1
                bar.update(size)
            o = {k: np.concatenate([x[k] for x in outs]) for k in outs[0]}
            rows.append(summarize(s_name, a_name, o))
    finally:
        bar.close()
    return rows


MARGIN_QUANTILES = {"min": 0.0, "5%": 0.05, "25%": 0.25, "50%": 0.5, "75%": 0.75, "95%": 0.95, "max": 1.0}


def run_searched(params, threats: dict, budget: int, *, seed: int = 0, config=None, progress: bool = True):
    """The searched attacker (:mod:`stp_env.coobservation.searched`) against every schedule in ``threats``:
    ``budget`` evaluations of the cross-entropy search each (``config``: a :class:`SearchConfig`, default
    :func:`~stp_env.coobservation.searched.default_config`), the wind keyed by ``seed``. Returns the rows (one per
    schedule, over every evaluated attack) and, per schedule, the search's record: evaluations, the best margin,
    the best attack ``z`` and what it means (replay: ``SearchedAttack(params, threat, wind_seed).episode(z)``)."""
    from stp_env.coobservation import searched

    check_int(budget, "budget", 1)
    config = searched.default_config(budget) if config is None else config
    rows, records = [], {}
    for s_name, tp in threats.items():
        attack = searched.SearchedAttack(params, tp, wind_seed=seed)
        with tqdm(total=config.budget, desc=f"searched attacker, {s_name}", unit="attack",
                  disable=not progress) as bar:
            out = searched.run(attack, config, seed=seed, progress=bar)
        o = threat.outcomes(out.finals)
        o.update({f"attempt_{k}": v for k, v in threat.attempts(out.finals, params, tp).items()})
        rows.append(summarize(s_name, "searched", o))
        r = out.result
        records[s_name] = {"evaluations": r.evaluations, "best_margin_s": r.best_value,
                           "undetected_entries_in_search": int((r.values >= 0).sum()),
                           "best_z": [float(v) for v in r.best_z], "best": dataclasses.asdict(out.best),
                           "wind_seed": seed, "history": [float(v) for v in r.history],
                           "config": dataclasses.asdict(config)}
    return rows, records


def summarize(schedule: str, attacker: str, o: dict) -> Row:
    """A row from per-episode outcomes (:func:`stp_env.coobservation.threat.outcomes`) and attempts
    (:func:`stp_env.coobservation.threat.attempts`, keys prefixed ``attempt_``)."""
    n = len(o["success"])
    k = int(o["success"].sum())
    delays = o["delay"][np.isfinite(o["delay"])]
    attempt = o["attempt_attempt"]
    undetected = int(o["attempt_undetected"].sum())
    margins = o["attempt_margin"][attempt]
    finite = margins[np.isfinite(margins)]
    quantiles = ({name: float(np.quantile(finite, q, method="inverted_cdf")) for name, q in MARGIN_QUANTILES.items()}
                 if len(finite) else {})
    return Row(schedule=schedule, attacker=attacker, episodes=n, successes=k,
               success_upper95=clopper_pearson_upper(k, n), entries=int(o["entered"].sum()),
               detections=int(o["detected"].sum()), detected_entries=int((o["entered"] & o["detected"]).sum()),
               mean_delay=float(delays.mean()) if len(delays) else math.nan,
               max_delay=float(delays.max()) if len(delays) else math.nan,
               other_misses=int(o["false_alarms"].sum()), honest_entries=int(o["honest_entries"].sum()),
               collisions=int(o["collisions"].sum()), max_tracking_error=float(o["max_track_error"].max()),
               unchecked=int((~o["all_checked"]).sum()), attempts=int(attempt.sum()), undetected_entries=undetected,
               undetected_upper95=clopper_pearson_upper(undetected, n), lost_attempts=int(o["attempt_lost"].sum()),
               margin_quantiles=quantiles, margins=finite)


def markdown(rows: list[Row]) -> str:
    head = ("| schedule | attacker | episodes | successes | success rate (95% upper) | entries | detected "
            "| detected / entries | delay mean / max [s] | other misses | honest entries | collisions "
            "| max honest error [m] |")
    lines = [head, "|" + "---|" * 13]
    for r in rows:
        det_entry = f"{r.detected_entries}/{r.entries}" if r.entries else "-"
        delay = f"{r.mean_delay:.1f} / {r.max_delay:.1f}" if math.isfinite(r.mean_delay) else "-"
        lines.append(f"| {r.schedule} | {r.attacker} | {r.episodes} | {r.successes} | {r.success_rate:.4f} "
                     f"(<= {r.success_upper95:.2e}) | {r.entries} | {r.detections} | {det_entry} | {delay} "
                     f"| {r.other_misses} | {r.honest_entries} | {r.collisions} | {r.max_tracking_error:.1f} |")
    return "\n".join(lines)


def attempts_markdown(rows: list[Row]) -> str:
    """The attempts table: attempts and their rate per episode, undetected entries with the exact 95 % bound, lost
    attempts and the quantiles of the finite time margins [s] (>= 0: undetected)."""
    head = ("| schedule | attacker | episodes | attempts | attempt rate | undetected entries (95% upper) "
            "| lost attempts | margin [s] min / 5% / 25% / 50% / 75% / 95% / max |")
    lines = [head, "|" + "---|" * 8]
    for r in rows:
        q = r.margin_quantiles
        margin = " / ".join(f"{q[k]:.1f}" for k in MARGIN_QUANTILES) if q else "-"
        lines.append(f"| {r.schedule} | {r.attacker} | {r.episodes} | {r.attempts} | {r.attempts / r.episodes:.4f} "
                     f"| {r.undetected_entries} (<= {r.undetected_upper95:.2e}) | {r.lost_attempts} | {margin} |")
    return "\n".join(lines)

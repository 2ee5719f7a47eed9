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
  schedule's ellipses allow for).
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

    @property
    def success_rate(self) -> float:
        return self.successes / self.episodes

    def as_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["success_rate"] = self.success_rate
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
                o = threat.outcomes(jax.device_get(final))
                outs.append({k: v[:size] for k, v in o.items()})
                done += size
                b += 1
                bar.update(size)
            o = {k: np.concatenate([x[k] for x in outs]) for k in outs[0]}
            rows.append(summarize(s_name, a_name, o))
    finally:
        bar.close()
    return rows


def summarize(schedule: str, attacker: str, o: dict) -> Row:
    n = len(o["success"])
    k = int(o["success"].sum())
    delays = o["delay"][np.isfinite(o["delay"])]
    return Row(schedule=schedule, attacker=attacker, episodes=n, successes=k,
               success_upper95=clopper_pearson_upper(k, n), entries=int(o["entered"].sum()),
               detections=int(o["detected"].sum()), detected_entries=int((o["entered"] & o["detected"]).sum()),
               mean_delay=float(delays.mean()) if len(delays) else math.nan,
               max_delay=float(delays.max()) if len(delays) else math.nan,
               other_misses=int(o["false_alarms"].sum()), honest_entries=int(o["honest_entries"].sum()),
               collisions=int(o["collisions"].sum()), max_tracking_error=float(o["max_track_error"].max()),
               unchecked=int((~o["all_checked"]).sum()))


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

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
        progress: bool = True, executor=None, pieces_dir=None, fingerprint: str | None = None) -> list[Row]:
    """Every (schedule, attacker) pair: ``threats`` maps schedule names to :class:`ThreatParams` (padded to one
    length, so that each attacker compiles once), ``attackers`` names to jittable attackers. Episode ``i`` of a
    pair uses the same key for every pair (common random numbers: the same compromises and winds).

    The batches of every pair are the pieces of one job (:mod:`stp_env.execution`, :func:`coobservation_job`):
    ``executor`` runs them (default in this process, in order; a :class:`~stp_env.execution.RayExecutor` on a
    cluster) with the same rows whatever runs them: batch ``b`` of a pair is keyed by ``(seed, b)`` alone.
    ``pieces_dir`` with ``fingerprint`` (a hex digest of what the attackers are, :func:`attackers_digest`): write
    every finished batch there and reuse those an earlier run of the same job wrote (a killed run resumes)."""
    from stp_env import execution

    check_int(n_episodes, "n_episodes", 1)
    check_int(batch, "batch", 1)
    prng_key(seed)  # [0, 2**63 - 1], every seed its own episodes
    executor = execution.check_executor(executor)
    if pieces_dir is not None and fingerprint is None:
        raise ValueError("pieces_dir needs the attackers' fingerprint (attackers_digest) to resume a job safely.")
    n_steps = threat.steps_for(params)
    pairs = tuple((s, a) for a in attackers for s in threats)
    job = coobservation_job(params, threats, attackers, pairs, n_episodes, batch=batch, seed=seed,
                            n_steps=n_steps, t_window=t_window, fingerprint=fingerprint)
    with tqdm(total=len(pairs) * n_episodes, desc="co-observation evaluation", unit="episode",
              disable=not progress) as bar:
        pieces = executor.run(job, out_dir=pieces_dir, progress=bar.update)
    rows = []
    for j, (s_name, a_name) in enumerate(pairs):
        mine = [piece for (k, _), piece in zip(job.arguments, pieces) if k == j]
        rows.append(summarize(s_name, a_name, {k: np.concatenate([p[k] for p in mine]) for k in mine[0]}))
    return rows


@dataclasses.dataclass(frozen=True)
class CoobservationContext:
    """What every batch of a co-observation evaluation shares (:func:`coobservation_job`): the simulator's
    ``EnvParams`` and the schedules' ``ThreatParams`` as host arrays (:func:`stp_env.execution.to_host`), the
    attackers (jittable functions; a worker keeps the first copy it receives, so that each compiles once there),
    the (schedule, attacker) pairs and the run's numbers."""

    token: str
    params: object
    threats: dict
    attackers: dict
    pairs: tuple
    episodes: int
    batch: int
    seed: int
    n_steps: int
    t_window: tuple


def coobservation_job(params, threats: dict, attackers: dict, pairs, n_episodes: int, *, batch: int, seed: int,
                      n_steps: int, t_window, fingerprint: str | None = None):
    """The batches of every (schedule, attacker) pair as a :class:`stp_env.execution.Job`: piece ``(j, b)`` runs
    batch ``b`` of pair ``j`` (:func:`coobservation_piece`). With ``fingerprint`` the job can resume; its folder is
    named by it, the simulator's and schedules' arrays, the numbers and the package's source."""
    from stp_env import execution

    host_params = execution.to_host(params)
    host_threats = {k: execution.to_host(v) for k, v in threats.items()}
    t_window = tuple(float(t) for t in t_window)
    context = CoobservationContext(token=execution.new_token(), params=host_params, threats=host_threats,
                                   attackers=dict(attackers), pairs=tuple(pairs), episodes=n_episodes, batch=batch,
                                   seed=seed, n_steps=n_steps, t_window=t_window)
    n_batches = -(-n_episodes // batch)
    arguments = tuple((j, b) for j in range(len(pairs)) for b in range(n_batches))
    if fingerprint is not None:
        from stp_env.evaluation.report import source_hash
        from stp_env.sim import engine

        shares = engine.shares(batch)  # another count is another program (left out at one: older runs resume)
        fingerprint = execution.digest("coobservation", fingerprint, [list(p) for p in pairs], n_episodes, batch,
                                       seed, n_steps, list(t_window), host_params,
                                       [[k, host_threats[k]] for k in sorted(host_threats)], source_hash(),
                                       *([shares] if shares > 1 else []))
    return execution.Job(name="coobservation", function=coobservation_piece, context=context, arguments=arguments,
                         fingerprint=fingerprint,
                         units=tuple(min(batch, n_episodes - b * batch) for _, b in arguments))


def coobservation_piece(context: CoobservationContext, argument) -> dict:
    """Batch ``b`` of pair ``j`` (``argument = (j, b)``): every episode's outcomes
    (:func:`stp_env.coobservation.threat.outcomes`) and entry attempts (keys prefixed ``attempt_``), the batch's
    key ``fold_in(key(seed), b)``."""
    from stp_env import execution

    j, b = (int(a) for a in argument)
    s_name, a_name = context.pairs[j]
    token = context.token
    params = execution.memo(token, "params", lambda: execution.to_device(context.params))
    tp = execution.memo(token, ("threat", s_name), lambda: execution.to_device(context.threats[s_name]))
    attacker = execution.memo(token, ("attacker", a_name), lambda: context.attackers[a_name])
    size = min(context.batch, context.episodes - b * context.batch)
    key = jax.random.fold_in(prng_key(context.seed), b)
    final, _ = threat.rollout(key, params, tp, attacker, context.batch, context.n_steps, context.t_window)
    final = jax.device_get(final)
    o = threat.outcomes(final)
    o.update({f"attempt_{k}": v for k, v in threat.attempts(final, params, tp).items()})
    return {k: np.asarray(v)[:size] for k, v in o.items()}


def attackers_digest(specs) -> str:
    """A hex digest of the attackers named by ``specs`` (the command line's names; a ``learned:<path>`` one by its
    file's bytes), what a resumable job's pieces are named by."""
    import hashlib

    from stp_env.loaders import read_bytes

    h = hashlib.sha256()
    for spec in specs:
        h.update(spec.encode() + b"\0")
        if spec.startswith("learned:"):
            h.update(hashlib.sha256(read_bytes(spec.split(":", 1)[1], "learned-policy")).digest())
    return h.hexdigest()


MARGIN_QUANTILES = {"min": 0.0, "5%": 0.05, "25%": 0.25, "50%": 0.5, "75%": 0.75, "95%": 0.95, "max": 1.0}


def run_searched(params, threats: dict, budget: int, *, seed: int = 0, config=None, progress: bool = True,
                 executor=None):
    """The searched attacker (:mod:`stp_env.coobservation.searched`) against every schedule in ``threats``:
    ``budget`` evaluations of the cross-entropy search each (``config``: a :class:`SearchConfig`, default
    :func:`~stp_env.coobservation.searched.default_config`), the wind keyed by ``seed``. Returns the rows (one per
    schedule, over every evaluated attack) and, per schedule, the search's record: evaluations, the best margin,
    the best attack ``z`` and what it means (replay: ``SearchedAttack(params, threat, wind_seed).episode(z)``).
    ``executor`` runs each search's restarts (:mod:`stp_env.execution`)."""
    from stp_env.coobservation import searched

    check_int(budget, "budget", 1)
    config = searched.default_config(budget) if config is None else config
    rows, records = [], {}
    for s_name, tp in threats.items():
        attack = searched.SearchedAttack(params, tp, wind_seed=seed)
        with tqdm(total=config.budget, desc=f"searched attacker, {s_name}", unit="attack",
                  disable=not progress) as bar:
            out = searched.run(attack, config, seed=seed, progress=bar, executor=executor)
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

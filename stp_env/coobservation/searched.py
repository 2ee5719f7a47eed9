"""A searched attacker of a co-observation schedule: the cross-entropy search of :mod:`stp_env.falsify.search`
chooses the attack that maximises its time margin to the observation that would detect it.

The scripted attackers (:mod:`stp_env.coobservation.attackers`) only go when their detour fits inside the
reachability inequality ``|x - q1| + |x - q2| <= v (t2 - t1)`` (Def. 3, grown by the observation radius), so against
a schedule whose ellipses miss the forbidden zones (Section II-F) they never try. This attacker tries whatever the
inequality says: a point ``z`` of ``[0, 1]^5`` (:data:`DIM`) is one attack, flown in the simulator (the threat of
:mod:`stp_env.coobservation.threat`):

====== ===========================================================================================================
z[0]   the compromised vehicle (``floor(z N)``); it is compromised at ``t = 0``, so every choice below is its own
z[1]   its departure time from the plan, ``z T`` (``T`` the flight's duration): any observation gap, any time in it,
       whether or not the round trip fits (negative slack)
z[2]   the entry point it flies to (``floor(z B)`` of :attr:`ThreatParams.entry_points`, ordered along the zones'
       boundaries)
z[3]   where it returns after the entry: the point toward it at ``z r`` from its own slot within every observer's
       disk of its next observation (``r`` the observation radius; 0: its slot, 1: the disks' edge, where the
       ellipse's worst case returns)
z[4]   its outbound speed, ``(0.5 + 0.5 z) v_max``
====== ===========================================================================================================

After the entry it flies to that return point (slowing down on arrival and waiting there), and after the first
observation that follows the entry back to its plan, as :func:`~stp_env.coobservation.attackers.optimistic` does.

The objective (:meth:`SearchedAttack.objective`) is the attack's time margin
(:func:`stp_env.coobservation.threat.attempt_margin`: seconds to spare at its closest observation since it left
the plan; >= 0 exactly when no observation of it was missed, so an entry with a margin >= 0 is an undetected
entry); an attack that got in but lost a vehicle of an observation pair scores :data:`LOST_MARGIN`, and one that
never got in scores ``-ENTRY_PENALTY`` minus its closest approach to a zone over the fastest ground speed, so that
the search first finds entries, then widens their margin. The wind of every evaluated attack is the same draw
(``wind_seed``): the objective is a deterministic function of ``z`` and every attack replays exactly.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.coobservation import threat as threat_lib
from stp_env.coobservation.attackers import after_entry, next_observation, observer_disks, steer
from stp_env.falsify import search as search_lib
from stp_env.policies import nominal_tracking
from stp_env.sim import engine
from stp_env.sim.bounds import V_MAX, WIND
from stp_env.sim.types import EnvParams

DIM = 5
ENTRY_PENALTY = 1000.0  # [s] below every margin of an attack that got in
LOST_MARGIN = -500.0    # [s] the objective of an entry that lost a vehicle of an observation pair (a collision)


@dataclasses.dataclass(frozen=True)
class Decision:
    """An attack ``z`` in physical terms (see the module docstring)."""

    vehicle: int
    departure: float   # [s]
    entry: int         # index into ThreatParams.entry_points
    entry_point: tuple[float, float]  # [m]
    return_radius: float  # [m]
    speed: float       # [m/s]


@dataclasses.dataclass(frozen=True)
class SearchedAttack:
    """The searched attacker against one schedule (``threat``) in the environment ``base`` (the scenario's
    ``EnvParams``); ``wind_seed`` keys the episode's random draws (the wind), the same for every ``z``."""

    base: EnvParams
    threat: threat_lib.ThreatParams
    wind_seed: int = 0
    name: str = "searched"
    n_steps: int = dataclasses.field(init=False, default=0)

    def __post_init__(self):
        object.__setattr__(self, "n_steps", threat_lib.steps_for(self.base))

    def _decode(self, z):
        z = jnp.clip(jnp.asarray(z, jnp.float32), 0.0, 1.0)
        n = self.base.vehicles.n
        b_count = self.threat.entry_points.shape[0]
        bounds = self.base.vehicles.bounds
        c = jnp.minimum(jnp.floor(z[0] * n), n - 1).astype(jnp.int32)
        t_dep = z[1] * (self.base.episode.t_end - self.base.episode.t_start) + self.base.episode.t_start
        k = jnp.minimum(jnp.floor(z[2] * b_count), b_count - 1).astype(jnp.int32)
        return c, t_dep, k, z[3] * self.threat.radius, (0.5 + 0.5 * z[4]) * bounds[V_MAX]

    def decision(self, z) -> Decision:
        """What ``z`` means (for reports and replays)."""
        c, t_dep, k, r, v = (np.asarray(a).item() for a in self._decode(z))
        return Decision(vehicle=int(c), departure=float(t_dep), entry=int(k),
                        entry_point=tuple(float(a) for a in np.asarray(self.threat.entry_points[k])),
                        return_radius=float(r), speed=float(v))

    def policy(self, z):
        """The attacker of ``z``: a jittable ``policy(key, state, params, threat, planned) -> (2,)``."""
        _, t_dep, k, return_radius, v_out = self._decode(z)

        def act(key, state, params, threat, planned):
            del key, planned
            c = jnp.maximum(state.compromised, 0)
            x, t = state.sim.x[c], state.sim.t
            b = params.vehicles.bounds
            t_next, own = next_observation(state, params, threat, c, t)
            centres, due = observer_disks(params, threat, c, t_next)
            to_zone = steer(x, threat.entry_points[k], v_out, b)
            before = jnp.where(t >= t_dep - 1e-6, to_zone, threat_lib.FLY_PLAN)
            return jnp.where(state.entered[c],
                             after_entry(state, params, threat, c, own, centres, due, return_radius), before)

        return act

    def episode(self, z) -> threat_lib.ThreatState:
        """The final :class:`~stp_env.coobservation.threat.ThreatState` of the attack ``z`` (one episode)."""
        params, tp = self.base, self.threat
        c = self._decode(z)[0]
        attacker = self.policy(z)
        k_reset, k_run = jax.random.split(jax.random.key(self.wind_seed))
        ts0 = threat_lib.reset(k_reset, params, tp, c, params.episode.t_start)

        def body(ts, k):
            k_v, k_a, k_s = jax.random.split(k, 3)
            a_v = nominal_tracking(k_v, ts.sim, params)
            a_att = attacker(k_a, ts, params, tp, a_v[c])
            return threat_lib.step(k_s, ts, a_v, a_att, params, tp), None

        final, _ = engine.play(body, ts0, jax.random.split(k_run, self.n_steps),
                               stop=lambda ts: threat_lib.episode_done(ts, params))
        return final

    def objective(self, z):
        """The attack's time margin (see the module docstring); larger is worse for the schedule."""
        final = self.episode(z)
        bounds = self.base.vehicles.bounds
        speed = bounds[V_MAX] + bounds[WIND]
        margin = threat_lib.attempt_margin(final, self.threat, speed, self.base.episode.dt)
        c = jnp.maximum(final.compromised, 0)
        reach = -ENTRY_PENALTY - jnp.maximum(final.closest_zone, 0.0) / speed
        got_in = jnp.where(jnp.isneginf(margin), LOST_MARGIN, jnp.minimum(margin, ENTRY_PENALTY - 1.0))
        return jnp.where(final.entered[c], got_in, reach)


@dataclasses.dataclass(frozen=True)
class SearchOutcome:
    """A search against one schedule: the :class:`~stp_env.falsify.search.SearchResult` and the final states of
    every evaluated attack (batched, on the host), in the order of ``result.samples``."""

    result: search_lib.SearchResult
    finals: threat_lib.ThreatState
    best: Decision


def default_config(budget: int) -> search_lib.SearchConfig:
    """Two cross-entropy restarts of populations of about ``budget / 20`` (at least 10): about ten iterations."""
    pop = max(10, budget // 20)
    return search_lib.SearchConfig(method="cem", budget=max(budget, 2 * pop), population=pop, restarts=2,
                                   batch=2 * pop)


def finals_of(attack: SearchedAttack, zs, batch: int) -> threat_lib.ThreatState:
    """The final states of the attacks ``zs`` ``(M, DIM)``, ``batch`` at a time (one compiled program)."""
    zs = np.asarray(zs, np.float32)
    program = search_lib.compiled(attack.episode)
    out = []
    for i in range(0, zs.shape[0], batch):
        chunk = zs[i:i + batch]
        pad = batch - chunk.shape[0]
        if pad:
            chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, axis=0)])
        final = program(jnp.asarray(chunk))
        out.append(jax.tree.map(lambda a, m=batch - pad: a[:m], final))
    return jax.device_get(jax.tree.map(lambda *a: jnp.concatenate(a), *out))


def run(attack: SearchedAttack, config: search_lib.SearchConfig, seed: int = 0, progress=None,
        executor=None) -> SearchOutcome:
    """Search ``attack`` with the cross-entropy method (``config.method`` must be ``"cem"``), then replay every
    evaluated attack for its final state (the attempt counts and margins of the evaluation). ``executor`` runs the
    search's restarts (:mod:`stp_env.execution`; default in this process, the same result on Ray)."""
    if config.method != "cem":
        raise ValueError(f"the searched attacker uses the cross-entropy method; got method {config.method!r}.")
    result = search_lib.search(attack.objective, DIM, jax.random.key(seed), config, progress=progress,
                               executor=executor)
    finals = finals_of(attack, result.samples, config.batch)
    if not math.isfinite(result.best_value):
        raise ArithmeticError("every attack of the search evaluated to NaN or -inf.")
    return SearchOutcome(result=result, finals=finals, best=attack.decision(result.best_z))

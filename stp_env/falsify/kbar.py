"""Attack on the k̄ bound (intruder paper Sections IV-V): against a planned scenario, make one intruder force more
than k̄ vehicles to avoid, or bring it or another vehicle inside ``R_c`` of a guarded vehicle.

The attacker picks when the intruder appears (in the scenario's appearance window), where (on the level
``V^A(0, t_IAT) = avoid_margin + level`` of a chosen flying vehicle, ``level`` in ``[0, max_level]`` metres, along a
chosen bearing and relative heading: the core then checks Assumption 3 against every vehicle and an attack that
breaks it does not count), and how it flies: its controls piecewise constant over ``segment`` seconds
(``intruder="search"``) or a scripted strategy (``"max-k"``, ``"hj"``: the papers' pursuit, re-read every step).
The wind is the environment's model (``"worst"``: the games' worst case at every inner control step). The vehicles
fly ``u*`` (eq. 38) through the core (``vehicles="switching"``), or the buffer game's worst control until forced
(``vehicles="worst"``: the assumption behind ``V^B``, the one under which the bound can be reached); the buffer-game
policies (``vehicles="worst"``, ``intruder="optimal-max-k"``) need ``V^B`` in the params, and an intruder whose
record lists another table needs that one (:func:`attack_tables`; :func:`stp_env.falsify.counterexample.environment`
loads them through :func:`stp_env.requirements.with_required_tables`).

Objective: ``|N^RP|`` plus a tie-breaker in ``[0, 1)`` that grows as the intruder comes closer to the avoid
boundary of a vehicle it never forces (:func:`closeness`: ``1 - min V^A / d^A`` over the episode and over the
vehicles not forced by its end), so that the search climbs toward forcing one more; a vehicle forced later in the
episode does not count (its value reached the avoid margin on the way, which would pin the tie-breaker near 1 for
every attack that forces anyone); ``-1`` for an attack that broke Assumption 3. The bound is k̄ (``|N^RP| > k̄`` is a
violation); the simulator's guarantee violations and closest approach are reported beside it.

``fleet="airborne"`` (the default) simulates only the vehicles that can fly while the attack runs
(:mod:`stp_env.sim.fleet`; the others never leave the ground or their targets, so the attack and its objective are
the same, up to float rounding, at a fraction of the cost); ``"whole"`` simulates every vehicle. The trace then
lists the simulated vehicles only.
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import requirements
from stp_env.falsify import harness
from stp_env.falsify.targets import register
from stp_env.policies.intruders import resolve_intruder
from stp_env.policies.vehicles import VEHICLE_POLICIES
from stp_env.sim import core, engine, fleet
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN
from stp_env.sim.physics import control_to_action, rotate, wrap_angle
from stp_env.sim.reference import nominal_reference
from stp_env.sim.spawn import radius_on_level
from stp_env.sim.types import FLYING, EnvParams, replace

SCRIPTED = ("max-k", "hj", "optimal-max-k")
"""The scripted intruders of the papers' pursuit; any intruder :func:`stp_env.policies.intruders.resolve_intruder`
takes flies here too (a registered name, ``learned:NAME_OR_PATH`` or a plug-in ``package.module:attribute``)."""
FLEETS = ("airborne", "whole")


def closeness(avoid_start, vmin, detection_range):
    """The objective's tie-breaker in ``[0, 0.99]``: ``0.99 (1 - min V^A / d^A)``, the minimum over the vehicles
    never forced (``avoid_start`` infinite at the end) of each one's smallest ``V^A`` over the episode (``vmin``,
    ``(N,)``); 0 when none came within ``d^A``."""
    left = jnp.min(jnp.where(jnp.isfinite(avoid_start), jnp.inf, vmin))
    return 0.99 * (1.0 - jnp.clip(left / detection_range, 0.0, 1.0))
VEHICLES = ("switching", "worst")


def attack_tables(vehicles: str = "switching", intruder: str = "search") -> tuple[str, ...]:
    """The tables the attack's vehicles and intruder read beyond the scenario's (``"buffer"``: ``V^B`` of the
    buffer-game policies; the intruder's by its record, :func:`stp_env.policies.intruders.capabilities`):
    :func:`stp_env.requirements.required_tables`."""
    return requirements.required_tables(vehicles, None if intruder == "search" else intruder)


@register
@dataclasses.dataclass(frozen=True)
class KbarAttack:
    """See the module docstring. ``base``: the planned scenario's environment (its plan, k̄, tables, wind model)."""

    base: EnvParams
    intruder: str = "search"
    segment: float = 0.5
    max_level: float = 20.0
    vehicles: str = "switching"
    fleet: str = "airborne"
    name: str = "kbar"

    def __post_init__(self) -> None:
        if not isinstance(self.intruder, str):
            raise ValueError(f"intruder must be 'search' or an intruder spec; got {self.intruder!r}.")
        if self.intruder != "search":
            try:
                resolve_intruder(self.intruder)
            except ValueError as err:
                raise ValueError(f"intruder must be 'search' or an intruder spec ({err})") from None
        if self.vehicles not in VEHICLES:
            raise ValueError(f"vehicles must be one of {VEHICLES}; got {self.vehicles!r}.")
        if self.fleet not in FLEETS:
            raise ValueError(f"fleet must be one of {FLEETS}; got {self.fleet!r}.")
        missing = requirements.missing_tables(self.base, self.required_tables)
        if missing:
            raise ValueError(f"vehicles={self.vehicles!r} / intruder={self.intruder!r} read tables the params lack: "
                             + "; ".join(f"{name!r} ({requirements.TABLES[name].description})" for name in missing)
                             + " (stp_env.requirements.with_required_tables loads them).")
        harness.check_durations(float(self.base.episode.dt), segment=self.segment)
        if int(self.base.intruder.kbar) < 1:
            raise ValueError("the scenario has no k̄ (plan it intruder-aware) to attack.")
        object.__setattr__(self, "_ids", self._simulated_ids())

    def _simulated_ids(self):
        """The vehicles that can fly from ``t_start`` to the attack's last step (``None``: all of them, or
        ``fleet="whole"``), from the concrete ``base`` at construction."""
        base = self.base
        if self.fleet == "whole" or base.vehicles.ids is not None:
            return None
        last = max(float(base.episode.t_end), float(base.episode.t_start) + self.n_steps * float(base.episode.dt))
        ids = fleet.airborne(base.replace(episode=dict(t_end=jnp.asarray(last, base.episode.t_end.dtype))))
        return None if ids.size in (0, base.vehicles.n) else ids

    @property
    def params(self) -> EnvParams:
        """The simulated environment: ``base``, or its vehicles that can fly while the attack runs. Built from
        ``base`` at every call (the search traces ``base``'s tables, :func:`stp_env.falsify.search.compiled`); the
        vehicles were chosen at construction."""
        ids = self.__dict__["_ids"]
        return self.base if ids is None else fleet.select(self.base, ids)

    @property
    def required_tables(self) -> tuple[str, ...]:
        """The tables this attack's policies read (:func:`attack_tables`)."""
        return attack_tables(self.vehicles, self.intruder)

    @property
    def n_present(self) -> int:
        return round(float(self.base.intruder.t_iat) / float(self.base.episode.dt))

    @property
    def n_steps(self) -> int:
        """Steps from the episode start to the last possible departure of the intruder."""
        # on the host: jnp arithmetic here would be staged into the caller's trace when simulate runs under jit
        base = self.base
        span = (float(np.asarray(base.intruder.appear_window)[1]) + float(base.intruder.t_iat)
                - float(base.episode.t_start))
        return round(span / float(base.episode.dt)) + 2

    def _split(self):
        rep = max(1, round(self.segment / float(self.base.episode.dt)))
        n_seg = math.ceil(self.n_present / rep) if self.intruder == "search" else 0
        return rep, n_seg

    @property
    def dim(self) -> int:
        return 5 + 2 * self._split()[1]

    @property
    def bound(self) -> float:
        return float(self.base.intruder.kbar)

    def margin(self, value: float) -> float:
        """``k̄ - |N^RP|`` of the worst attack (the tie-breaker dropped): negative is a violation."""
        return self.bound - math.floor(value)

    def spawn(self, z5, params: EnvParams):
        """``(t_, intruder state at t_)`` from ``z5``: appearance time, vehicle, bearing, relative heading, level."""
        lo, hi = params.intruder.appear_window[0], params.intruder.appear_window[1]
        dt = params.episode.dt
        k = jnp.floor((lo + z5[0] * (hi - lo) - params.episode.t_start) / dt + 0.5)
        t_app = params.episode.t_start + k * dt
        x_app, _ = nominal_reference(params, t_app)
        v = params.vehicles
        fly = (v.departure <= t_app) & (jnp.hypot(*(x_app[:, :2] - v.targets).T) > v.target_radii)
        # the floor(z * n_fly)-th flying vehicle
        rank = jnp.cumsum(fly) - 1
        pick = jnp.minimum(jnp.floor(z5[1] * jnp.sum(fly)), jnp.sum(fly) - 1)
        j = jnp.argmax(fly & (rank == pick))
        bearing = 2 * jnp.pi * z5[2] - jnp.pi
        rel_heading = 2 * jnp.pi * z5[3] - jnp.pi
        level = params.tables.avoid_margin + 1e-3 + self.max_level * z5[4]
        direction = jnp.stack([jnp.cos(bearing), jnp.sin(bearing)])
        r = radius_on_level(params, direction, rel_heading, level)
        p = x_app[j, :2] + rotate(x_app[j, 2], r * direction)
        return t_app, jnp.stack([p[0], p[1], wrap_angle(x_app[j, 2] + rel_heading)])

    def simulate(self, z, record: bool = False):
        params = self.params
        rep, n_seg = self._split()
        t_app, xi0 = self.spawn(z[:5], params)
        state = core.reset(jax.random.key(0), params)
        state = replace(state, t_appear=t_app, intruder_memory=jnp.concatenate([xi0, jnp.zeros(1)]))
        policy = None if self.intruder == "search" else resolve_intruder(self.intruder)
        if self.intruder == "search":
            b = params.intruder.bounds
            u = harness.segments(z[5:5 + 2 * n_seg], n_seg, rep, (b[V_MIN], -b[OMEGA_MAX]),
                                 (b[V_MAX], b[OMEGA_MAX]))[:self.n_present]
            plan = control_to_action(u[:, 0], u[:, 1], b)
        n = params.vehicles.n
        keys = jax.random.split(jax.random.key(1), self.n_steps)

        def body(carry, key):
            s, vmin = carry                  # vmin: (N,) each vehicle's smallest V^A while flying so far
            if policy is not None:
                a_i = policy(jax.random.fold_in(key, 1), s, params)
            else:
                k = jnp.clip(jnp.round((s.t - s.t_appear) / params.episode.dt).astype(jnp.int32), 0, self.n_present - 1)
                a_i = plan[k]
            actions = jnp.concatenate([jnp.zeros((n, 2), s.x.dtype), a_i[None, :]], axis=0)
            s2, _ = core.step(key, s, actions, params, vehicle_policy=VEHICLE_POLICIES[self.vehicles])
            vmin = jnp.minimum(vmin, jnp.where(s2.status == FLYING, s2.avoid_value, jnp.inf))
            return (s2, vmin), None

        (final, vmin), traj = engine.play(body, (state, jnp.full((n,), jnp.inf, jnp.float32)), keys,
                                          record=(lambda c, info: harness.record_path(c[0], info)) if record else None)
        return final, vmin, traj

    def objective(self, z):
        final, vmin, _ = self.simulate(z)
        forced = jnp.sum(jnp.isfinite(final.avoid_start)).astype(jnp.float32)
        valid = jnp.all(final.assumption_ok)
        return jnp.where(valid, forced + closeness(final.avoid_start, vmin, self.base.tables.detection_range), -1.0)

    def outcome(self, z) -> dict:
        """The simulator's verdict on the attack at ``z``: forced count, guarantee violations, closest approach."""
        from stp_env.falsify.search import compiled

        final, _, _ = compiled(self.simulate, lambda f: f)(jnp.asarray(z, jnp.float32))
        return harness.to_numpy({"forced": jnp.sum(jnp.isfinite(final.avoid_start)),
                                 "guarantee_violations": jnp.sum(final.guarantee_violation),
                                 "min_separation": jnp.min(final.min_separation),
                                 "assumption_ok": jnp.all(final.assumption_ok)})

    def trace(self, z) -> dict:
        final, _, traj = self.simulate(jnp.asarray(z, jnp.float32), record=True)
        x, xi, t = traj
        return harness.to_numpy({"t": t, "vehicles": x, "intruder": xi, "avoid_start": final.avoid_start,
                                 "status": final.status, "forced": jnp.sum(jnp.isfinite(final.avoid_start)),
                                 "t_appear": final.t_appear, "collision_radius": self.base.episode.collision_radius,
                                 "min_separation": jnp.min(final.min_separation)})

    @classmethod
    def tables_for(cls, options: dict) -> tuple[str, ...]:
        """The tables the attack with ``options`` reads, which its environment must carry (:func:`attack_tables`)."""
        return attack_tables(str(options.get("vehicles", "switching")), str(options.get("intruder", "search")))

    def details(self, z) -> dict:
        out = self.outcome(z)
        return {"forced": int(out["forced"]), "guarantee_violations": int(out["guarantee_violations"]),
                "min_separation_m": round(float(out["min_separation"]), 3),
                "assumption_ok": bool(out["assumption_ok"])}

    def draw(self, ax, ax2, z) -> None:
        """Every vehicle's path (red: forced) and the intruder's while present; the closest vehicle's distance."""
        tr = self.trace(z)
        veh, intr, t = tr["vehicles"], tr["intruder"], tr["t"]
        present = (t >= float(tr["t_appear"])) & (t <= float(tr["t_appear"]) + float(self.base.intruder.t_iat))
        for i in range(veh.shape[1]):
            forced = np.isfinite(tr["avoid_start"][i])
            ax.plot(veh[:, i, 0], veh[:, i, 1], color="C3" if forced else "C0", lw=0.8)
        ax.plot(intr[present, 0], intr[present, 1], "k", lw=1.5, label="intruder")
        d = np.min(np.hypot(veh[:, :, 0] - intr[:, None, 0], veh[:, :, 1] - intr[:, None, 1]), axis=1)
        ax2.plot(t[present], d[present], "k", label="closest vehicle to the intruder")
        for s in tr["avoid_start"][np.isfinite(tr["avoid_start"])]:
            ax2.axvline(float(s), color="C3", lw=0.8)
        ax2.axhline(float(tr["collision_radius"]), color="C3", ls="--", label="R_c")
        ax2.set_ylabel("distance [m]")
        ax.set_title(f"|N^RP| = {int(tr['forced'])} (red: forced), k̄ = {int(self.base.intruder.kbar)}")

    def describe(self) -> dict:
        return {"attack": self.name, "intruder": self.intruder, "segment": self.segment,
                "max_level": self.max_level}

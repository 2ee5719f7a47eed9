"""Attack on the avoid region ``V^A`` and the avoidance control ``u^A`` (intruder paper eqs. 13-18): from any state
outside the avoid region, a vehicle that starts avoiding when the core detects it must keep the intruder outside
the danger zone ``R_c`` until the intruder leaves (``t_IAT``).

The attacker picks the intruder's start relative to the vehicle (bearing, relative heading, and the level
``V^A(0, t_IAT) = avoid_margin + level``, ``level`` in ``[0, max_level]`` metres, it starts on: just outside where
the core's Assumption 3 check puts the intruder, ``V^A > avoid_margin``; on the boundary ``V^A = 0`` itself the
game is won with equality and float32 rounding alone decides the last micrometres),
then either the intruder's controls (piecewise constant over ``segment`` seconds) or the game's optimal pursuit
(``intruder="hj"``, the minimising player of eq. 14, re-read every step), and either the winds of both in their
disks (``wind="search"``, piecewise constant over ``wind_segment``) or the avoid game's worst-case winds at every
inner control step (``wind="worst"``). The vehicle flies ``u*`` (eq. 38): its plan (a straight line at the top
planning speed) until the core's avoid-start check fires (eqs. 17-18, at the inner control rate), then ``u^A``
(``vehicle="nominal"``: it only tracks its plan and never avoids, a control case the search must break).
Objective: ``R_c - min distance`` over the intruder's presence, from the simulator's closest approaches over the
inner steps. The bound under attack is 0 (positive: the intruder entered the danger zone).

``start="band"`` attacks from *inside* the check's band instead: the check fires wherever the value crossed the
margin between two inner steps, that is anywhere in ``[margin - control_dt * fall_rate, margin]``, so the guarantee
must hold from every state of that band, at every time since the intruder appeared. The intruder appeared ``tau_0``
seconds ago (searched, on the step grid) and is on the level ``V^A(tau_0) = floor + band_level * (margin - floor)``
(``band_level`` in ``[0, 1]``, searched unless fixed); the vehicle avoids from the start. Its seeds
(:meth:`AvoidanceAttack.seeds`) are the game's own worst starts on the band's floor, found by flying the game's
optimal pursuit and worst wind against ``u^A`` with the simulator's tables
(:func:`stp_env.reach.avoid.certify_zero_level`).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.falsify import harness
from stp_env.falsify.targets import register
from stp_env.policies.intruders import hj_pursuit
from stp_env.policies.vehicles import VEHICLE_POLICIES
from stp_env.sim import core
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN, WIND
from stp_env.sim.physics import control_to_action
from stp_env.sim.spawn import radius_on_level
from stp_env.sim.tables import PERIODIC_PAD
from stp_env.sim.types import EnvParams, replace


@register
@dataclasses.dataclass(frozen=True)
class AvoidanceAttack:
    """See the module docstring. ``base``: the environment whose vehicle, intruder, tables and rates are used."""

    base: EnvParams
    segment: float = 0.5
    intruder: str = "search"
    wind: str = "search"
    wind_segment: float = 0.5
    max_level: float = 10.0
    vehicle: str = "switching"
    start: str = "outside"
    band_level: float | None = None
    name: str = "avoidance"

    def __post_init__(self) -> None:
        if self.intruder not in ("search", "hj"):
            raise ValueError(f"intruder must be 'search' or 'hj'; got {self.intruder!r}.")
        if self.vehicle not in VEHICLE_POLICIES:
            raise ValueError(f"vehicle must be one of {', '.join(VEHICLE_POLICIES)}; got {self.vehicle!r}.")
        if self.wind not in ("search", "worst"):
            raise ValueError(f"wind must be 'search' or 'worst'; got {self.wind!r}.")
        harness.check_durations(float(self.base.episode.dt), segment=self.segment, wind_segment=self.wind_segment)
        if not (math.isfinite(self.max_level) and self.max_level >= 0):
            raise ValueError(f"max_level must be >= 0 [m]; got {self.max_level}.")
        if self.start not in ("outside", "band"):
            raise ValueError(f"start must be 'outside' or 'band'; got {self.start!r}.")
        if self.band_level is not None and not (isinstance(self.band_level, (int, float))
                                                and 0.0 <= self.band_level <= 1.0):
            raise ValueError(f"band_level must be a number in [0, 1] or None; got {self.band_level!r}.")

    @property
    def n_steps(self) -> int:
        return round(float(self.base.intruder.t_iat) / float(self.base.episode.dt))

    def _split(self):
        dt = float(self.base.episode.dt)
        rep, n_seg = harness.split(self.n_steps, dt, self.segment, self.intruder == "search")
        w_rep, n_wind = harness.split(self.n_steps, dt, self.wind_segment, self.wind == "search")
        return rep, n_seg, w_rep, n_wind

    @property
    def n_start(self) -> int:
        """Coordinates of the start: bearing, relative heading, level (and ``tau_0`` for band starts)."""
        return 4 if self.start == "band" else 3

    @property
    def dim(self) -> int:
        _, n_seg, _, n_wind = self._split()
        return self.n_start + 2 * n_seg + 4 * n_wind

    @property
    def band_floor(self) -> float:
        """[m] the lowest avoid value at which the core's check can fire: ``margin - control_dt * fall_rate``."""
        control_dt = float(self.base.episode.dt) / int(self.base.episode.control_substeps)
        return float(self.base.tables.avoid_margin) - control_dt * float(self.base.tables.avoid_fall_rate)

    @property
    def bound(self) -> float:
        return 0.0

    def margin(self, value: float) -> float:
        """``min distance - R_c`` [m]: negative is a capture."""
        return -value

    def _params(self) -> EnvParams:
        return harness.one_vehicle(self.base, self.n_steps + 2,
                                   wind_model="constant" if self.wind == "search" else "worst")

    def tau0(self, zs):
        """The time since the intruder appeared at the attack's start [s] (0 for ``start="outside"``): a whole
        number of steps, at most ``t_IAT`` less two steps (the core's leaving rule counts whole steps)."""
        if self.start != "band":
            return jnp.zeros((), jnp.float32)
        dt = float(self.base.episode.dt)
        n = max(round(float(self.base.intruder.t_iat) / dt) - 2, 0)
        return dt * jnp.round(zs[3] * n)

    def level(self, zs):
        """The start's avoid value [m]."""
        if self.start != "band":
            return self.base.tables.avoid_margin + 1e-3 + self.max_level * zs[2]
        frac = zs[2] if self.band_level is None else jnp.asarray(self.band_level, jnp.float32)
        floor = self.band_floor
        return floor + frac * (self.base.tables.avoid_margin - floor)

    def start_state(self, zs):
        """The intruder's start ``(3,)`` (world frame = the vehicle's frame at ``t = 0``) on ``V^A(tau_0) =``
        :meth:`level`."""
        bearing = 2 * jnp.pi * zs[0] - jnp.pi
        rel_heading = 2 * jnp.pi * zs[1] - jnp.pi
        direction = jnp.stack([jnp.cos(bearing), jnp.sin(bearing)])
        r = radius_on_level(self.base, direction, rel_heading, self.level(zs), self.tau0(zs))
        return jnp.stack([r * direction[0], r * direction[1], rel_heading])

    def seeds(self) -> np.ndarray | None:
        """Band starts: the game's worst starts on the band's floor, ``(1, dim)`` (the other inputs in the middle
        of their box); ``None`` for ``start="outside"``."""
        if self.start != "band":
            return None
        from stp_env.reach.avoid import AvoidGame, certify_zero_level

        base = self.base
        grid = base.tables.avoid_grid
        before, after = PERIODIC_PAD
        values = np.asarray(base.tables.avoid_values)[(slice(None), slice(None), slice(None), slice(before, -after))]
        game = AvoidGame(grid=grid, dynamics=base.tables.avoid_dynamics, t_iat=float(base.intruder.t_iat),
                         collision_radius=float(base.episode.collision_radius))
        control_dt = float(base.episode.dt) / int(base.episode.control_substeps)
        cert = certify_zero_level(game, base.tables.avoid_taus, values, n_taus=10, n_bearings=24, n_headings=24,
                                  n_refine=4, level=self.band_floor, control_dts=(control_dt,),
                                  decision_dt=float(base.episode.dt))
        z = np.full(self.dim, 0.5)
        n = max(round(float(base.intruder.t_iat) / float(base.episode.dt)) - 2, 1)
        z[0] = ((cert["bearing"] + np.pi) / (2 * np.pi)) % 1.0
        z[1] = ((cert["heading"] + np.pi) / (2 * np.pi)) % 1.0
        z[2] = 0.0 if self.band_level is None else self.band_level
        z[3] = min(max(cert["tau0"] / (float(base.episode.dt) * n), 0.0), 1.0)
        return z[None, :]

    def simulate(self, z, record: bool = False):
        rep, n_seg, w_rep, n_wind = self._split()
        params = self._params()
        dt = float(self.base.episode.dt)
        n = self.n_steps + 2
        v_plan = self.base.vehicles.planning_v_max
        controls = jnp.tile(jnp.stack([v_plan, 0.0]).astype(jnp.float32), (n, 1))
        states = harness.reference(jnp.zeros(3), controls, dt)
        params = harness.with_reference(params, states, controls)
        ns = self.n_start
        xi0 = self.start_state(z[:ns])
        state = core.reset(jax.random.key(0), params)
        # The intruder appeared tau_0 before t = 0 (0 unless a band start) at the attacker's start (Assumption 3 as
        # the core checks it, or a state inside the check's band).
        state = replace(state, intruder_x=xi0, intruder_memory=jnp.concatenate([xi0, jnp.zeros(1)]),
                        assumption_ok=jnp.ones((1,), bool), t_appear=-self.tau0(z[:ns]))
        state = core.avoid_start(core.observe_controllers(state, params), params)
        rest = z[ns:]
        actions = policy = None
        if self.intruder == "search":
            b = self.base.intruder.bounds
            u = harness.segments(rest[:2 * n_seg], n_seg, rep, (b[V_MIN], -b[OMEGA_MAX]),
                                 (b[V_MAX], b[OMEGA_MAX]))[:self.n_steps]
            actions = control_to_action(u[:, 0], u[:, 1], b)
            rest = rest[2 * n_seg:]
        else:
            policy = hj_pursuit
        winds = None
        if self.wind == "search":
            wv = harness.disk(rest[:2 * n_wind], self.base.vehicles.bounds[WIND], n_wind, w_rep)[:self.n_steps]
            wi = harness.disk(rest[2 * n_wind:4 * n_wind], self.base.intruder.bounds[WIND], n_wind,
                              w_rep)[:self.n_steps]
            winds = jnp.stack([wv, wi], axis=1)
        final, traj = harness.run(params, state, self.n_steps, vehicle_policy=VEHICLE_POLICIES[self.vehicle],
                                  intruder_actions=actions,
                                  intruder_policy=policy, winds=winds, record=record)
        return final, traj

    def objective(self, z):
        final, _ = self.simulate(z)
        return self.base.episode.collision_radius - final.min_separation[0]

    def trace(self, z) -> dict:
        final, traj = self.simulate(jnp.asarray(z, jnp.float32), record=True)
        x, xi, t = traj
        return harness.to_numpy({"t": t, "vehicle": x[:, 0, :], "intruder": xi,
                                 "min_distance": final.min_separation[0], "avoid_start": final.avoid_start[0],
                                 "collision_radius": self.base.episode.collision_radius})

    def details(self, z) -> dict:
        tr = self.trace(z)
        start = float(tr["avoid_start"])
        return {"min_distance_m": round(float(tr["min_distance"]), 4),
                "avoid_start_s": round(start, 3) if math.isfinite(start) else None}

    def draw(self, ax, ax2, z) -> None:
        """The vehicle's and the intruder's paths; their distance over time against ``R_c``."""
        tr = self.trace(z)
        veh, intr = tr["vehicle"], tr["intruder"]
        ax.plot(veh[:, 0], veh[:, 1], "C0", label="vehicle (u*)")
        ax.plot(intr[:, 0], intr[:, 1], "C3", label="intruder")
        ax.plot(intr[0, 0], intr[0, 1], "C3o", ms=4)
        ax2.plot(tr["t"], np.hypot(*(veh[:, :2] - intr[:, :2]).T), "C0", label="vehicle-intruder distance")
        ax2.axhline(float(tr["collision_radius"]), color="C3", ls="--", label="R_c")
        if np.isfinite(tr["avoid_start"]):
            ax2.axvline(float(tr["avoid_start"]), color="k", lw=0.8, label="avoid start")
        ax2.set_ylabel("distance [m]")

    def describe(self) -> dict:
        return {"attack": self.name, "segment": self.segment, "intruder": self.intruder, "wind": self.wind,
                "wind_segment": self.wind_segment, "max_level": self.max_level, "vehicle": self.vehicle,
                "start": self.start, "band_level": self.band_level}

"""Attack on the robust-tracking bound ``r_e`` (SPP eqs. 24-26): a legal reference and the wind against the tracker.

The attacker picks the reference's controls in the planning set ``U^p`` (piecewise constant over ``segment``
seconds) and either the wind in the disk of radius ``d_r`` (piecewise constant over ``wind_segment`` seconds) or the
tracking game's own worst-case wind, re-evaluated at every inner control step (``wind="worst"``). The vehicle starts
on its reference (zero error) and flies ``u^PP`` (the tracker ``kappa``, run by the core at the inner control rate).
Objective: the largest distance to the reference over ``horizon`` seconds, as measured by the simulator
(``EnvState.max_tracking_error``). The bound under attack is the ``r_e`` the planner and the simulator use.

The search starts from the game's own worst strategy (:meth:`TrackingAttack.seeds`): the reference control that
the tracking value's gradient says grows the error most (and, with ``wind="search"``, the worst wind), chosen in
feedback on the simulator's own closed loop at the start of every ``segment`` and written as the open-loop plan the
attack searches over; the cross-entropy search then looks around it. Replaying that plan reproduces the feedback
run exactly (the core is deterministic).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.falsify import harness
from stp_env.falsify.targets import register
from stp_env.kinematics import dubins_step, relative_state, rotate
from stp_env.policies.vehicles import nominal_tracking
from stp_env.sim import core, engine, tables
from stp_env.sim.bounds import WIND
from stp_env.sim.types import EnvParams, replace

WIND_MODES = ("search", "worst")


@register
@dataclasses.dataclass(frozen=True)
class TrackingAttack:
    """See the module docstring. ``base``: the environment whose vehicle, tables, step and inner rate are used."""

    base: EnvParams
    horizon: float = 30.0
    segment: float = 1.0
    wind: str = "search"
    wind_segment: float = 0.5
    name: str = "tracking"

    def __post_init__(self) -> None:
        if self.wind not in WIND_MODES:
            raise ValueError(f"wind must be one of {WIND_MODES}; got {self.wind!r}.")
        harness.check_durations(float(self.base.episode.dt), horizon=self.horizon, segment=self.segment,
                                wind_segment=self.wind_segment)

    # -- sizes
    @property
    def n_steps(self) -> int:
        return round(self.horizon / float(self.base.episode.dt))

    def _split(self):
        dt = float(self.base.episode.dt)
        rep, n_seg = harness.split(self.n_steps, dt, self.segment, True)
        w_rep, n_wind = harness.split(self.n_steps, dt, self.wind_segment, self.wind == "search")
        return rep, n_seg, w_rep, n_wind

    @property
    def dim(self) -> int:
        _, n_seg, _, n_wind = self._split()
        return 2 * n_seg + 2 * n_wind

    @property
    def bound(self) -> float:
        """``r_e`` [m]."""
        return float(self.base.tables.tracking_bound)

    def margin(self, value: float) -> float:
        """``r_e - worst error`` [m]: negative is a violation."""
        return self.bound - value

    # -- the simulation
    def _params(self) -> EnvParams:
        params = harness.one_vehicle(self.base, self.n_steps + 2,
                                     wind_model="constant" if self.wind == "search" else "worst")
        # No intruder: it would appear only after the horizon.
        far = jnp.full((2,), 1.0e9, jnp.float32)
        return params.replace(intruder=dict(appear_window=far))

    def simulate(self, z, record: bool = False):
        rep, n_seg, w_rep, n_wind = self._split()
        dyn = self.base.tables.tracking_dynamics
        lo = (dyn.other_v_min, -dyn.other_omega_max)
        hi = (dyn.other_v_max, dyn.other_omega_max)
        n = self.n_steps + 2
        controls = harness.segments(z[:2 * n_seg], n_seg, rep, lo, hi)
        controls = jnp.concatenate([controls, jnp.repeat(controls[-1:], n, axis=0)])[:n]
        states = harness.reference(jnp.zeros(3), controls, float(self.base.episode.dt))
        params = harness.with_reference(self._params(), states, controls)
        winds = None
        if self.wind == "search":
            w = harness.disk(z[2 * n_seg:], self.base.vehicles.bounds[WIND], n_wind, w_rep)[:self.n_steps]
            winds = jnp.stack([w, jnp.zeros_like(w)], axis=1)  # (steps, 2, 2): the vehicle, no intruder
        state = core.reset(jax.random.key(0), params)
        final, traj = harness.run(params, state, self.n_steps, vehicle_policy=nominal_tracking, winds=winds,
                                  record=record)
        return final, traj, states

    def seeds(self) -> np.ndarray:
        """The game's worst reference (and worst wind, when searched) from zero error as a point of the search box,
        ``(1, dim)`` (module docstring).

        The reference is chosen in feedback on the simulator's own closed loop: at the start of each ``segment`` the
        reference control is the disturbance player's optimal control (the first two components of
        ``optimal_disturbance``) of the tracking value's gradient at the core's current error, the plan sample
        after it is written, and the core steps on (the tracker and, with ``wind="worst"``, the wind model are the
        core's). Replaying a lean closed loop's reference open loop is not the same: at 11 m/s the game has
        switching surfaces where millimetres of difference between two integrations send the error elsewhere (the
        lean loop reached 35.8 m where its replay in the core reached 30.0 m)."""
        rep, n_seg, w_rep, n_wind = self._split()
        base = self.base
        dt = float(base.episode.dt)
        grid, dyn = base.tables.tracking_grid, base.tables.tracking_dynamics
        lo_b, hi_b = jnp.asarray(grid.lo, jnp.float32), jnp.asarray(grid.hi, jnp.float32)
        lo = jnp.asarray([dyn.other_v_min, -dyn.other_omega_max], jnp.float32)
        hi = jnp.asarray([dyn.other_v_max, dyn.other_omega_max], jnp.float32)
        n = self.n_steps + 2
        radius = base.vehicles.bounds[WIND]
        searched_wind = self.wind == "search"
        params0 = harness.with_reference(self._params(), jnp.zeros((n, 3), jnp.float32),
                                         jnp.zeros((n, 2), jnp.float32))

        def game(x_ref, x_own):
            """The game's reference control and the vehicle's worst wind (world frame) at the core's error."""
            x_rel = relative_state(x_own, x_ref)
            p = tables.interpolate_components(grid, base.tables.tracking_table, jnp.clip(x_rel, lo_b, hi_b))
            d = dyn.optimal_disturbance(tuple(x_rel[i] for i in range(3)), tuple(p[i] for i in range(3)))
            u = jnp.clip(jnp.stack([d[0], d[1]]), lo, hi)
            if dyn.wind > 0:  # the combined wind pushes the reference; the vehicle's own wind is its opposite
                w = -rotate(x_own[2], jnp.stack([d[2], d[3]]))
            else:
                w = jnp.zeros(2, jnp.float32)
            return u, w

        @jax.jit
        def fly():
            def body(carry, x):
                k, key = x
                s, states, controls, u_prev, w_prev = carry
                u, w = game(states[k], s.x[0])
                u = jnp.where(k % rep == 0, u, u_prev)
                w = jnp.where(k % w_rep == 0, w, w_prev)
                controls = controls.at[k].set(u)
                states = states.at[k + 1].set(dubins_step(states[k], u[0], u[1], jnp.zeros(2, jnp.float32), dt))
                params = harness.with_reference(params0, states, controls)
                if searched_wind:
                    s = replace(s, wind=jnp.stack([w, jnp.zeros_like(w)]))
                actions = jnp.zeros((2, 2), s.x.dtype)
                s, _ = core.step(key, s, actions, params, vehicle_policy=nominal_tracking)  # harness.run's keys
                return (s, states, controls, u, w), (u, w)

            state = core.reset(jax.random.key(0), params0)
            zeros2 = jnp.zeros(2, jnp.float32)
            init = (state, params0.vehicles.nominal_states[0], params0.vehicles.nominal_controls[0], zeros2, zeros2)
            keys = jax.random.split(jax.random.key(0), self.n_steps)
            _, (us, ws) = engine.play(body, init, (jnp.arange(self.n_steps), keys), record=lambda c, info: info)
            return us, ws

        us, ws = (np.asarray(a, np.float64) for a in fly())
        lo_n, hi_n = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
        u = us[::rep][:n_seg]
        z_ref = np.clip((u - lo_n) / np.where(hi_n > lo_n, hi_n - lo_n, 1.0), 0.0, 1.0).reshape(-1)
        parts = [z_ref]
        if searched_wind:
            w = ws[::w_rep][:n_wind]
            r = max(float(radius), 1e-12)
            ang = (np.arctan2(w[:, 1], w[:, 0]) / (2 * np.pi)) % 1.0
            mag = np.clip(np.hypot(w[:, 0], w[:, 1]) / r, 0.0, 1.0)
            parts.append(np.stack([ang, mag], axis=1).reshape(-1))
        return np.concatenate(parts)[None, :]

    def objective(self, z):
        final, _, _ = self.simulate(z)
        return final.max_tracking_error[0]

    def trace(self, z) -> dict:
        """Trajectories of the attack at ``z`` for plots: the vehicle's and the reference's positions."""
        final, traj, states = self.simulate(jnp.asarray(z, jnp.float32), record=True)
        x, _, t = traj
        return harness.to_numpy({"t": t, "vehicle": x[:, 0, :], "reference": states[:self.n_steps + 1],
                                 "worst": final.max_tracking_error[0]})

    def details(self, z) -> dict:
        return {"max_error_m": round(float(self.trace(z)["worst"]), 4)}

    def draw(self, ax, ax2, z) -> None:
        """The reference and the vehicle's path; the distance between them over time against ``r_e``."""
        tr = self.trace(z)
        ref, veh = tr["reference"], tr["vehicle"]
        ax.plot(ref[:, 0], ref[:, 1], "k--", lw=1, label="reference (legal, U^p)")
        ax.plot(veh[:, 0], veh[:, 1], "C0", lw=1.2, label="vehicle (u^PP)")
        k = np.clip(np.round(np.asarray(tr["t"]) / float(self.base.episode.dt)).astype(int), 0, len(ref) - 1)
        err = np.hypot(*(veh[:, :2] - ref[k, :2]).T)  # the plan is sampled at the step
        ax2.plot(tr["t"], err, "C0", label="distance to reference")
        ax2.axhline(self.bound, color="C3", ls="--", label=f"r_e = {self.bound:.2f} m")
        ax2.set_ylabel("error [m]")

    def describe(self) -> dict:
        return {"attack": self.name, "horizon": self.horizon, "segment": self.segment, "wind": self.wind,
                "wind_segment": self.wind_segment}

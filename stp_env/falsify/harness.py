"""Building blocks shared by the attacks: small environments cut from a scenario's, legal references, inputs
decoded from the unit box, and the simulator's own step on the episode engine (:mod:`stp_env.sim.engine`).

Every attack runs the simulation core itself (:func:`stp_env.sim.core.step`: the inner control loop, the
papers' controllers, the events), so that what is attacked is what the environment and the evaluation run.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import hj
from stp_env.sim import core, engine
from stp_env.sim.physics import dubins_step
from stp_env.sim.types import EnvParams, EnvState, replace

FAR_DOMAIN = 1.0e6  # [m] half-size of the domain of the one-vehicle environments (no walls to hit)


def one_vehicle(base: EnvParams, n_samples: int, *, wind_model: str | None = None) -> EnvParams:
    """A one-vehicle environment with the tables, bounds, step and inner rate of ``base``, no buildings, an
    unbounded domain and a placeholder plan of ``n_samples`` samples (the attack writes the plan).

    The intruder appears at ``t = 0`` (the attacks that need no intruder never let it near: see
    :func:`without_intruder`)."""
    f32 = jnp.float32
    sdf_grid = hj.Grid.from_bounds((-FAR_DOMAIN, -FAR_DOMAIN), (FAR_DOMAIN, FAR_DOMAIN), (5, 5))
    return base.replace(
        episode=dict(t_start=jnp.asarray(0.0, f32), t_end=jnp.asarray(1.0e9, f32),
                     domain_lo=jnp.full((2,), -FAR_DOMAIN, f32), domain_hi=jnp.full((2,), FAR_DOMAIN, f32)),
        vehicles=dict(n=1, departure=jnp.zeros((1,), f32), sta=jnp.full((1,), 1.0e9, f32),
                      nominal_arrival=jnp.full((1,), 1.0e9, f32), starts=jnp.zeros((1, 3), f32),
                      targets=jnp.full((1, 2), FAR_DOMAIN, f32), target_radii=jnp.ones((1,), f32),
                      nominal_t0=jnp.zeros((1,), f32), nominal_dt=base.episode.dt,
                      nominal_states=jnp.zeros((1, n_samples, 3), f32),
                      nominal_controls=jnp.zeros((1, n_samples, 2), f32),
                      nominal_len=jnp.full((1,), n_samples, jnp.int32), certified=jnp.ones((1,), bool)),
        tables=dict(sdf=jnp.full((5, 5), 1.0e6, f32), sdf_grid=sdf_grid),
        intruder=dict(appear_window=jnp.zeros((2,), f32), spawn_boundary_probability=jnp.asarray(0.0, f32),
                      kbar=jnp.asarray(1, jnp.int32)),
        wind=dict(model=base.wind.model if wind_model is None else wind_model),
    )


def reference(x0, controls, dt):
    """States of the exact Dubins motion from ``x0`` (3,) under ``controls`` ``(K, 2)`` held for ``dt`` each, no
    wind: ``(K, 3)`` samples (the state at the start of each hold), a legal plan for the simulator."""

    def body(x, u):
        return dubins_step(x, u[0], u[1], jnp.zeros(2, x.dtype), dt), x

    _, xs = jax.lax.scan(body, jnp.asarray(x0, jnp.float32), controls)
    return xs


def with_reference(params: EnvParams, states, controls) -> EnvParams:
    """``params`` (one vehicle) with the plan ``states`` ``(K, 3)``, ``controls`` ``(K, 2)`` from ``t = 0``."""
    return params.replace(vehicles=dict(nominal_states=states[None], nominal_controls=controls[None],
                                        starts=states[:1]))


def check_durations(dt: float, **durations: float) -> None:
    """``ValueError`` unless every one of ``durations`` (seconds, by name) is finite and at least one step ``dt``.
    ``dt`` is the params' float32 step, so a duration equal to it in float64 (0.1 against 0.10000000149) passes: the
    comparison is relative, to float32 precision."""
    for label, value in durations.items():
        try:
            seconds = math.nan if isinstance(value, (bool, str)) else float(value)
        except (TypeError, ValueError):
            seconds = math.nan
        if not (math.isfinite(seconds) and seconds >= dt * (1.0 - 1e-6)):
            raise ValueError(f"{label} must be at least the step dt = {dt:.6g} s; got {value!r}.")


def split(n_steps: int, dt: float, segment: float, searched: bool) -> tuple[int, int]:
    """``(steps per segment, number of segments)`` of an input held piecewise constant over ``segment`` seconds for
    ``n_steps`` steps of ``dt`` (no segments when the input is not ``searched``)."""
    rep = max(1, round(segment / dt))
    return rep, (math.ceil(n_steps / rep) if searched else 0)


def segments(z, n_segments: int, repeat: int, lo, hi):
    """``n_segments`` inputs of ``len(lo)`` components decoded from ``z`` (``n_segments * len(lo)``,) in ``[0, 1]``
    to ``[lo, hi]``, each held for ``repeat`` samples: ``(n_segments * repeat, len(lo))``."""
    lo, hi = jnp.asarray(lo, jnp.float32), jnp.asarray(hi, jnp.float32)
    u = lo + jnp.reshape(z, (n_segments, lo.shape[0])) * (hi - lo)
    return jnp.repeat(u, repeat, axis=0)


def disk(z, radius, n: int, repeat: int):
    """``n`` vectors in the disk of ``radius`` from ``z`` ``(2 n,)`` (angle, then magnitude in ``[0, radius]``),
    each held for ``repeat`` samples: ``(n * repeat, 2)``."""
    z = jnp.reshape(z, (n, 2))
    ang = 2 * jnp.pi * z[:, 0]
    r = radius * z[:, 1]
    w = jnp.stack([r * jnp.cos(ang), r * jnp.sin(ang)], axis=-1)
    return jnp.repeat(w, repeat, axis=0)


def run(params: EnvParams, state: EnvState, n_steps: int, *, vehicle_policy, intruder_actions=None,
        intruder_policy=None, winds=None, record: bool = False):
    """``n_steps`` core steps from ``state``. The intruder flies ``intruder_actions`` ``(n_steps, 2)`` (held per
    step) or ``intruder_policy``; ``winds`` ``(n_steps, N + 1, 2)`` [m/s] are the attacker's (held per step; the
    environment must use the ``"constant"`` model, which applies ``state.wind``), or ``None`` for the
    environment's own wind model. Returns the final state and, with ``record``, per-step ``x``, ``intruder_x``
    and ``t``."""
    n = params.vehicles.n
    keys = jax.random.split(jax.random.key(0), n_steps)

    def body(s, k):
        i, key = k
        if intruder_policy is not None:
            a_i = intruder_policy(jax.random.fold_in(key, 1), s, params)
        elif intruder_actions is not None:
            a_i = intruder_actions[i]
        else:
            a_i = jnp.zeros(2, s.x.dtype)
        if winds is not None:
            s = replace(s, wind=winds[i])
        actions = jnp.concatenate([jnp.zeros((n, 2), s.x.dtype), a_i[None, :]], axis=0)
        s2, _ = core.step(key, s, actions, params, vehicle_policy=vehicle_policy)
        return s2, None

    return engine.play(body, state, (jnp.arange(n_steps), keys), record=record_path if record else None)


def record_path(state, _):
    """What the attacks record of each step: ``(vehicle states, intruder state, time)`` after it."""
    return state.x, state.intruder_x, state.t


def to_numpy(tree):
    return jax.tree.map(lambda a: np.asarray(a), tree)

"""Scripted intruders as jittable ``(key, state, params) -> (2,)`` actions in ``[-1, 1]``.

* :func:`hover`: stays where it appeared (``v = v_min``, no turn): a Bezier curve of degree 1 with both control
  points at the spawn point (mission-survivability paper, Section III-B).
* :func:`bezier_intruder`: a random Bezier curve of degree ``k`` over ``[t_, t_ + t_IAT]`` from the spawn point
  (the other ``k`` control points uniform within ``v_I,max t_IAT / 2`` of it, drawn from the episode's intruder
  key), followed by steering at the next point of the curve.
* :func:`random_intruder`: uniform random actions every step.
* :func:`greedy_pursuit`: full speed at the nearest flying vehicle.
* :func:`hj_pursuit`: the minimising player of the avoid game (eq. 14) against the most threatened flying vehicle
  (the smallest ``V^A``): optimal pursuit from the value table.
* :func:`max_k`: the strategy of the intruder paper's Figs. 6-7: appear on a vehicle's avoid boundary (use
  ``spawn_mode="boundary"``), then go for the avoid boundary of the next vehicle not yet forced (HJ pursuit of the
  unforced vehicle with the smallest ``V^A``), to force as many vehicles as possible.
* :func:`optimal_max_k`: the same strategy played optimally for the hops *between* vehicles: from the vehicle it
  has just forced it takes the time-optimal route to the next vehicle's avoid region, the minimising player of the
  buffer game ``V^B`` (eqs. 46-47: the game the buffer region is built from; the heading of steepest descent of
  ``V^B`` at full speed, see :func:`_hop_to`), choosing as next vehicle the unforced
  one with the smallest ``V^B`` (the one it can force soonest). Where ``V^B > 0`` it flies straight at that vehicle
  (the nearest unforced one outside the table). Needs the buffer table (:func:`stp_env.assembly.with_buffer`).
  :func:`ordered_max_k` plays a fixed vehicle order instead (to check by brute force over orders that the greedy
  choice forces the most).
"""

from __future__ import annotations

import functools
import importlib
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import catalog
from stp_env.policies.record import Intruder
from stp_env.sim import tables
from stp_env.sim.bounds import OMEGA_MAX, V_MAX, V_MIN
from stp_env.sim.physics import control_to_action, relative_state, wrap_angle
from stp_env.sim.types import FLYING

HEADING_GAIN = 3.0  # [1/s]


def _steer(state, params, point, speed=None):
    """Action turning the intruder toward ``point`` at ``speed`` (default ``v_max``)."""
    xi = state.intruder_x
    b = params.intruder.bounds
    d = point - xi[:2]
    err = wrap_angle(jnp.arctan2(d[1], d[0]) - xi[2])
    omega = jnp.clip(HEADING_GAIN * err, -b[OMEGA_MAX], b[OMEGA_MAX])
    v = b[V_MAX] if speed is None else speed
    return control_to_action(v, omega, b)


def hover(key, state, params):
    del key, state
    b = params.intruder.bounds
    return control_to_action(b[V_MIN], 0.0, b)


def random_intruder(key, state, params):
    del state, params
    return jax.random.uniform(key, (2,), minval=-1.0, maxval=1.0)


def bezier_intruder(degree: int):
    """A random-Bezier intruder of ``degree >= 1`` (degree 1: :func:`hover`)."""
    if isinstance(degree, bool) or not isinstance(degree, int) or degree < 1:
        raise ValueError(f"degree must be an integer >= 1; got {degree!r}.")
    if degree == 1:
        return hover
    # numpy constants: a JAX array made here, at import, would start JAX's backend and fix its settings too early
    binom = np.asarray([math.comb(degree, i) for i in range(degree + 1)], np.float32)
    powers = np.arange(degree + 1, dtype=np.float32)

    def policy(key, state, params):
        del key
        b = params.intruder.bounds
        reach = 0.5 * b[V_MAX] * params.intruder.t_iat
        u = jax.random.uniform(state.intruder_key, (degree, 2))
        r = reach * jnp.sqrt(u[:, 0])
        a = 2 * jnp.pi * u[:, 1]
        p0 = state.intruder_memory[:2]
        pts = jnp.concatenate([p0[None], p0 + jnp.stack([r * jnp.cos(a), r * jnp.sin(a)], 1)], 0)
        s = jnp.clip((state.t - state.t_appear + params.episode.dt) / params.intruder.t_iat, 0.0, 1.0)
        basis = binom * s ** powers * (1 - s) ** (degree - powers)
        target = basis @ pts
        dist = jnp.linalg.norm(target - state.intruder_x[:2])
        speed = jnp.clip(dist / params.episode.dt, b[V_MIN], b[V_MAX])
        return _steer(state, params, target, speed)

    policy.__name__ = f"bezier{degree}"
    return policy


def greedy_pursuit(key, state, params):
    del key
    fly = state.status == FLYING
    d = jnp.where(fly, jnp.hypot(*(state.x[:, :2] - state.intruder_x[None, :2]).T), jnp.inf)
    j = jnp.argmin(d)
    return jnp.where(jnp.any(fly), _steer(state, params, state.x[j, :2]), hover(None, state, params))


def _pursue(state, params, eligible):
    """HJ-optimal pursuit (eq. 14's minimiser) of the eligible vehicle with the smallest ``V^A``."""
    tau = state.t - state.t_appear
    rel = relative_state(params.vehicles.model.pose(state.x), state.intruder_x[None, :])
    vals = jnp.where(eligible, state.avoid_value, jnp.inf)  # V^A per vehicle, kept by the core
    j = jnp.argmin(vals)
    d = tables.pursuit_input(params, tau, rel[j])
    hj_action = control_to_action(d[0], d[1], params.intruder.bounds)
    # Outside the table (V = FAR), the gradient is zero: close in greedily instead.
    return jnp.where(vals[j] < tables.FAR, hj_action, _steer(state, params, state.x[j, :2])), jnp.any(eligible)


def hj_pursuit(key, state, params):
    del key
    a, ok = _pursue(state, params, state.status == FLYING)
    return jnp.where(ok, a, hover(None, state, params))


def _force_next(state, params, hop):
    """``hop`` toward the next unforced flying vehicle; when all are forced, HJ pursuit of any; else hover."""
    fly = state.status == FLYING
    unforced = fly & ~jnp.isfinite(state.avoid_start)
    a_next, ok_next = hop(state, params, unforced)
    a_any, ok_any = _pursue(state, params, fly)
    return jnp.where(ok_next, a_next, jnp.where(ok_any, a_any, hover(None, state, params)))


def max_k(key, state, params):
    del key
    return _force_next(state, params, _pursue)


def _buffer_hop(state, params, eligible):
    """The buffer game's minimising intruder action toward vehicle ``j`` (the eligible one with the smallest
    ``V^B``; the nearest when none is within the table) and whether any vehicle is eligible."""
    rel = relative_state(state.x, state.intruder_x[None, :])
    vb = jnp.where(eligible, jax.vmap(lambda r: tables.buffer_value(params, r))(rel), jnp.inf)
    dist = jnp.where(eligible, jnp.hypot(*(state.x[:, :2] - state.intruder_x[None, :2]).T), jnp.inf)
    in_table = vb < tables.FAR
    j = jnp.where(jnp.any(in_table), jnp.argmin(vb), jnp.argmin(dist))
    return _hop_to(state, params, j, rel), jnp.any(eligible)


def _hop_to(state, params, j, rel):
    """The intruder's time-optimal move toward vehicle ``j``'s avoid region: the heading of steepest descent of
    ``V^B`` (``-grad_p V^B``, the minimiser of the game's position term, turned into the world frame) at full speed,
    steered to with the proportional law of :func:`_steer`. The game's own turn rate is bang-bang; held over a
    decision step (0.1 s) it zig-zags across the optimal heading by ``omega_max dt``, which costs the hop time the
    buffer region is built on. Where ``V^B > 0`` (no direction in the table): straight at the vehicle."""
    heading, inside = tables.buffer_hop(params, rel[j], state.x[j, 2])
    point = state.intruder_x[:2] + 100.0 * jnp.stack([jnp.cos(heading), jnp.sin(heading)])
    return jnp.where(inside, _steer(state, params, point), _steer(state, params, state.x[j, :2]))


def optimal_max_k(key, state, params):
    del key
    return _force_next(state, params, _buffer_hop)


def _simulated_rows(params, fleet_indices):
    """The simulated rows of the fleet's vehicles ``fleet_indices`` and whether each is simulated (part of a fleet,
    :mod:`stp_env.sim.fleet`; every index is its own row otherwise)."""
    if params.vehicles.ids is None:
        return jnp.minimum(fleet_indices, params.vehicles.n - 1), fleet_indices < params.vehicles.n
    ids = jnp.asarray(params.vehicles.ids, jnp.int32)
    rows = jnp.minimum(jnp.searchsorted(ids, fleet_indices), params.vehicles.n - 1)
    return rows, ids[rows] == fleet_indices


def ordered_max_k(order):
    """:func:`optimal_max_k` with a fixed order: the next vehicle is the first of ``order`` (vehicle indices in the
    fleet; an index beyond it is never next) that flies and is not yet forced."""
    order = tuple(int(i) for i in order)
    if not order or len(set(order)) != len(order) or min(order) < 0:
        raise ValueError(f"order must list distinct vehicle indices >= 0; got {order!r}.")
    idx = jnp.asarray(order, jnp.int32)

    def policy(key, state, params):
        fly = state.status == FLYING
        unforced = fly & ~jnp.isfinite(state.avoid_start)
        rows, listed = _simulated_rows(params, idx)
        ok = unforced[rows] & listed
        j = rows[jnp.argmax(ok)]
        rel = relative_state(state.x, state.intruder_x[None, :])
        return jnp.where(jnp.any(ok), _hop_to(state, params, j, rel), optimal_max_k(key, state, params))

    policy.__name__ = "ordered_max_k(" + ",".join(map(str, order)) + ")"
    return policy


INTRUDERS = {
    "hover": Intruder(hover, description="stays where it appeared (v_min, no turn)"),
    "random": Intruder(random_intruder, description="uniform random actions every step"),
    "bezier2": Intruder(bezier_intruder(2), description="a random Bezier curve of degree 2 from its spawn"),
    "bezier3": Intruder(bezier_intruder(3), description="a random Bezier curve of degree 3 from its spawn"),
    "greedy": Intruder(greedy_pursuit, description="full speed at the nearest flying vehicle"),
    "hj": Intruder(hj_pursuit, description="optimal pursuit of the most threatened vehicle (the avoid game)"),
    "max-k": Intruder(max_k, spawn="boundary",
                      description="the papers' Figs. 6-7: from a vehicle's avoid boundary, on to the next unforced "
                                  "vehicle's"),
    "optimal-max-k": Intruder(optimal_max_k, tables=("buffer",), spawn="boundary",
                              description="max-k with the buffer game's time-optimal hops (reads V^B)"),
}
"""The scripted intruders by name, each an :class:`Intruder` (its policy and capabilities). A plug-in intruder
needs no entry (``package.module:attribute``, :func:`resolve_intruder`); :func:`register_intruder` lists one by
name in this process; an installed plug-in joins by the entry-point group ``stp_env.intruders``
(:mod:`stp_env.catalog`)."""

BUFFER_GAME_INTRUDERS = frozenset(name for name, entry in INTRUDERS.items() if "buffer" in entry.tables)
"""The registered intruders that read the buffer table, as names (a view of the ``tables`` of :data:`INTRUDERS`'
records; :func:`capabilities` answers for any intruder, plug-ins included)."""

LEARNED_PREFIX = "learned:"


def register_intruder(name: str, intruder: Intruder) -> Intruder:
    """List ``intruder`` under ``name`` in :data:`INTRUDERS` (for this process); a name is registered once."""
    if not isinstance(name, str) or not name or ":" in name or name.startswith(LEARNED_PREFIX[:-1]):
        raise ValueError(f"an intruder name is a non-empty string without ':' (not 'learned'); got {name!r}.")
    if not isinstance(intruder, Intruder):
        raise ValueError(f"register an Intruder record (its policy and capabilities); got {type(intruder).__name__}.")
    if name in INTRUDERS and INTRUDERS[name] is not intruder:
        raise ValueError(f"an intruder named {name!r} is already registered.")
    INTRUDERS[name] = intruder
    return intruder


def intruder_policy(name: str):
    """A scripted intruder by name: one of :data:`INTRUDERS`."""
    if name not in INTRUDERS:
        raise ValueError(f"unknown intruder {name!r}; allowed: {', '.join(INTRUDERS)}.")
    return INTRUDERS[name]


def is_plugin(spec: str) -> bool:
    """Whether ``spec`` names code to import (``package.module:attribute``), not a registered or learned intruder."""
    return isinstance(spec, str) and ":" in spec and not spec.startswith(LEARNED_PREFIX)


def resolve_intruder(spec: str, *, allow_plugins: bool = True) -> Callable:
    """An intruder policy from a name or an import spec.

    * a scripted intruder: one of :data:`INTRUDERS` (its :class:`Intruder` record);
    * ``"learned:NAME_OR_PATH"``: a learned intruder, :func:`stp_env.policies.learned.load_intruder` (a shipped
      name or an ``.npz`` exported by :func:`stp_env.policies.learned.export_mlp`);
    * ``"package.module:attribute"``: a jittable policy ``(key, state, params) -> (2,)``, or an :class:`Intruder`
      record of one, defined in an importable module (how a learned intruder exported to JAX is evaluated);
    * ``"package.module:factory=ARGUMENT"``: ``factory(ARGUMENT)`` must return such a policy (e.g. a loader
      taking a checkpoint path).

    The policy is a static argument of the compiled rollout: the same object must be passed for every batch, or
    each batch would compile again; a plug-in spec is therefore resolved once per process (a factory is called
    once).

    An import spec runs code (it imports the module and may call the factory): it is for specs the user typed
    (the command line) or wrote (their own code), never for names read from a file. ``allow_plugins=False``
    refuses them (how saved events and counterexamples are replayed).
    """
    if not isinstance(spec, str) or not spec:
        raise ValueError(f"an intruder is a non-empty name or spec string; got {spec!r}.")
    if spec in INTRUDERS:
        return INTRUDERS[spec]
    if spec.startswith(LEARNED_PREFIX):
        from stp_env.policies.learned import load_intruder

        return load_intruder(spec[len(LEARNED_PREFIX):])
    if ":" not in spec and allow_plugins and spec in catalog.plugins("intruders"):
        return _entry_point(spec)
    if ":" not in spec:
        raise ValueError(f"unknown intruder {spec!r}; allowed: {', '.join(catalog.names('intruders', INTRUDERS))}, "
                         "'learned:NAME_OR_PATH' "
                         "(stp_env.policies.learned.load_intruder), or 'package.module:policy' / "
                         "'package.module:factory=ARGUMENT' for any jittable intruder policy.")
    if not allow_plugins:
        raise ValueError(f"intruder {spec!r} is a plug-in spec (code to import), which is not accepted here; "
                         f"allowed: {', '.join(INTRUDERS)} or 'learned:NAME_OR_PATH'.")
    return _plugin(spec)


@functools.cache
def _entry_point(name: str):
    """The intruder an installed distribution declares as ``name`` (entry-point group ``stp_env.intruders``)."""
    policy = catalog.load_plugin("intruders", name)
    if not callable(policy):
        raise ValueError(f"intruder plug-in {name!r} is not callable; expected a policy (key, state, params) -> (2,) "
                         "or its record.")
    return policy


@functools.cache
def _plugin(spec: str):
    module_name, _, attribute = spec.partition(":")
    attribute, has_argument, argument = attribute.partition("=")
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ValueError(f"intruder {spec!r}: cannot import {module_name!r} ({err}).") from None
    if not hasattr(module, attribute):
        raise ValueError(f"intruder {spec!r}: module {module_name!r} has no attribute {attribute!r}.")
    policy = getattr(module, attribute)
    if has_argument:
        policy = policy(argument)
    if not callable(policy):
        raise ValueError(f"intruder {spec!r} is not callable; expected a policy (key, state, params) -> (2,).")
    return policy


def capabilities(intruder) -> Intruder:
    """What running ``intruder`` takes, as an :class:`Intruder` record: of a spec (:func:`resolve_intruder`), of a
    record, or of a bare policy (a function says nothing: it reads no table beyond the scenario's, spawns
    outside)."""
    if isinstance(intruder, str):
        intruder = resolve_intruder(intruder)
    return intruder if isinstance(intruder, Intruder) else Intruder(intruder)


def mixture(names):
    """One intruder policy that plays ``names[i]`` in an episode, ``i`` drawn uniformly from the episode's
    intruder key (:func:`mixture_index`): many intruder types in one compiled rollout. Under ``vmap`` every
    branch is evaluated (``lax.switch`` becomes a select), so a mixture costs the sum of its members."""
    names = tuple(names)
    policies = [intruder_policy(name) for name in names]

    def policy(key, state, params):
        i = mixture_index(state, len(policies))
        return jax.lax.switch(i, policies, key, state, params)

    policy.__name__ = "mixture(" + ",".join(names) + ")"
    return policy


def mixture_index(state, n: int):
    """Which member of a :func:`mixture` of ``n`` intruders plays in the episode of ``state``."""
    return jax.random.randint(jax.random.fold_in(state.intruder_key, 7), (), 0, n)

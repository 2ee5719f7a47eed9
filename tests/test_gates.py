"""The batch gates of the simulator (:mod:`stp_env.sim.gates`): work skipped when no episode of a batch needs it
gives the same episodes, bit for bit, as doing it, and an episode's outcome does not depend on its batch."""

from __future__ import annotations

import functools
import unittest.mock

import jax
import jax.numpy as jnp
import numpy as np

from stp_env import assembly, sim
from stp_env.baselines import INTRUDERS, switching
from stp_env.planning.stp import shipped_plan_for
from stp_env.sim import gates
from stp_env.sim.rollout import episode_step
from stp_env.sim.types import AVOIDING, GONE, PENDING, PRESENT, replace


def test_batch_any_reduces_over_every_vmapped_axis():
    def f(x, p):
        return gates.when_any(p, lambda x: jnp.sin(x) * jnp.where(p, 1.0, 0.0), lambda x: jnp.zeros_like(x), x)

    x = jnp.arange(6.0).reshape(2, 3)
    p = jnp.asarray([[False, True, False], [False, False, False]])
    out = jax.vmap(jax.vmap(f))(x, p)
    np.testing.assert_allclose(np.asarray(out), np.where(np.asarray(p), np.sin(np.asarray(x)), 0.0), rtol=1e-6)
    # one branch for the whole batch: the predicate was reduced over both axes, not turned into a select
    conds = [e for e in jax.make_jaxpr(jax.vmap(jax.vmap(f)))(x, p).eqns if e.primitive.name == "cond"]
    assert len(conds) == 1 and conds[0].invars[0].aval.shape == ()
    assert not bool(jax.vmap(jax.vmap(gates.batch_any))(jnp.zeros((2, 3), bool)).any())
    assert bool(gates.batch_any(jnp.asarray(True)))
    # differentiable through the branch taken
    g = jax.grad(lambda x: jnp.sum(jax.vmap(f)(x, p[0])))(x[0])
    np.testing.assert_allclose(np.asarray(g), [0.0, np.cos(1.0), 0.0], rtol=1e-6)


@functools.lru_cache(maxsize=1)
def _params():
    plan = shipped_plan_for("town", 2)
    lo, _ = assembly.busiest_window(plan)
    first = min(v.plan.t_ldt for v in plan.vehicles)
    return assembly.params_for("town", sim.EnvConfig(appear_window=(lo - first, lo - first + 10.0)), progress=False)


def _batch(params):
    """Three episodes in the states the gates must tell apart: the intruder not yet there; present 120 m ahead of
    a flying vehicle that is already avoiding it (its ``u^A`` is applied); present far from every vehicle."""
    states = jax.vmap(lambda k: sim.reset(k, params))(jax.random.split(jax.random.key(5), 3))
    flying = np.asarray(states.status[1]) == sim.FLYING
    i = int(np.flatnonzero(flying)[0])
    x = np.asarray(states.x[1, i])
    ahead = np.asarray([x[0] + 120.0 * np.cos(x[2]), x[1] + 120.0 * np.sin(x[2]), x[2] + np.pi], np.float32)
    far = np.asarray([x[0] + 5_000.0, x[1] + 5_000.0, 0.0], np.float32)
    status = jnp.asarray([PENDING, PRESENT, PRESENT], jnp.int32)
    mode = states.mode.at[1, i].set(AVOIDING)
    avoid_start = states.avoid_start.at[1, i].set(states.t[1])
    t_appear = jnp.where(status == PRESENT, states.t - 1.0, states.t_appear)
    return replace(states, intruder_status=status, intruder_x=jnp.asarray([np.zeros(3, np.float32), ahead, far]),
                   t_appear=t_appear, mode=mode, avoid_start=avoid_start), i


def _steps(params, states, keys, n_steps: int):
    @jax.jit
    def run(states, keys):
        def body(s, k):
            s, r = jax.vmap(lambda k, s: episode_step(k, s, params, switching, INTRUDERS["hj"]))(k, s)
            return s, (s, r)
        return jax.lax.scan(body, states, keys)[1]
    def host(a):
        return np.asarray(jax.random.key_data(a) if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key) else a)
    return jax.tree.map(host, run(states, keys))


def _assert_same(a, b):
    for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(x, y, err_msg=jax.tree_util.keystr(path))


def test_gated_steps_are_the_ungated_steps_in_every_episode():
    params = _params()
    states, i = _batch(params)
    keys = jax.random.split(jax.random.key(9), (4, 3))
    gated = _steps(params, states, keys, 4)
    with unittest.mock.patch.object(gates, "when_any", lambda pred, compute, skip, *ops: compute(*ops)):
        full = _steps(params, states, keys, 4)
    _assert_same(gated, full)
    s = gated[0]
    # the states did what the gates must tell apart: vehicle i avoided the near intruder with u^A, the far one gave
    # FAR, and the pending intruder left every value FAR and every avoidance action zero
    assert (s.mode[:, 1, i] == AVOIDING).all() and (np.abs(s.avoid_action[:, 1, i]) > 0).any()
    assert (s.avoid_value[:, 0] == 1.0e6).all() and (s.avoid_action[:, 0] == 0.0).all()
    assert (s.avoid_value[:, 2] == 1.0e6).all()
    # each episode alone (its batch needs no read, or only its own) is the same episode as in the batch
    for j in range(3):
        alone = _steps(params, jax.tree.map(lambda a, j=j: a[j:j + 1], states), keys[:, j:j + 1], 4)
        _assert_same(jax.tree.map(lambda a, j=j: a[:, j:j + 1], gated), alone)
    # a batch in which no intruder is present skips every read and every intruder decision, and still matches
    quiet = replace(states, intruder_status=jnp.asarray([PENDING, GONE, PENDING], jnp.int32))
    gated = _steps(params, quiet, keys, 4)
    with unittest.mock.patch.object(gates, "when_any", lambda pred, compute, skip, *ops: compute(*ops)):
        full = _steps(params, quiet, keys, 4)
    _assert_same(gated, full)


def test_the_evaluator_batches_episodes_by_their_intruders_appearance():
    from stp_env.evaluation.runner import batch_indices, episode_order
    from stp_env.seeds import prng_key

    params = _params()
    order = episode_order(3, 40, params)
    assert sorted(order.tolist()) == list(range(40))
    keys = jax.vmap(lambda i: jax.random.split(jax.random.fold_in(jax.random.fold_in(prng_key(3), i), 0))[0])(
        jnp.arange(40))
    t_appear = np.asarray(jax.vmap(lambda k: sim.reset(k, params).t_appear)(keys))
    assert np.all(np.diff(t_appear[order]) >= 0) and np.ptp(t_appear) > 1.0
    np.testing.assert_array_equal(batch_indices(order, 32, 16), np.concatenate([order[32:], np.arange(40, 48)]))


def test_boundary_spawns_are_computed_only_when_an_episode_of_the_batch_spawns_on_a_boundary():
    """The intruder's boundary candidates (a bisection of table reads each) are gated: in a batch mixing boundary
    and outside spawns, and in one with outside spawns only, every episode's spawn is the ungated one, and the same
    as the episode's spawn alone."""
    from stp_env.sim import spawn as spawn_mod

    params = _params()
    states = jax.vmap(lambda k: sim.reset(k, params))(jax.random.split(jax.random.key(5), 8))
    fly = states.status == sim.FLYING
    assert bool(fly.any())
    keys = jax.random.split(jax.random.key(11), 8)

    def with_probability(probability):
        return replace(params, intruder=replace(params.intruder, spawn_boundary_probability=jnp.float32(probability)))

    def batched(k, x, f, p):
        return jax.vmap(lambda k, x, f: spawn_mod.spawn(k, x, f, p))(k, x, f)

    gated_run = jax.jit(batched)
    with unittest.mock.patch.object(gates, "when_any", lambda pred, compute, skip, *ops: compute(*ops)):
        full_run = jax.jit(batched).lower(keys, states.x, fly, with_probability(0.5)).compile()
    out = {}
    for probability in (0.5, 0.0):
        p = with_probability(probability)
        out[probability] = gated = np.asarray(gated_run(keys, states.x, fly, p))
        np.testing.assert_array_equal(gated, np.asarray(full_run(keys, states.x, fly, p)))
        for j in range(8):
            alone = np.asarray(gated_run(keys[j:j + 1], states.x[j:j + 1], fly[j:j + 1], p))[0]
            np.testing.assert_array_equal(alone, gated[j])
    # the mixed batch did spawn some intruders on a boundary: they differ from the outside-only spawns
    assert 0 < int(np.sum(np.any(out[0.5] != out[0.0], axis=1))) < 8

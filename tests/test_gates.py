"""The batch gates of the simulator (:mod:`stp_env.sim.gates`): work skipped when no episode of a batch needs it,
or done only for the elements of the batch that need it, gives the same episodes, bit for bit, as doing all of it,
and an episode's outcome does not depend on its batch."""

from __future__ import annotations

import contextlib
import functools
import unittest.mock

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import assembly, sim
from stp_env.planning.stp import shipped_plan_for
from stp_env.policies import INTRUDERS, switching
from stp_env.sim import core, gates, status
from stp_env.sim.physics import relative_state
from stp_env.sim.rollout import episode_step
from stp_env.sim.types import AVOIDING, FLYING, GONE, PENDING, PRESENT, WAITING, replace


def _every_element(pred, fn, fill, elements, shared=()):
    """What :func:`gates.where_needed` must equal: ``fn`` of every element, masked (the computation written out)."""
    lead = pred.shape
    flat = jax.tree.map(lambda a: a.reshape((-1, *a.shape[len(lead):])), elements)
    out = jax.tree.map(lambda o: o.reshape(lead + o.shape[1:]), jax.vmap(fn, in_axes=(0, None))(flat, shared))
    return jax.tree.map(lambda o, f: jnp.where(pred.reshape(lead + (1,) * (o.ndim - len(lead))), o, f), out, fill)


def _ungated(criterion: bool = True):
    """Patches under which every gate computes everything (the reference of the gated steps); with ``criterion``
    also every flying vehicle's avoid read while its intruder is present (not only those in the table's box or
    avoiding)."""
    patches = [unittest.mock.patch.object(gates, "when_any", lambda pred, compute, skip, *ops: compute(*ops)),
               unittest.mock.patch.object(gates, "where_needed", _every_element)]
    if criterion:
        patches.append(unittest.mock.patch.object(
            core, "avoid_read_needed",
            lambda params, state, rel: status.flying(state) & status.intruder_present(state)))
    return _all(patches)


@contextlib.contextmanager
def _all(patches):
    with contextlib.ExitStack() as stack:
        for p in patches:
            stack.enter_context(p)
        yield


def _elementwise(e, s):
    x, y = e
    return {"a": jnp.sin(x) * s["c"] + y[0] * y[1], "b": y * s["d"]}


_FILL = {"a": np.float32(7.0), "b": np.zeros(2, np.float32)}


def _nested(fn):
    """``fn(pred, x, y, c, d)`` of one vehicle ``vmap``-ed over vehicles, then over episodes (``c`` per episode)."""
    return jax.jit(jax.vmap(jax.vmap(fn, (0, 0, 0, None, None)), (0, 0, 0, 0, None)))


def _branches(fn, *args):
    eqns = jax.make_jaxpr(fn)(*args).eqns
    found = []
    while eqns:
        e = eqns.pop()
        if e.primitive.name == "cond":
            found.append(len(e.params["branches"]))
        for v in e.params.values():
            for j in (v if isinstance(v, (list, tuple)) else [v]):
                inner = getattr(j, "jaxpr", None)
                if inner is not None:
                    eqns.extend(getattr(inner, "eqns", []) or getattr(getattr(inner, "jaxpr", None), "eqns", []))
    return found


@pytest.mark.slow
def test_where_needed_computes_only_the_needed_elements_of_the_whole_batch_and_equals_computing_every_one():
    rng = np.random.default_rng(0)
    d = np.float32(2.0)

    def where(p, x, y, c, d):
        return gates.where_needed(p, _elementwise, _FILL, (x, y), {"c": c, "d": d})

    def every(p, x, y, c, d):
        return _every_element(p, _elementwise, _FILL, (x, y), {"c": c, "d": d})

    for b, counts, n_branches in ((300, (0, 1, 700, 1024, 1025, 2400), 3), (1125, (5, 1024, 2250, 2251, 9000), 4)):
        x = jnp.asarray(rng.normal(size=(b, 8)), jnp.float32)
        y = jnp.asarray(rng.normal(size=(b, 8, 2)), jnp.float32)
        c = jnp.asarray(rng.normal(size=(b,)), jnp.float32)
        gathered, reference = _nested(where), _nested(every)
        # one branch over the whole batch: none, each gathered size (at least MIN_GATHER), every element
        assert _branches(gathered, jnp.zeros((b, 8), bool), x, y, c, d) == [n_branches]
        for count in counts:  # the tiers' edges: exactly a gathered size, one more
            p = np.zeros(b * 8, bool)
            p[rng.choice(b * 8, count, replace=False)] = True
            p = jnp.asarray(p.reshape(b, 8))
            got, want = gathered(p, x, y, c, d), reference(p, x, y, c, d)
            for k in want:
                np.testing.assert_array_equal(np.asarray(got[k]), np.asarray(want[k]), err_msg=f"{k} at {count}")
    # one episode (no enclosing vmap; too few to gather): a branch between none and every element
    p1 = jnp.asarray([False, True, False, True, False, False, False, False])
    one = jax.jit(jax.vmap(where, (0, 0, 0, None, None)))(p1, x[0], y[0], c[0], d)
    np.testing.assert_array_equal(np.asarray(one["a"]), np.asarray(jax.jit(jax.vmap(every, (0, 0, 0, None, None)))(
        p1, x[0], y[0], c[0], d)["a"]))
    # derivatives: those of every element computed and masked, with or without an enclosing vmap around the grad
    p = p.at[0].set(True)

    def loss(f):
        return lambda x, c: jnp.sum(jax.vmap(jax.vmap(f, (0, 0, 0, None, None)), (0, 0, 0, 0, None))(
            p, x, y, c, d)["a"])

    for got, want in zip(jax.grad(loss(where), (0, 1))(x, c), jax.grad(loss(every), (0, 1))(x, c)):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))
    per_episode = jax.vmap(jax.grad(lambda x, c, p, y: jnp.sum(jax.vmap(where, (0, 0, 0, None, None))(
        p, x, y, c, d)["a"]), (0, 1)))(x, c, p, y)
    for got, want in zip(per_episode, jax.grad(loss(every), (0, 1))(x, c)):
        np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-6)


@pytest.mark.slow
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
    a flying vehicle that is already avoiding it (its ``u^A`` is applied), with three more vehicles flying at the
    edge of the avoid table's box around it (1 cm inside, 1 cm outside, and 5 m outside but avoiding: a read that
    must happen, one that can be skipped, one that must happen although its value is ``FAR``); present far from
    every vehicle. Returns the states, the avoiding vehicle and the three at the edge."""
    states = jax.vmap(lambda k: sim.reset(k, params))(jax.random.split(jax.random.key(5), 3))
    flying = np.asarray(states.status[1]) == sim.FLYING
    i = int(np.flatnonzero(flying)[0])
    x = np.asarray(states.x[1, i])
    ahead = np.asarray([x[0] + 120.0 * np.cos(x[2]), x[1] + 120.0 * np.sin(x[2]), x[2] + np.pi], np.float32)
    far = np.asarray([x[0] + 5_000.0, x[1] + 5_000.0, 0.0], np.float32)
    status = jnp.asarray([PENDING, PRESENT, PRESENT], jnp.int32)
    edge = [j for j in range(states.x.shape[1]) if j != i][:3]
    hi = float(params.tables.avoid_grid.hi[0])
    pose = np.asarray(states.x).copy()
    for j, offset in zip(edge, (hi - 0.01, hi + 0.01, hi + 5.0)):  # heading 0: the intruder at +offset along x
        pose[1, j] = [ahead[0] - offset, ahead[1], 0.0]
    vehicle_status = states.status.at[1, np.asarray(edge)].set(FLYING)
    mode = states.mode.at[1, i].set(AVOIDING).at[1, edge[2]].set(AVOIDING)
    avoid_start = states.avoid_start.at[1, i].set(states.t[1]).at[1, edge[2]].set(states.t[1])
    t_appear = jnp.where(status == PRESENT, states.t - 1.0, states.t_appear)
    return replace(states, x=jnp.asarray(pose), status=vehicle_status, intruder_status=status,
                   intruder_x=jnp.asarray([np.zeros(3, np.float32), ahead, far]), t_appear=t_appear, mode=mode,
                   avoid_start=avoid_start), i, edge


def _stepper(params):
    """A jitted ``(states, keys) -> (states, rewards)`` per step of ``keys`` ``(steps, B)``, as host arrays."""
    @jax.jit
    def run(states, keys):
        def body(s, k):
            s, r = jax.vmap(lambda k, s: episode_step(k, s, params, switching, INTRUDERS["hj"]))(k, s)
            return s, (s, r)
        return jax.lax.scan(body, states, keys)[1]

    return lambda states, keys: _host(run(states, keys))


def _host(tree):
    """``tree`` as numpy arrays (keys as their data)."""
    return jax.tree.map(lambda a: np.asarray(jax.random.key_data(a) if jax.dtypes.issubdtype(a.dtype,
                                                                                              jax.dtypes.prng_key)
                                             else a), tree)


def _steps(params, states, keys):
    return _stepper(params)(states, keys)


def _needed(params, s):
    """:func:`stp_env.sim.core.avoid_read_needed` of recorded states (numpy, any leading axes)."""
    rel = np.asarray(relative_state(jnp.asarray(s.x), jnp.asarray(s.intruder_x)[..., None, :]))
    box = params.tables.avoid_grid
    inside = np.all((rel[..., :2] >= np.asarray(box.lo[:2])) & (rel[..., :2] <= np.asarray(box.hi[:2])), axis=-1)
    return (s.status == FLYING) & (s.intruder_status == PRESENT)[..., None] & (inside | (s.mode == AVOIDING))


def _assert_same(a, b):
    for (path, x), y in zip(jax.tree_util.tree_leaves_with_path(a), jax.tree.leaves(b)):
        np.testing.assert_array_equal(x, y, err_msg=jax.tree_util.keystr(path))


def _assert_same_episodes(params, gated, full):
    """Every field of the recorded steps the same bit for bit, but ``u^A`` where no read was needed
    (:func:`_needed`): zero in ``gated``, a read that no one applies in ``full``."""
    needed = _needed(params, gated[0])
    np.testing.assert_array_equal(gated[0].avoid_action[needed], full[0].avoid_action[needed])
    assert (gated[0].avoid_action[~needed] == 0.0).all()
    _assert_same(replace(gated[0], avoid_action=None), replace(full[0], avoid_action=None))
    _assert_same(gated[1], full[1])


@pytest.mark.slow
def test_avoid_reads_are_skipped_only_where_they_cannot_matter():
    """At the avoid table's box edge: the vehicle 1 cm inside is read, the one 1 cm outside is not (its ``V^A`` is
    ``FAR`` either way; its unused ``u^A`` zero), the avoiding one outside is read (its ``u^A`` is applied)."""
    params = _params()
    states, i, (inside, outside, avoiding) = _batch(params)
    reads = jax.jit(jax.vmap(lambda s: core.avoid_reads(params, s)))
    value, action = (np.asarray(a) for a in reads(states))
    with _ungated():
        every_value, every_action = (np.asarray(a) for a in jax.jit(jax.vmap(lambda s: core.avoid_reads(params, s)))(
            states))
    np.testing.assert_array_equal(value, every_value)
    assert value[1, inside] < 1.0e6 and value[1, outside] == 1.0e6 and value[1, avoiding] == 1.0e6
    for j in (i, inside, avoiding):
        np.testing.assert_array_equal(action[1, j], every_action[1, j])
        assert np.abs(action[1, j]).max() > 0
    assert (action[1, outside] == 0).all() and np.abs(every_action[1, outside]).max() > 0
    needed = _needed(params, _host(states))
    np.testing.assert_array_equal(action[~needed], 0.0)
    np.testing.assert_array_equal(action[needed], every_action[needed])


@pytest.mark.slow
def test_gated_steps_are_the_ungated_steps_in_every_episode():
    params = _params()
    states, i, _ = _batch(params)
    keys = jax.random.split(jax.random.key(9), (4, 3))
    gated = _steps(params, states, keys)
    with _ungated():
        full = _steps(params, states, keys)
    _assert_same_episodes(params, gated, full)
    assert (full[0].avoid_action[~_needed(params, gated[0])] != 0.0).any()  # the skip did skip reads
    s = gated[0]
    # the states did what the gates must tell apart: vehicle i avoided the near intruder with u^A, the far one gave
    # FAR, and the pending intruder left every value FAR and every avoidance action zero
    assert (s.mode[:, 1, i] == AVOIDING).all() and (np.abs(s.avoid_action[:, 1, i]) > 0).any()
    assert (s.avoid_value[:, 0] == 1.0e6).all() and (s.avoid_action[:, 0] == 0.0).all()
    assert (s.avoid_value[:, 2] == 1.0e6).all()
    # each episode alone (its batch needs no read, or only its own) is the same episode as in the batch
    for j in range(3):
        alone = _steps(params, jax.tree.map(lambda a, j=j: a[j:j + 1], states), keys[:, j:j + 1])
        _assert_same(jax.tree.map(lambda a, j=j: a[:, j:j + 1], gated), alone)
    # a batch in which no intruder is present skips every read and every intruder decision, and still matches
    quiet = replace(states, intruder_status=jnp.asarray([PENDING, GONE, PENDING], jnp.int32))
    gated = _steps(params, quiet, keys)
    with _ungated():
        full = _steps(params, quiet, keys)
    _assert_same_episodes(params, gated, full)


@pytest.mark.slow
def test_an_episode_is_the_same_whichever_gathered_size_its_batch_mates_make_the_reads_take():
    """300 town episodes (2,100 vehicles; reads gathered into 1,024, or all computed): the first 20 episodes, their
    intruders near their vehicles, step the same bit for bit whether the other episodes need no reads, need
    exactly 1,024 or 1,025 at the step's start (the gathered size's edge), or all of theirs."""
    params = _params()
    b, k = 300, 20
    states = jax.vmap(lambda key: sim.reset(key, params))(jax.random.split(jax.random.key(3), b))
    n = states.x.shape[1]
    rng = np.random.default_rng(4)
    intruder = np.stack([rng.uniform(-500, 500, b), rng.uniform(-500, 500, b), rng.uniform(-np.pi, np.pi, b)], -1)
    # every vehicle 60-250 m from its intruder, so that every flying one needs its read
    r, a = rng.uniform(60, 250, (b, n)), rng.uniform(-np.pi, np.pi, (b, n))
    x = np.stack([intruder[:, None, 0] + r * np.cos(a), intruder[:, None, 1] + r * np.sin(a),
                  rng.uniform(-np.pi, np.pi, (b, n))], -1)
    states = replace(states, x=jnp.asarray(x, jnp.float32), intruder_x=jnp.asarray(intruder, jnp.float32),
                     intruder_status=jnp.full((b,), PRESENT, jnp.int32),
                     t_appear=states.t - jnp.asarray(rng.uniform(0.0, 8.0, b), states.t.dtype))
    keys = jax.random.split(jax.random.key(9), (2, b))
    run = _stepper(params)
    probe_flying = np.ones((k, n), bool)
    outs = []
    for mates in (0, 1024 - k * n, 1025 - k * n, (b - k) * n):
        fly = np.zeros((b - k) * n, bool)
        fly[rng.choice((b - k) * n, mates, replace=False)] = True
        status = np.concatenate([probe_flying, fly.reshape(b - k, n)]).astype(bool)
        s = replace(states, status=jnp.asarray(np.where(status, FLYING, WAITING), jnp.int32))
        assert int(_needed(params, _host(s)).sum()) == k * n + mates
        outs.append(jax.tree.map(lambda a: a[:, :k], run(s, keys)))
    for other in outs[1:]:
        _assert_same(outs[0], other)


@pytest.mark.slow
def test_a_rollout_with_gathered_reads_is_the_rollout_with_every_read():
    """200 steps of 300 town episodes (``sim.rollout``), the reads gathered against every vehicle's read computed
    and masked: the same episodes bit for bit (a smaller gathered size than ``gates.MIN_GATHER`` fails here)."""
    params = _params()

    def run():
        final, record = sim.rollout(jax.random.key(0), params, switching, INTRUDERS["hj"], 300, 200, record=True)
        return _host((final, record))

    gathered = run()
    jax.clear_caches()  # the rollout is jitted: traced again under the patch, not found in the cache
    try:
        with unittest.mock.patch.object(gates, "where_needed", _every_element):
            every = run()
    finally:
        jax.clear_caches()
    _assert_same(gathered, every)
    assert (gathered[1]["intruder_status"] == PRESENT).any()


@pytest.mark.slow
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


@pytest.mark.slow
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


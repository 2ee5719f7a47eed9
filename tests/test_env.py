"""The PettingZoo adapter (stp_env.env): PettingZoo's own API tests, determinism, parity with the pure core,
bad inputs, and long runs without recompilation."""

from __future__ import annotations

import functools
import itertools
import resource

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pettingzoo.test import (
    state_test,
)

import stp_env.env as stp_module
from stp_env import sim
from stp_env.env import INFO_CODES, env, parallel_env
from stp_env.sim import packing, stepping
from stp_env.sim.jit import sim_jit
from stp_env.sim.stepping import TRACE_COUNTS
from stp_env.sim.types import replace as sim_replace


def _enable_x64(on: bool):
    """``jax.enable_x64`` (newer JAX) or ``jax.experimental.enable_x64`` (older)."""
    if hasattr(jax, "enable_x64"):
        return jax.enable_x64(on)
    from jax import experimental

    return experimental.enable_x64(on)



@pytest.fixture(scope="module")
def par():
    return parallel_env()


@pytest.mark.slow
def test_the_agents_of_an_episode_are_its_possible_agents_all_present_at_reset():
    """Vehicles that arrived before the episode's first instant are not possible agents (the same for every seed),
    every possible agent is an agent at reset, and a scripted intruder is not an agent."""
    par = parallel_env()
    for seed in (0, 1):
        par.reset(seed=seed)
        done = [f"vehicle_{i}" for i in np.flatnonzero(np.asarray(par._state.status) >= sim.ARRIVED)]
        assert done, "the default episode should start after some vehicle has arrived"
        assert par.agents == par.possible_agents and not set(done) & set(par.possible_agents)
        assert len(par.possible_agents) == par.params.vehicles.n - len(done) + 1
    scripted = parallel_env(intruder="greedy")
    assert scripted.possible_agents == par.possible_agents[:-1] and par.possible_agents[-1] == "intruder"
    with pytest.raises(ValueError, match="unknown agent 'intruder'"):
        scripted.observation_space("intruder")


def _zeros_until_the_end(e, options):
    """Zero actions from ``reset(seed=3, options)`` to the episode's end: every step's agents and outputs."""
    e.reset(seed=3, options=options)
    steps = []
    while e.agents:
        live = list(e.agents)
        out = e.step({a: np.zeros(2, np.float32) for a in live})
        steps.append((live, *out[1:4]))
    return steps


def test_keep_finished_keeps_every_agent_to_the_end_and_the_last_step_truncates_every_agent():
    """``keep_finished=True``: the intruder, done ``t_IAT`` after it appeared, stays an agent (reward 0, not
    terminated) until the episode's last step, where every agent ends together; without it the intruder leaves when
    done. Either way the last step of a truncated episode truncates every agent left, even one that terminates in it
    (the intruder leaving in the very step the episode is cut: RLlib ends an episode only when all its agents are
    terminated or all are truncated)."""
    base = parallel_env(max_cycles=150)
    options = {"appear_time": float(base.params.episode.t_start)}
    removed = _zeros_until_the_end(base, options)
    left = next(k for k, (_, _, terms, _) in enumerate(removed) if terms.get("intruder"))
    assert 0 < left < 149 and "intruder" not in removed[left + 1][0]
    kept = _zeros_until_the_end(parallel_env(max_cycles=150, keep_finished=True), options)
    assert len(kept) == 150 and all(live == base.possible_agents for live, *_ in kept)
    assert not any(any(terms.values()) or any(truncs.values()) for _, _, terms, truncs in kept[:-1])
    assert all(rewards["intruder"] == 0.0 for _, rewards, _, _ in kept[left + 1:])
    _, _, terms, truncs = kept[-1]
    assert terms["intruder"] and all(truncs.values())
    for a in base.possible_agents:  # up to the intruder's exit, the same rewards as without keep_finished
        assert [r[a] for _, r, _, _ in kept[:left + 1]] == [r[a] for _, r, _, _ in removed[:left + 1]]
    cut = _zeros_until_the_end(parallel_env(max_cycles=left + 1), options)  # the intruder leaves in the last step
    _, _, terms, truncs = cut[-1]
    assert len(cut) == left + 1 and terms["intruder"] and all(truncs.values())


def test_state():
    state_test(env(max_cycles=30), parallel_env(max_cycles=30), num_cycles=10)


def _run(e, seed, n_steps, rng_seed=3):
    """Seeded random actions; returns the per-step vehicle states and intruder states."""
    rng = np.random.default_rng(rng_seed)
    e.reset(seed=seed)
    xs, xi = [], []
    for _ in range(n_steps):
        if not e.agents:
            break
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in e.agents}
        e.step(actions)
        xs.append(np.asarray(e.env_state.x))
        xi.append(np.asarray(e.env_state.intruder_x))
    return np.stack(xs), np.stack(xi)


@pytest.mark.slow
def test_same_seed_same_trajectories_for_500_steps():
    one, other = parallel_env(), parallel_env()
    a = _run(one, 11, 500)
    b = _run(other, 11, 500)
    assert a[0].shape[0] == 500
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    c = _run(one, 12, 500)
    assert not np.array_equal(a[1], c[1])  # another seed: another intruder


@pytest.mark.slow
def test_adapter_matches_the_pure_core(par):
    """Same keys and actions through ``sim.reset`` / ``sim.step`` give the adapter's states, to float32 rounding
    (the adapter's step is compiled together with the observations, so XLA may fuse differently: last-bit
    differences, 2.4e-4 m on 2.4 km were seen)."""
    rng = np.random.default_rng(0)
    par.reset(seed=5)
    key = jax.random.key(5)
    key, sub = jax.random.split(key)
    state = sim.reset(sub, par.params)
    n = par.params.vehicles.n
    for _ in range(120):
        acts = rng.uniform(-1, 1, (n + 1, 2)).astype(np.float32)
        rows = {**{f"vehicle_{i}": i for i in range(n)}, "intruder": n}  # an agent's row of the core's arrays
        par.step({a: acts[rows[a]] for a in par.agents})
        key, sub = jax.random.split(key)
        state, _ = sim_jit(sim.step)(sub, state, jnp.asarray(acts), par.params)
        np.testing.assert_allclose(np.asarray(state.x), np.asarray(par.env_state.x), rtol=1e-6, atol=1e-3)
        np.testing.assert_array_equal(np.asarray(state.status), np.asarray(par.env_state.status))
    np.testing.assert_allclose(np.asarray(state.intruder_x), np.asarray(par.env_state.intruder_x), rtol=1e-6,
                               atol=1e-3)


def _snapshot(e):
    return jax.tree.map(lambda a: np.asarray(jax.random.key_data(a)) if jnp.issubdtype(a.dtype, jax.dtypes.prng_key)
                        else np.asarray(a), e.env_state)


def _same(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)))


BAD_VALUES = st.sampled_from([np.nan, np.inf, -np.inf])


@settings(max_examples=25)
@given(bad=BAD_VALUES, which=st.integers(0, 7), component=st.integers(0, 1))
def test_non_finite_actions_are_rejected_and_change_nothing(par, bad, which, component):
    par.reset(seed=1)
    before = _snapshot(par)
    acts = {a: np.zeros(2, np.float32) for a in par.agents}
    agent = par.agents[which % len(par.agents)]
    acts[agent] = acts[agent].copy()
    acts[agent][component] = bad
    with pytest.raises(ValueError, match="not finite"):
        par.step(acts)
    assert _same(before, _snapshot(par))


@settings(max_examples=25)
@given(shape=st.sampled_from([(), (1,), (3,), (2, 2), (1, 2)]))
def test_wrong_shapes_are_rejected(par, shape):
    par.reset(seed=1)
    before = _snapshot(par)
    with pytest.raises(ValueError, match="shape"):
        par.step({"vehicle_0": np.zeros(shape, np.float32)})
    assert _same(before, _snapshot(par))


@pytest.mark.slow
@settings(max_examples=20)
@given(name=st.text(min_size=1, max_size=12).filter(lambda s: s not in {f"vehicle_{i}" for i in range(7)}
                                                   and s != "intruder"))
def test_unknown_agents_are_rejected(par, name):
    par.reset(seed=1)
    with pytest.raises(ValueError, match="unknown agent"):
        par.step({name: np.zeros(2, np.float32)})


def test_finished_agents_and_bad_arguments_are_rejected(par):
    # the intruder appears at once, so that it leaves (t_IAT later) long before the episode ends
    par.reset(seed=2, options={"appear_time": float(par.params.episode.t_start)})
    # run the zero action until some agent is done
    finished = None
    for _ in range(2000):
        par.step({a: np.zeros(2, np.float32) for a in par.agents})
        gone = set(par.possible_agents) - set(par.agents)
        if gone:
            finished = sorted(gone)[0]
            break
    assert finished is not None
    with pytest.raises(ValueError, match="finished"):
        par.step({finished: np.zeros(2, np.float32)})
    with pytest.raises(ValueError, match="render_mode"):
        parallel_env(render_mode="ascii")
    with pytest.raises(ValueError, match="max_cycles"):
        parallel_env(max_cycles=0)
    with pytest.warns(UserWarning, match="unknown reset option"):
        par.reset(options={"appear": 3.0})
    with pytest.raises(ValueError, match="appear_time must be finite"):
        par.reset(options={"appear_time": float("nan")})
    with pytest.raises(ValueError, match="wind_model"):
        sim.EnvConfig(wind_model="hurricane")


def _per_agent(par, actions):
    """The general path of the action check, agent by agent (the reference for the vectorised one)."""
    arr = np.zeros((par.params.vehicles.n + 1, 2), np.float32)
    for agent, a in actions.items():
        checked = par._check_action(agent, a)
        if checked is not None:
            arr[par._index[agent], :checked.shape[0]] = checked
    return arr


@settings(max_examples=40)
@given(values=st.lists(st.floats(-5, 5, width=32), min_size=16, max_size=16),
       dtype=st.sampled_from([np.float16, np.float32, np.float64]), drop=st.sets(st.integers(0, 7)))
def test_the_vectorised_action_check_equals_the_per_agent_one(par, values, dtype, drop):
    par.reset(seed=1)
    acts = {a: np.asarray(values[2 * i:2 * i + 2], dtype) for i, a in enumerate(par.agents) if i not in drop}
    fast = np.zeros((par.params.vehicles.n + 1, 2), np.float32)
    assert par._actions._parse_plain(acts, fast, par.agents)
    np.testing.assert_array_equal(fast, _per_agent(par, acts))


def test_the_vectorised_action_check_equals_the_per_agent_one_for_a_three_input_vehicle_model(par):
    """With a vehicle model of three inputs (the intruder keeps two), the actions are checked per input size and
    give what the per-agent check gives."""
    from stp_env.sim.vehicle_models.dubins import Dubins

    class ThreeInputs(Dubins):
        name = "three-inputs"
        action_dim = 3

    from stp_env.env_checks import ActionChecker

    par.reset(seed=1)
    checker = ActionChecker(par.possible_agents, par._index, par.params.vehicles.n, ThreeInputs.action_dim)
    rng = np.random.default_rng(7)
    acts = {a: rng.uniform(-3, 3, 2 if a == "intruder" else 3).astype(np.float32) for a in par.agents}
    fast = np.zeros((par.params.vehicles.n + 1, 3), np.float32)
    assert checker._parse_plain(acts, fast, par.agents)
    reference = np.zeros_like(fast)
    for agent, a in acts.items():
        reference[par._index[agent], :a.shape[0]] = checker.check(agent, a, par.agents)
    np.testing.assert_array_equal(fast, reference)
    acts["vehicle_0"] = np.zeros(2, np.float32)  # a vehicle's action of the intruder's size: the general path
    assert not checker._parse_plain(acts, np.zeros_like(fast), par.agents)


def _hold_still(key, state, params):
    """A user's own vehicle policy: the zero action for every vehicle."""
    del key
    return jnp.zeros((params.vehicles.n, params.vehicles.model.action_dim), state.x.dtype)


@pytest.mark.slow
def test_a_function_as_vehicle_policy_flies_inside_the_step():
    """``vehicle_policy=`` a function: the same episode, bit for bit, as its actions passed from outside (zero
    actions: held over the step or evaluated at every inner step, they are the same), the safety filter included."""
    # the HJ-pursuit intruder appearing on an avoid boundary forces vehicles: the safety filter acts in both
    par = parallel_env(intruder="hj", spawn_mode="boundary")
    own = parallel_env(vehicle_policy=_hold_still, intruder="hj", spawn_mode="boundary")
    options = {"appear_time": float(par.params.episode.t_start) + 0.5}
    par.reset(seed=6, options=options)
    own.reset(seed=6, options=options)
    rng = np.random.default_rng(3)
    zero = np.zeros(2, np.float32)
    for _ in range(40):
        intruder = rng.uniform(-1, 1, 2).astype(np.float32)
        outside = par.step({a: intruder if a == "intruder" else zero for a in par.agents})
        inside = own.step({a: intruder if a == "intruder" else rng.uniform(-1, 1, 2).astype(np.float32)
                           for a in own.agents})  # the vehicles' actions are ignored
        assert outside[1:4] == inside[1:4]
        for agent in outside[0]:
            np.testing.assert_array_equal(outside[0][agent], inside[0][agent])
        if not par.agents:
            break
    assert np.isfinite(np.asarray(par.env_state.avoid_start)).any()  # a vehicle was forced: the filter flew it
    for a, b in zip(jax.tree.leaves(par.env_state), jax.tree.leaves(own.env_state)):
        np.testing.assert_array_equal(np.asarray(jax.random.key_data(a) if a.dtype == jax.random.key(0).dtype
                                                 else a),
                                      np.asarray(jax.random.key_data(b) if b.dtype == jax.random.key(0).dtype
                                                 else b))


@pytest.mark.parametrize("policy, message", [
    (lambda key, state, params: jnp.zeros(3), r"must return the vehicles' actions.*returned shape \(3,\)"),
    (lambda key, state, params: jnp.zeros((params.vehicles.n, 2), jnp.int32), "dtype int32"),
    (lambda key, state, params: state.no_such_field, "not a jittable function.*no_such_field"),
    (42, "vehicle_policy 42 is not known"),
])
def test_a_bad_vehicle_policy_is_refused_when_the_env_is_made(policy, message):
    with pytest.raises(ValueError, match=message):
        parallel_env(vehicle_policy=policy)


@pytest.mark.parametrize("odd", [[0.5, 0.5], None, np.array([1, 0]), np.array([np.nan, 0.0]),
                                 np.zeros(3, np.float32), np.zeros((1, 2), np.float32)])
def test_anything_but_plain_float_arrays_takes_the_general_path(par, odd):
    par.reset(seed=1)
    acts = {a: np.full(2, 0.25, np.float32) for a in par.agents}
    acts["vehicle_3"] = odd
    untouched = np.full((par.params.vehicles.n + 1, 2), 9.0, np.float32)
    assert not par._actions._parse_plain(acts, untouched, par.agents)
    assert np.all(untouched == 9.0)


def test_out_of_range_actions_are_clipped(par):
    par.reset(seed=4)
    a = _snapshot(par)
    par.step({ag: np.full(2, 7.0, np.float32) for ag in par.agents})
    x_big = np.asarray(par.env_state.x)
    par.reset(seed=4)
    assert _same(a, _snapshot(par))
    par.step({ag: np.ones(2, np.float32) for ag in par.agents})
    np.testing.assert_array_equal(x_big, np.asarray(par.env_state.x))


def test_appear_time_option_and_infos(par):
    t = float(par.params.episode.t_start) + 1.0
    _, infos = par.reset(seed=0, options={"appear_time": t})
    assert set(infos["vehicle_0"]) >= {"avoid_start_time", "forced", "n_forced", "kbar", "collision",
                                       "guarantee_violation", "used_filter", "min_separation", "cost"}
    for _ in range(12):
        _, _, _, _, infos = par.step({a: np.zeros(2, np.float32) for a in par.agents})
    assert infos["intruder"]["status"] == sim.PRESENT
    assert INFO_CODES["intruder_status"][infos["intruder"]["status"]] == "present"
    first = infos["intruder"]
    _, _, _, _, infos2 = par.step({a: np.zeros(2, np.float32) for a in par.agents})
    assert infos2["intruder"] is not first  # fresh dicts every step


@pytest.mark.slow
def test_long_run_without_recompiling_or_growing_memory(par):
    """20,000 adapter steps over many episodes: one trace of the step function and flat memory (the 100,000-step
    run is in benchmarks/env_throughput.py)."""
    par.reset(seed=0)
    par.step({a: np.zeros(2, np.float32) for a in par.agents})
    traces = TRACE_COUNTS["step"]
    zero = np.zeros(2, np.float32)
    rss = []
    steps = 0
    episode = 0
    while steps < 20_000:
        par.reset(seed=episode)
        episode += 1
        while par.agents and steps < 20_000:
            par.step(dict.fromkeys(par.agents, zero))
            steps += 1
            if steps % 5000 == 0:
                rss.append(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)
    assert TRACE_COUNTS["step"] == traces
    assert rss[-1] - rss[0] < 50_000, rss  # KiB: less than 50 MB growth after warm-up


@pytest.mark.slow
def test_packed_step_is_the_unpacked_one_bit_for_bit():
    """The adapter keeps the key and state packed on the device (the carry) and fetches a step's outputs as one
    packed array: unpacked, the next key and state and the outputs are exactly those of the unpacked step, over
    steps in which the intruder pursues and vehicles avoid."""
    # the HJ-pursuit intruder appearing on an avoid boundary forces vehicles
    par = parallel_env(intruder="hj", spawn_mode="boundary")
    par.reset(seed=6, options={"appear_time": float(par.params.episode.t_start) + 0.5})
    n = par.params.vehicles.n
    key, state = par._key, par._state
    carry = packing._pack_jit((key, state))
    layout = packing.Layout.of((key, state))
    scripted = functools.partial(stepping.advance_scripted, intruder_policy=par._intruder_policy)
    direct_step = sim_jit(scripted)
    out_layout = None
    for _ in range(40):  # zero actions, as in the vehicle-policy test above: vehicles are forced
        acts = jnp.zeros((n + 1, 2), jnp.float32)
        if out_layout is None:
            out_layout = packing.Layout.of(jax.eval_shape(scripted, key, state, acts, par.params)[2])
        key, state, direct = direct_step(key, state, acts, par.params)
        carry, words = stepping.advance_carry_jit(carry, acts, par.params, layout=layout,
                                                     intruder_policy=par._intruder_policy)
        unpacked = out_layout.unpack(np.asarray(words))
        for a, b in zip(jax.tree.leaves(jax.device_get(direct)), jax.tree.leaves(unpacked)):
            assert a.dtype == b.dtype and a.shape == b.shape
            np.testing.assert_array_equal(a, b)
        back_key, back_state = packing._unpack_jit(carry, layout=layout)
        np.testing.assert_array_equal(jax.random.key_data(back_key), jax.random.key_data(key))
        for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(back_state)):
            assert a.dtype == b.dtype and a.shape == b.shape
            if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
                a, b = jax.random.key_data(a), jax.random.key_data(b)
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert int(state.intruder_status) != 0 and bool(np.any(np.isfinite(np.asarray(state.avoid_start))))
    with pytest.raises(ValueError, match="packed step output"):
        out_layout.unpack(np.asarray(words)[:-1])
    with pytest.raises(ValueError, match="PRNG keys"):
        layout.unpack(np.asarray(carry))


def test_the_env_state_and_key_follow_the_packed_carry(par):
    """``env_state`` is the carry unpacked, after steps and after a replanning-style state change."""
    par.reset(seed=0)
    before = par.env_state
    par.step({a: np.zeros(2, np.float32) for a in par.agents})
    after = par.env_state
    assert after is par.env_state  # unpacked once per step
    assert float(after.t) > float(before.t)
    key, state = par._key, par._state
    par._carry.set((key, sim_replace(state, t=state.t + 1.0)))
    assert float(par.env_state.t) == float(state.t) + 1.0
    np.testing.assert_array_equal(np.asarray(packing._unpack_jit(par._carry.words, layout=par._carry.layout)[1].t),
                                  np.asarray(state.t) + np.float32(1.0))


def test_a_loop_reading_env_state_gets_it_from_the_step_with_the_same_episode(par):
    """Read between two steps, ``env_state`` comes with the next step's outputs (a second compiled variant of the
    step): the same episode, bit for bit, as a loop that never reads it."""
    other = parallel_env()
    par.reset(seed=11)
    other.reset(seed=11)
    rng = np.random.default_rng(5)
    for i in range(30):
        acts = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in par.agents}
        if i >= 3:
            state = par.env_state  # read: the next step returns the state with its outputs
            assert par._carry.was_read
        got, want = par.step(acts), other.step(acts)
        if i >= 3:
            assert par._carry._tree is not None  # no unpacking call needed for the next read
            assert float(par.env_state.t) > float(state.t)
        assert got[1:4] == want[1:4]
        for agent in got[0]:
            np.testing.assert_array_equal(got[0][agent], want[0][agent])
    assert not other._carry.was_read
    for a, b in zip(jax.tree.leaves(par.env_state), jax.tree.leaves(other.env_state)):
        if jax.dtypes.issubdtype(a.dtype, jax.dtypes.prng_key):
            a, b = jax.random.key_data(a), jax.random.key_data(b)
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.mark.slow
def test_pack_round_trips_every_dtype():
    tree = {"f32": jnp.asarray([1.5, -np.inf, np.nan], jnp.float32), "i32": jnp.asarray([[-7, 2 ** 31 - 1]]),
            "b": jnp.asarray([True, False, True, True, False]), "u8": jnp.asarray([0, 255, 7], jnp.uint8),
            "i16": jnp.asarray([-3, 300, 2 ** 15 - 1], jnp.int16), "b0": jnp.asarray(True), "s": jnp.asarray(3.25)}
    layout = packing.Layout.of(tree)
    words = jax.jit(packing.pack)(tree)
    back, traced = layout.unpack(np.asarray(words)), jax.jit(lambda w: layout.unpack_traced(w))(words)
    for k, v in tree.items():
        for got in (back[k], traced[k]):  # on the host (views of the words) and on the device
            assert got.dtype == np.asarray(v).dtype and got.shape == v.shape
            np.testing.assert_array_equal(got, np.asarray(v))
    with _enable_x64(True):
        wide = {"f64": jnp.asarray([np.pi, -1e300], jnp.float64), "i64": jnp.asarray([-(2 ** 40), 5], jnp.int64)}
        back = packing.Layout.of(wide).unpack(np.asarray(jax.jit(packing.pack)(wide)))
        for k, v in wide.items():
            assert back[k].dtype == np.asarray(v).dtype
            np.testing.assert_array_equal(back[k], np.asarray(v))
        both = {**tree, **wide, "key": jax.random.split(jax.random.key(5), 3)}
        layout = packing.Layout.of(both)
        back = jax.jit(lambda w: layout.unpack_traced(w))(jax.jit(packing.pack)(both))
        for k, v in both.items():
            if k == "key":
                np.testing.assert_array_equal(jax.random.key_data(back[k]), jax.random.key_data(v))
            else:
                assert back[k].dtype == v.dtype
                np.testing.assert_array_equal(np.asarray(back[k]), np.asarray(v))
    with pytest.raises(ValueError, match="abstract PRNG key"):
        packing.Layout.of(jax.eval_shape(lambda: jax.random.key(0)))


def _same_record(info: dict, readable: dict) -> None:
    """An info's episode record (its flat ``stp_episode_*`` numbers) is ``env.episode`` (names, ``None``) in codes."""
    numbers = {k[len("stp_episode_"):]: v for k, v in info.items() if k.startswith("stp_episode_")}
    assert set(numbers) == set(readable)
    assert INFO_CODES["intruder_status"][numbers["intruder_status"]] == readable["intruder_status"]
    assert (readable["max_tracking_error"] is None) == (numbers["max_tracking_error"] == -np.inf)
    assert all(type(v) in (int, float, bool) for v in numbers.values()), numbers
    for k in set(numbers) - {"intruder_status", "max_tracking_error"}:
        assert numbers[k] == readable[k], k


def test_episode_results_are_readable_at_the_end_whatever_agent_is_left(par):
    """The quick start reads the episode's results after the loop: the intruder has left before the last step
    (its info is gone), so they are in every agent's info and in ``env.episode``."""
    rng = np.random.default_rng(0)
    _, infos = par.reset(seed=0, options={"appear_time": float(par.params.episode.t_start) + 1.0})
    _same_record(infos["vehicle_0"], par.episode)
    in_episode = [int(a.split("_")[1]) for a in par.agents if a != "intruder"]
    intruder_left_at = None
    while par.agents:
        _, _, _, _, infos = par.step({a: rng.uniform(-1, 1, 2).astype(np.float32) for a in par.agents})
        if intruder_left_at is None and "intruder" not in par.agents:
            intruder_left_at = par.episode["time"]
    assert intruder_left_at is not None and "intruder" not in infos  # the case the quick start met
    assert par.episode["intruder_status"] == "gone" and par.episode["time"] > intruder_left_at
    for info in infos.values():
        _same_record(info, par.episode)
    state = par.env_state
    assert par.episode["n_forced"] == int(np.isfinite(np.asarray(state.avoid_start)).sum())
    assert par.episode["kbar"] == int(par.params.intruder.kbar)
    assert par.episode["collisions"] == int((np.asarray(state.status) == sim.COLLIDED).sum())
    assert par.episode["tracking_violations"] == int(np.asarray(state.tracking_violation).sum())
    # random actions: no vehicle tracked its plan, so there is no tracking error to bound (the evaluator's rule)
    assert not np.asarray(state.tracked)[in_episode].any()
    assert par.episode["max_tracking_error"] is None


def test_vehicle_infos_are_the_core_state_as_python_scalars(par):
    """Every vehicle's info entries are the core state's arrays after the step, read element by element, as plain
    Python scalars (the infos are built from whole columns; this reads them one at a time); the rewards and
    terminations are Python floats and bools; each observation is its own writable array."""
    obs, infos = par.reset(seed=5, options={"appear_time": float(par.params.episode.t_start) + 0.5})
    rng = np.random.default_rng(2)
    for _ in range(12):
        actions = {a: rng.uniform(-1, 1, 2).astype(np.float32) for a in par.agents}
        obs, rewards, terms, truncs, infos = par.step(actions)
        state = jax.device_get(par.env_state)
        for agent, info in infos.items():
            if agent == "intruder":
                continue
            i = int(agent.split("_")[1])
            forced = bool(np.isfinite(state.avoid_start[i]))
            expected = {
                "status": int(state.status[i]), "mode": int(state.mode[i]),
                "avoid_start_time": float(state.avoid_start[i]), "forced": forced,
                "collision": bool(state.status[i] == sim.COLLIDED),
                "guarantee_violation": bool(state.guarantee_violation[i]),
                "tracking_error": float(state.tracking_error[i]),
                "max_tracking_error": float(state.max_tracking_error[i]), "tracked": bool(state.tracked[i]),
                "tracking_violation": bool(state.tracking_violation[i]), "used_filter": bool(state.used_filter[i]),
                "min_separation": float(state.min_separation[i]), "time": float(state.t),
                "sta": float(par.params.vehicles.sta[i]), "replanned": False,
            }
            for field, value in expected.items():
                assert info[field] == value and type(info[field]) is type(value), (agent, field, info[field])
        assert all(type(r) is float for r in rewards.values())
        assert all(type(v) is bool for v in [*terms.values(), *truncs.values()])
        names = list(obs)
        for a, b in itertools.pairwise(names):
            assert not np.shares_memory(obs[a], obs[b])
        for a in names:
            obs[a][...] = 0.0  # writable
        if not par.agents:
            break


def test_tracking_error_and_violation_in_the_infos(par):
    """The infos carry what the evaluator reports: each vehicle's tracking error, its largest while tracking,
    and the tracking violation (farther than r_e from its plan while tracking it)."""
    par.reset(seed=1)
    for _ in range(40):
        _, _, _, _, infos = par.step({a: np.zeros(2, np.float32) for a in par.agents})
    state = par.env_state
    error, largest = np.asarray(state.tracking_error), np.asarray(state.max_tracking_error)
    violation = np.asarray(state.tracking_violation)
    flying = [a for a in infos if a.startswith("vehicle_") and infos[a]["status"] == sim.FLYING]
    assert flying
    for a in flying:
        i = int(a.split("_")[1])
        assert infos[a]["tracking_error"] == pytest.approx(float(error[i]))
        assert infos[a]["max_tracking_error"] == pytest.approx(float(largest[i]))
        assert infos[a]["tracking_violation"] is bool(violation[i])
    assert infos[flying[0]]["tracked"] is bool(np.asarray(state.tracked)[int(flying[0].split("_")[1])])
    assert par.episode["tracking_bound"] == pytest.approx(float(par.params.tables.tracking_bound))
    assert infos["intruder"]["tracking_violations"] == int(violation.sum())
    assert max(infos[a]["tracking_error"] for a in flying) > 0.0  # zero actions: the tracker is not flying them


def test_the_package_exports_the_environment():
    import stp_env

    par = stp_env.parallel_env(max_cycles=5)
    assert isinstance(par, stp_module.STPParallelEnv)
    aec = stp_env.env(max_cycles=5)
    assert type(aec) is type(env(max_cycles=5)) and aec.unwrapped.metadata["name"] == "stp_v1"
    assert stp_env.env.parallel_env is parallel_env  # still the module

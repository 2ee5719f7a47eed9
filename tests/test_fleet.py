"""Simulating part of a fleet (``stp_env.sim.fleet``): only the vehicles that can fly in the episode window, with
the same random numbers and the same outcomes as the whole fleet."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import sim
from stp_env.evaluation import Configuration, build_params
from stp_env.evaluation.replays import same_outcome
from stp_env.evaluation.runner import host_state, run_batch, simulated_vehicles
from stp_env.policies.intruders import _simulated_rows
from stp_env.sim import fleet
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import VEHICLE_FIELDS, WAITING
from stp_env.sim.winds.base import uniform_in_disks

EPISODES = 32
DISCRETE = ("status", "mode", "complied", "assumption_ok", "collided_with_intruder", "guarantee_violation",
            "tracked", "tracking_violation")


@pytest.fixture(scope="module")
def crossing():
    """The crossing (20 vehicles, 4 of them airborne in the window), Ornstein-Uhlenbeck gusts (a wind state that
    persists), intruders on the avoid boundaries playing max-k."""
    config = Configuration(scenario="crossing", kbar=2, intruder="max-k", wind_model="gusts")
    return config, build_params([config], progress=False)[0]


@pytest.mark.slow
def test_vehicle_fields_are_exactly_the_state_fields_with_a_row_per_vehicle(crossing):
    _, params = crossing
    full = jax.eval_shape(sim.reset, jax.random.key(0), params)
    part = jax.eval_shape(sim.reset, jax.random.key(0), fleet.select(params, np.array([1, 5, 6])))
    changed = {f.name for f in dataclasses.fields(full)
               if getattr(full, f.name).shape != getattr(part, f.name).shape}
    assert changed == set(VEHICLE_FIELDS)
    assert all(getattr(part, name).shape[0] == 3 for name in VEHICLE_FIELDS)
    assert part.wind.shape == full.wind.shape == (params.vehicles.n + 1, 2)   # the wind state is the fleet's


@pytest.mark.slow
def test_random_draws_are_the_whole_fleets(crossing):
    _, params = crossing
    ids = np.array([0, 3, 4, 11, 19])
    part = fleet.select(params, ids)
    for seed in range(50):
        key = jax.random.key(seed)
        # winds: the simulated agents' rows of the fleet's draw (the intruder's row last)
        np.testing.assert_array_equal(uniform_in_disks(key, part), uniform_in_disks(key, params)[np.append(ids, 20)])
        # the vehicle an intruder spawns next to: the fleet's draw among the same flying vehicles
        mask = np.array(jax.random.bernoulli(jax.random.fold_in(key, 1), 0.5, (ids.size,)))
        mask[seed % ids.size] = True
        full_mask = np.zeros(params.vehicles.n, bool)
        full_mask[ids] = mask
        j_full, _ = fleet.random_vehicle(key, jnp.asarray(full_mask), params)
        j_part, any_part = fleet.random_vehicle(key, jnp.asarray(mask), part)
        assert bool(any_part) and ids[int(j_part)] == int(j_full)


@pytest.mark.slow
def test_select_refuses_bad_ids(crossing):
    _, params = crossing
    for bad in ([], [3, 1], [1, 1], [-1, 2], [0, 20], [[1, 2]]):
        with pytest.raises(ValueError, match="ids must"):
            fleet.select(params, np.asarray(bad, int))
    with pytest.raises(ValueError, match="already"):
        fleet.select(fleet.select(params, np.array([1, 2])), np.array([0]))


def test_ordered_intruders_read_fleet_indices(crossing):
    _, params = crossing
    part = fleet.select(params, np.array([2, 7, 9]))
    rows, listed = _simulated_rows(part, jnp.asarray([9, 3, 2, 25], jnp.int32))
    assert np.asarray(listed).tolist() == [True, False, True, False]
    assert np.asarray(rows)[np.asarray(listed)].tolist() == [2, 0]


def test_part_of_the_fleet_plays_the_same_episodes(crossing):
    """The same episodes from the airborne vehicles alone as from all 20: every discrete outcome, forced set and
    avoid start equal; states within float32 rounding (closed-loop bang-bang controls amplify a last-bit
    difference between two compiled programs, as a different batch size does); the vehicles left out put back
    exactly as the whole fleet's simulation leaves them. The premise is checked too: in the whole fleet's
    episodes the vehicles ``airborne`` leaves out never change status, and some it keeps do (so a wrong
    ``airborne`` would be caught here)."""
    config, params = crossing
    active = simulated_vehicles(params, True)
    assert 1 <= len(active) < params.vehicles.n
    vehicle_policy, intruder_policy = config.policies()
    n_steps = sim.steps_for(params)
    idx = jnp.arange(EPISODES, dtype=jnp.int32)
    out = {}
    for name, act in (("full", None), ("part", active)):
        final, traj = run_batch(jax.random.key(3), idx, params, vehicle_policy, intruder_policy, n_steps,
                                record=True, active=act)
        out[name] = host_state(final), jax.tree.map(np.asarray, traj)
    (a, ta), (b, tb) = out["full"], out["part"]
    assert set(a) == set(b) and all(a[k].shape == b[k].shape for k in a)
    for k in (*DISCRETE, "intruder_status", "step_count", "t", "t_appear"):
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)
    np.testing.assert_array_equal(a["avoid_start"], b["avoid_start"])
    assert np.isfinite(a["avoid_start"]).sum() >= EPISODES // 2          # the episodes force vehicles
    matched = [same_outcome({k: v[i] for k, v in a.items()}, {k: v[i] for k, v in b.items()})
               for i in range(EPISODES)]
    assert np.mean(matched) >= 0.75, matched
    for k in ("status", "mode", "t", "intruder_status"):
        np.testing.assert_array_equal(ta[k], tb[k], err_msg=k)
    np.testing.assert_allclose(ta["x"], tb["x"], atol=2.0)
    # the vehicles left out: exactly the whole fleet's rows (float fields up to rounding)
    rest = np.setdiff1d(np.arange(params.vehicles.n), active)
    for k in (*VEHICLE_FIELDS, "wind"):
        x, y = np.asarray(a[k], float)[:, rest], np.asarray(b[k], float)[:, rest]
        np.testing.assert_allclose(np.where(np.isfinite(x), x, 0), np.where(np.isfinite(y), y, 0), atol=1e-4,
                                   err_msg=k)
    # the premise: left-out vehicles never leave their reset status in the whole fleet's episodes ...
    assert np.all(ta["status"][:, :, rest] == ta["status"][:, :1, rest])
    assert set(np.unique(ta["status"][:, :, rest])) <= {WAITING, sim.ARRIVED}
    # ... and the comparison above can fail: every vehicle airborne() keeps moves in the whole fleet's episodes, so
    # putting any of them back parked would not match
    moved = np.any(ta["x"][:, -1, list(active)] != ta["x"][:, 0, list(active)], axis=-1)
    assert np.all(np.any(moved, axis=0))


@pytest.mark.slow
def test_wind_models_may_answer_for_the_whole_fleet(crossing):
    """A model that sizes its winds like the wind state (the whole fleet) still gives each simulated agent its own
    row; one whose state is not the fleet's is refused."""
    from stp_env.sim import wind as wind_lib
    from stp_env.sim.winds.base import WindModel

    @dataclasses.dataclass(frozen=True)
    class PerAgent(WindModel):
        name = "per-agent"

        def draw(self, key, state, params):
            rows = jnp.arange(state.wind.shape[0], dtype=jnp.float32)          # the fleet's row numbers
            return jnp.stack([0.1 * rows, -0.1 * rows], axis=1), state.wind    # inside every wind bound

    @dataclasses.dataclass(frozen=True)
    class Undersized(PerAgent):
        name = "undersized"

        def initial(self, key, params):
            return jnp.zeros((params.vehicles.n + 1, 2))

    _, params = crossing
    ids = np.array([2, 7, 9])
    part = fleet.select(params.replace(wind=dict(model=PerAgent())), ids)
    state = SimpleNamespace(wind=wind_lib.initial_wind(jax.random.key(0), part))   # all draw() reads
    winds, heading, new = wind_lib.sample(jax.random.key(1), state, part)
    assert np.allclose(np.asarray(winds)[:, 0], [0.2, 0.7, 0.9, 2.0]) and heading.shape == (4,) and new.shape == (21, 2)
    with pytest.raises(ValueError, match="whole fleet"):
        wind_lib.initial_wind(jax.random.key(0), fleet.select(params.replace(wind=dict(model=Undersized())),
                                                              ids))


@pytest.mark.slow
def test_part_of_a_fleet_ends_when_the_whole_fleet_would(crossing):
    """The episode of part of a fleet ends early (every vehicle done, the intruder gone) only if no vehicle left
    out still waits to take off, as for the whole fleet."""
    _, params = crossing
    t0 = jnp.sort(params.vehicles.departure)[10] + 1.0           # a window in the middle of the plan
    params = params.replace(episode=dict(t_start=t0, t_end=t0 + 30.0))
    arrived = np.asarray(fleet.arrived_at_start(params))
    airborne = fleet.airborne(params)
    later = np.setdiff1d(np.flatnonzero(~arrived), airborne)          # they take off after the window
    assert arrived.any() and later.size
    for ids, waits in ((airborne, True), (np.flatnonzero(~arrived), False)):
        part = fleet.select(params, ids)
        assert bool(part.vehicles.outside_waiting) is waits
        done = SimpleNamespace(status=jnp.full((ids.size,), sim.ARRIVED), intruder_status=jnp.asarray(sim.GONE),
                               t=part.episode.t_start)                 # what episode_over reads
        terminated, _ = sim.episode_over(done, part)
        assert bool(terminated) is not waits


@pytest.mark.slow
def test_a_vehicle_whose_trajectory_flies_on_past_its_target_has_arrived(crossing):
    """A vehicle leaves the airspace when its nominal trajectory reaches the target, even where the trajectory then
    flies on out of the target disk (the city planner's do, by up to 1 km): at the episode's start it is ARRIVED,
    not simulated and no spawn anchor, and its position after the arrival is never read as a flight."""
    _, params = crossing
    order = np.argsort(np.asarray(params.vehicles.nominal_arrival))
    i = int(order[0])                                                   # the first to arrive
    t_arr = float(params.vehicles.nominal_arrival[i])
    t0 = t_arr + 20.0
    assert t0 < float(np.sort(np.asarray(params.vehicles.nominal_arrival))[1])   # nobody else has arrived yet
    last = int(params.vehicles.nominal_len[i]) - 1        # the reference stays at the last sample after it
    k = min(int(np.ceil((t_arr + 1.0 - float(params.vehicles.nominal_t0[i])) / float(params.vehicles.nominal_dt))),
            last)
    states = np.array(params.vehicles.nominal_states)
    states[i, k:, :2] = np.asarray(params.vehicles.targets[i]) + np.array([0.0, 400.0])  # 400 m north of the centre
    flown_on = params.replace(vehicles=dict(nominal_states=jnp.asarray(states)),
                              episode=dict(t_start=jnp.float32(t0), t_end=jnp.float32(t0 + 30.0)),
                              intruder=dict(appear_window=jnp.asarray([t0, t0 + 1.0], jnp.float32)))
    x_nom, _ = sim.nominal_reference(flown_on, flown_on.episode.t_start)
    assert np.hypot(*(np.asarray(x_nom[i, :2]) - np.asarray(params.vehicles.targets[i]))) > 300.0  # outside by position
    arrived = np.asarray(fleet.arrived_at_start(flown_on))
    assert arrived[i] and arrived.sum() == 1
    assert i not in fleet.airborne(flown_on)
    state = sim.reset(jax.random.key(0), flown_on)
    assert int(state.status[i]) == sim.ARRIVED and float(state.arrival_time[i]) == pytest.approx(t_arr)
    # the position rule alone (the mutant) would have put it back in the air, 400 m from its target
    mutant = flown_on.replace(vehicles=dict(nominal_arrival=jnp.full_like(params.vehicles.nominal_arrival, jnp.inf)))
    assert not np.asarray(fleet.arrived_at_start(mutant))[i]


def test_select_slices_every_per_vehicle_parameter(crossing):
    _, params = crossing
    n = params.vehicles.n
    per_vehicle = {f.name for f in dataclasses.fields(params.vehicles)
                   if hasattr(getattr(params.vehicles, f.name), "shape")
                   and getattr(params.vehicles, f.name).shape[:1] == (n,)}
    assert per_vehicle == set(fleet.PARAM_VEHICLE_FIELDS)


@pytest.mark.slow
def test_the_kbar_attack_on_the_airborne_vehicles_scores_as_on_the_whole_fleet(crossing):
    """The falsifier's k̄ attack (default ``fleet="airborne"``) gives every attack the objective the whole fleet
    gives it (forced counts equal, tie-breakers within float rounding), from fewer vehicles."""
    from stp_env.falsify.kbar import KbarAttack

    _, params = crossing
    z = jax.random.uniform(jax.random.key(0), (16, 5))
    values = {}
    for which in ("whole", "airborne"):
        attack = KbarAttack(base=params, intruder="max-k", fleet=which)
        values[which] = np.asarray(sim_jit(jax.vmap(attack.objective))(z))
    assert attack.params.vehicles.n < params.vehicles.n
    np.testing.assert_array_equal(np.floor(values["whole"]), np.floor(values["airborne"]))
    assert np.mean(values["whole"] >= 1) >= 0.5                            # the attacks force vehicles
    np.testing.assert_allclose(values["whole"], values["airborne"], atol=1e-3)
    with pytest.raises(ValueError, match="fleet"):
        KbarAttack(base=params, fleet="some")

"""The grouped EnvParams: five groups, changed with ``replace``, flat names of earlier releases pointing to their
new place, static fields in the pytree's metadata (they key the compiled program, arrays do not)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import RelativeDubins
from stp_env.sim import types
from stp_env.sim.types import (
    EnvParams,
    EpisodeParams,
    IntruderParams,
    RewardWeights,
    TableParams,
    VehicleParams,
    WindParams,
)

f32 = jnp.float32


def _params(n=2, k=4) -> EnvParams:
    z = lambda *shape: jnp.zeros(shape, f32)  # noqa: E731
    grid = hj.Grid.from_bounds((-1.0, -1.0), (1.0, 1.0), (5, 5))
    return EnvParams(
        episode=EpisodeParams(dt=jnp.asarray(0.1, f32), t_start=z(), t_end=jnp.asarray(10.0, f32), domain_lo=z(2),
                              domain_hi=jnp.ones(2, f32), collision_radius=jnp.asarray(1.0, f32),
                              reward_weights=RewardWeights(*[z() for _ in RewardWeights._fields])),
        vehicles=VehicleParams(bounds=z(5), departure=z(n), sta=z(n), nominal_arrival=z(n), starts=z(n, 3),
                               targets=z(n, 2), target_radii=z(n), nominal_t0=z(n), nominal_dt=z(),
                               nominal_states=z(n, k, 3), nominal_controls=z(n, k, 2),
                               nominal_len=jnp.full((n,), k, jnp.int32), certified=jnp.ones(n, bool),
                               planning_v_max=z(), n=n),
        intruder=IntruderParams(bounds=z(5), t_iat=z(), appear_window=z(2), spawn_radius=z(),
                                spawn_boundary_probability=z(), kbar=jnp.asarray(1, jnp.int32), d_sense=z()),
        tables=TableParams(sdf=z(5, 5), avoid_taus=z(1), avoid_values=z(1, 5, 5), detection_range=z(),
                           avoid_margin=z(), avoid_fall_rate=z(), tracking_table=z(5, 5, 2), tracking_bound=z(),
                           tracking_free_level=z(),
                           sdf_grid=grid, avoid_grid=grid, tracking_grid=grid, avoid_dynamics=RelativeDubins(),
                           tracking_dynamics=RelativeDubins()),
        wind=WindParams(model="uniform"),
    )


@pytest.mark.slow
def test_replace_changes_only_the_named_fields_and_refuses_unknown_groups_and_fields():
    params = _params()
    new = params.replace(episode=dict(t_end=jnp.asarray(20.0, f32)), vehicles=dict(sta=jnp.ones(2, f32)))
    assert float(new.episode.t_end) == 20.0 and float(params.episode.t_end) == 10.0    # a copy
    assert np.array_equal(new.vehicles.sta, np.ones(2))
    assert new.vehicles.nominal_states is params.vehicles.nominal_states
    assert new.intruder is params.intruder and new.tables is params.tables
    whole = params.replace(wind=WindParams(model="worst"))
    assert whole.wind.model == "worst"
    with pytest.raises(TypeError, match="no group 'vehicle'"):
        params.replace(vehicle=dict(sta=jnp.ones(2)))
    with pytest.raises(TypeError, match="must be a IntruderParams or a dict"):
        params.replace(intruder=params.episode)
    with pytest.raises(TypeError):
        params.replace(episode=dict(nonsense=1.0))


def test_static_fields_are_metadata_and_arrays_are_leaves():
    """Changing an array reuses the compiled program; changing a static field (the vehicle count, a switch)
    compiles a new one."""
    params = _params()
    leaves = jax.tree_util.tree_leaves(params)
    assert all(isinstance(x, jax.Array) for x in leaves)
    traces = []

    @jax.jit
    def f(p):
        traces.append(1)
        return p.episode.t_end + p.vehicles.n + jnp.sum(p.vehicles.sta)

    f(params)
    f(params.replace(episode=dict(t_end=jnp.asarray(3.0, f32)), vehicles=dict(sta=jnp.ones(2, f32))))
    assert len(traces) == 1
    f(params.replace(episode=dict(safety_filter=False)))
    assert len(traces) == 2
    assert types.GROUPS.keys() == {g.name for g in dataclasses.fields(params)}

"""Storing large plans: the lossless packed trajectories of shipped plan files and the trimming of samples after a
vehicle's arrival (``stp_env.planning.plan``)."""

from __future__ import annotations

import io

import numpy as np
import pytest

from stp_env.planning.plan import (
    Plan,
    SinglePlan,
    VehiclePlan,
    pack_trajectories,
    plan_from_arrays,
    plan_to_arrays,
    trim_after_arrival,
)


def _plan(lengths=(2000, 25, 1), seed=0) -> Plan:
    """Vehicles flying smooth random arcs (ragged lengths, one of a single sample), with arrivals inside their
    trajectories except the last one (it never arrives)."""
    rng = np.random.default_rng(seed)
    vehicles = []
    for i, m in enumerate(lengths):
        t0 = -rng.uniform(100.0, 3000.0)
        times = t0 + 0.1 * np.arange(m)
        omega = np.repeat(rng.choice([-1.2, 0.0, 1.2], m // 20 + 1), 20)[:m]      # bang-bang, as u^PP flies
        theta = rng.uniform(-np.pi, np.pi) + np.cumsum(0.1 * omega)
        xy = rng.uniform(0.0, 5000.0, 2) + np.cumsum(1.1 * np.stack([np.cos(theta), np.sin(theta)], 1), axis=0)
        states = np.concatenate([xy, theta[:, None]], axis=1)
        controls = np.stack([np.full(m, 11.0), omega], axis=1)
        arrival = float(times[m // 2]) if i < len(lengths) - 1 else float("inf")
        single = SinglePlan(t_ldt=t0, sta=float(times[-1]), times=times, states=states, controls=controls,
                            arrival_time=arrival, n_steps=m)
        vehicles.append(VehiclePlan(index=i, priority=i, plan=single, obstacle_lags=np.zeros(2),
                                    obstacle_radii=np.ones(2)))
    return Plan(vehicles=tuple(vehicles), tracking_bound=5.3, collision_radius=5.0, kbar=2)


def _same(a: Plan, b: Plan) -> bool:
    return all(np.array_equal(getattr(u.plan, f), getattr(v.plan, f))
               for u, v in zip(a.vehicles, b.vehicles, strict=True) for f in ("times", "states", "controls")) and (
        [(u.plan.t_ldt, u.plan.sta, u.plan.arrival_time, u.priority) for u in a.vehicles]
        == [(v.plan.t_ldt, v.plan.sta, v.plan.arrival_time, v.priority) for v in b.vehicles])


def _npz_bytes(arrays) -> int:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return len(buf.getvalue())


def test_packed_trajectories_are_lossless_and_smaller():
    plan = _plan()
    arrays = plan_to_arrays(plan)
    packed = pack_trajectories(arrays)
    assert not {"times", "states", "controls"} & set(packed)
    assert packed["packed_trajectories"].dtype == np.uint8
    assert _same(plan_from_arrays(packed), plan)                     # every bit back
    buf = io.BytesIO()
    np.savez_compressed(buf, **packed)
    buf.seek(0)
    with np.load(buf, allow_pickle=False) as data:                   # through a file, as shipped
        assert _same(plan_from_arrays({k: data[k] for k in data.files}), plan)
    assert _npz_bytes(packed) < 0.7 * _npz_bytes(arrays)


def test_packed_trajectories_of_the_wrong_size_are_refused():
    packed = pack_trajectories(plan_to_arrays(_plan()))
    short = dict(packed, packed_trajectories=packed["packed_trajectories"][:, :, :-1])
    with pytest.raises(ValueError, match="sum of lengths"):
        plan_from_arrays(short)
    wrong = dict(packed, packed_trajectories=packed["packed_trajectories"].astype(np.int16))
    with pytest.raises(ValueError, match="uint8"):
        plan_from_arrays(wrong)


def test_trimming_keeps_the_flight_and_the_given_seconds_after_arrival():
    plan = _plan()
    trimmed = plan_from_arrays(trim_after_arrival(plan_to_arrays(plan), 1.0))
    for full, cut in zip(plan.vehicles, trimmed.vehicles, strict=True):
        f, c = full.plan, cut.plan
        if np.isfinite(f.arrival_time):
            assert c.times[-1] <= f.arrival_time + 1.0 + 1e-9 < c.times[-1] + 0.1 + 1e-9 or len(c.times) == len(
                f.times)
            assert len(c.times) < len(f.times) or len(f.times) == 1
        else:
            assert len(c.times) == len(f.times)                      # never arrives: everything kept
        m = len(c.times)
        assert np.array_equal(c.states, f.states[:m]) and np.array_equal(c.controls, f.controls[:m])
        np.testing.assert_array_equal(c.flight()[1], f.flight()[1])  # the flight is untouched
    with pytest.raises(ValueError, match="non-negative"):
        trim_after_arrival(plan_to_arrays(plan), -1.0)

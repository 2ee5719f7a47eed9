"""The simulator's avoid-table reader (one 2 x 4 x 4 x 4 block per state, ``stp_env.sim.tables``) is the reference
reader (``stp_env.reach.avoid``: scalar gathers, central differences) up to rounding: inside, outside, on nodes,
across the periodic seam and outside the time range. The comparison can fail (a perturbed table is caught)."""

from __future__ import annotations

import types

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from stp_env import hj
from stp_env.dynamics import RelativeDubins
from stp_env.reach.avoid import avoid_table_input, avoid_table_value
from stp_env.sim import tables


def _enable_x64(on: bool):
    """``jax.enable_x64`` (newer JAX) or ``jax.experimental.enable_x64`` (older)."""
    if hasattr(jax, "enable_x64"):
        return jax.enable_x64(on)
    from jax import experimental

    return experimental.enable_x64(on)


GRID = hj.Grid.from_bounds((-50.0, -40.0, -np.pi), (50.0, 40.0, np.pi), (9, 11, 8), periodic=2)
TAUS = jnp.asarray([0.0, 1.5, 4.0, 6.0, 10.0], jnp.float32)


def _table(seed: int = 0) -> np.ndarray:
    """A smooth field plus noise (so that no read is right by accident), ``(S, *GRID.shape)``."""
    rng = np.random.default_rng(seed)
    x, y, th = np.meshgrid(*(np.asarray(GRID.lo[d] + GRID.spacing[d] * np.arange(GRID.shape[d]))
                             for d in range(3)), indexing="ij")
    base = np.hypot(x, y) - 20.0 + 5.0 * np.cos(th) + 3.0 * np.sin(2 * th)
    out = np.stack([base - 2.0 * t for t in np.asarray(TAUS)])
    return (out + rng.normal(0.0, 2.0, out.shape)).astype(np.float32)


def _queries(n: int = 4000, seed: int = 1):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(GRID.lo), np.asarray(GRID.hi)
    x = lo + (hi - lo) * rng.uniform(-0.15, 1.15, (n, 3))
    x[: n // 8, 2] = rng.choice([-np.pi, np.pi, 0.0, np.pi - 1e-6, -np.pi + 1e-6, 3 * np.pi], n // 8)  # seam
    nodes = rng.integers(0, np.asarray(GRID.shape), (n // 8, 3))
    x[n // 8: n // 4] = lo + nodes * np.asarray(GRID.spacing)                                        # nodes
    x[n // 4: 3 * n // 8, :2] = rng.choice([lo[0], hi[0], lo[1], hi[1]], (n // 8, 2))                # edges
    t = rng.uniform(-2.0, 12.0, n)
    t[: n // 16] = rng.choice(np.asarray(TAUS), n // 16)
    return jnp.asarray(x, jnp.float32), jnp.asarray(t, jnp.float32)


def _block(table):
    padded = jnp.asarray(tables.pad_periodic(table, GRID, lead=1))
    return jax.jit(jax.vmap(lambda t, x: tables.avoid_value_and_gradient(GRID, TAUS, padded, t, x)))


def _reference(table):
    raw = jnp.asarray(table)
    return jax.jit(jax.vmap(lambda t, x: (avoid_table_value(GRID, TAUS, raw, t, x),
                                          hj.interpolation.gradient_slices(GRID, TAUS, raw, t, x))))


@pytest.mark.slow
def test_block_read_is_the_reference_reader_up_to_rounding():
    table = _table()
    x, t = _queries()
    v, g = _block(table)(t, x)
    v_ref, g_ref = _reference(table)(t, x)
    scale = float(np.abs(table).max())
    np.testing.assert_allclose(np.asarray(v), np.asarray(v_ref), rtol=0, atol=2e-6 * scale)
    g_scale = scale / np.asarray(GRID.spacing)
    err = np.abs(np.asarray(g - g_ref)).max(axis=0)
    assert np.all(err < 4e-6 * g_scale), (err, g_scale)


@pytest.mark.slow
def test_the_comparison_catches_a_wrong_table():
    """One node off by 1 m is seen by the reads around it: the test above can fail."""
    table = _table()
    bad = table.copy()
    bad[2, 4, 5, 0] += 1.0  # on the periodic seam's first node
    x, t = _queries()
    v, _ = _block(bad)(t, x)
    v_ref, _ = _reference(table)(t, x)
    assert float(jnp.max(jnp.abs(v - v_ref))) > 0.05


@pytest.mark.slow
def test_avoidance_control_matches_the_reference_input():
    """``u^A`` (eq. 15) and the intruder's input from the block-read gradient: the reference's, except where a
    switching function is within rounding of zero."""
    table = _table(3)
    params = types.SimpleNamespace(tables=types.SimpleNamespace(
        avoid_grid=GRID, avoid_taus=TAUS, avoid_dynamics=RelativeDubins(),
        avoid_values=jnp.asarray(tables.pad_periodic(table, GRID, lead=1))))
    x, t = _queries(seed=4)
    raw = jnp.asarray(table)
    for player, ours in (("vehicle", tables.avoidance_control), ("intruder", tables.pursuit_input)):
        u = jax.jit(jax.vmap(lambda tt, xx, f=ours: f(params, tt, xx)))(t, x)
        u_ref = jax.jit(jax.vmap(lambda tt, xx, p=player: avoid_table_input(RelativeDubins(), GRID, TAUS, raw, p, tt,
                                                                            xx)))(t, x)
        same = np.all(np.isclose(np.asarray(u), np.asarray(u_ref), rtol=1e-5, atol=1e-5), axis=1)
        assert same.mean() > 0.995, (player, same.mean())


def test_pad_periodic_checks_its_input():
    table = _table()
    with pytest.raises(ValueError, match="do not match the grid"):
        tables.pad_periodic(table[:, :-1], GRID, lead=1)
    small = hj.Grid.from_bounds((0.0, 0.0, -np.pi), (1.0, 1.0, np.pi), (3, 5, 8), periodic=2)
    with pytest.raises(ValueError, match="at least 4 nodes"):
        tables.pad_periodic(np.zeros((3, 5, 8)), small)
    padded = tables.pad_periodic(table, GRID, lead=1)
    assert padded.shape == (len(TAUS), 9, 11, 8 + sum(tables.PERIODIC_PAD))
    np.testing.assert_array_equal(padded[..., 0], table[..., -1])
    np.testing.assert_array_equal(padded[..., -2:], table[..., :2])


@pytest.mark.slow
def test_tracking_gradient_read_is_the_reference_up_to_rounding():
    """The stacked, padded tracking gradients read as one cell block: ``interpolate_gradient`` of the fields."""
    fields = tuple(np.asarray(f) for f in _table(5)[:3])
    padded = jnp.asarray(tables.pad_components(fields, GRID))
    x, _ = _queries(seed=6)
    ours = jax.jit(jax.vmap(lambda s: tables.interpolate_components(GRID, padded, s)))(x)
    ref = jax.jit(jax.vmap(lambda s: hj.interpolation.interpolate_gradient(
        GRID, tuple(jnp.asarray(f) for f in fields), s)))(x)
    scale = max(float(np.abs(f).max()) for f in fields)
    np.testing.assert_allclose(np.asarray(ours), np.asarray(ref), rtol=0, atol=2e-6 * scale)
    wrong = jax.jit(jax.vmap(lambda s: tables.interpolate_components(GRID, padded[..., ::-1], s)))(x)
    assert float(jnp.max(jnp.abs(wrong - ref))) > 1.0  # components swapped: caught


@pytest.mark.slow
def test_block_reads_run_with_x64_enabled():
    """With ``JAX_ENABLE_X64`` (``examples/pymunk_agreement.py`` compares in float64) indices are int64: the reads
    still trace, and agree with the float32 ones."""
    table = _table()
    x, t = _queries(200)
    v32, _ = _block(table)(t, x)
    with _enable_x64(True):
        padded = jnp.asarray(tables.pad_periodic(table, GRID, lead=1), jnp.float64)
        taus = jnp.asarray(TAUS, jnp.float64)
        v64, _ = jax.vmap(lambda tt, xx: tables.avoid_value_and_gradient(GRID, taus, padded, tt, xx))(
            jnp.asarray(t, jnp.float64), jnp.asarray(x, jnp.float64))
        fields = jnp.asarray(tables.pad_components(tuple(table[:3]), GRID), jnp.float64)
        c64 = jax.vmap(lambda s: tables.interpolate_components(GRID, fields, s))(jnp.asarray(x, jnp.float64))
        assert v64.dtype == jnp.float64 and c64.shape == (200, 3)
    np.testing.assert_allclose(np.asarray(v64), np.asarray(v32), atol=1e-3)

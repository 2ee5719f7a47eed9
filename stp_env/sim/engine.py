"""The episode engine: the package's one ``lax.scan`` over the steps of an episode.

Every loop over the core's step is built on :func:`play` (``tests/test_architecture.py`` fails on another
``lax.scan`` that is not classified there): the batched rollouts (:func:`stp_env.sim.rollout`, and the evaluator's
batches on them), the worst-case reproductions (:mod:`stp_env.evaluation.worst_case`), every falsifier attack
(:func:`stp_env.falsify.harness.run`, :class:`stp_env.falsify.kbar.KbarAttack`), the co-observation threat's
rollouts and its attacker's decisions (:mod:`stp_env.coobservation.threat`, :mod:`stp_env.coobservation.learned`).
They differ only in their hooks:

* the **step** ``step(carry, x) -> (carry, info)``: one step of the episode (the core's step with the caller's
  actions; the carry may hold more than the :class:`~stp_env.sim.types.EnvState`, e.g. a running minimum);
* the **initial state** ``init(key) -> carry`` (:func:`episode`, :func:`episodes`): the reset, and whatever the
  caller fixes at the start (an intruder's spawn);
* the **stop rule** ``stop(carry) -> bool``: the episode is over before this step, which then leaves the carry as
  it is and its ``info`` zero (the rollouts' episode-over freeze: steps after the end change nothing);
* the **per-step record** ``record(carry, info) -> pytree``: what to keep of each step, from the carry after it
  (``None``: nothing is kept and the records are ``None``).

:func:`episode` and :func:`episodes` fix the keying that the rollouts and the reproductions share: the episode
keyed ``k`` resets with the first half of ``split(k)`` and steps with ``split(second half, n_steps)``.
"""

from __future__ import annotations

import threading

import jax
import jax.numpy as jnp


def play(step, carry, xs, *, stop=None, record=None, batched: bool = False):
    """``lax.scan`` of ``step`` over ``xs`` (leading axis: the steps) from ``carry``: ``(final carry, records)``.

    ``stop``, ``record``: the hooks of the module docstring. ``batched``: ``carry`` and every step's ``xs`` hold a
    batch of episodes on their leading axis, and the step (with its stop rule and record) is ``vmap``-ed over it
    inside the scan (a ``lax.scan`` over steps of the ``vmap``-ed step, not a ``vmap`` of a scan: the same
    arithmetic, but tracing a batched scan re-batches its whole body until the batching of its carry settles, which
    made the rollout several times slower to trace and compile); the records are then ``(n_steps, B, ...)``."""

    def body(c, x):
        new, info = step(c, x)
        if stop is not None:
            over = stop(c)
            new = jax.tree.map(lambda a, b: jnp.where(over, a, b), c, new)
            info = jax.tree.map(lambda a: jnp.where(over, jnp.zeros_like(a), a), info)
        return new, (None if record is None else record(new, info))

    return jax.lax.scan(jax.vmap(body) if batched else body, carry, xs)


def reset_key(episode_key):
    """The key the episode keyed ``episode_key`` resets with (the first half of its split)."""
    return jax.random.split(episode_key)[0]


def _split(episode_key, n_steps: int):
    k_reset, k_run = jax.random.split(episode_key)
    return k_reset, jax.random.split(k_run, n_steps)


def episode(key, init, step, n_steps: int, *, stop=None, record=None):
    """One episode of ``n_steps`` steps keyed by ``key``: ``init(first half of split(key))`` then :func:`play` of
    ``step(carry, step_key)`` over ``split(second half, n_steps)``. Returns ``(final carry, records)``, the
    records ``(n_steps, ...)``."""
    k_reset, k_steps = _split(key, n_steps)
    return play(step, init(k_reset), k_steps, stop=stop, record=record)


def episodes(episode_keys, init, step, n_steps: int, *, stop=None, record=None):
    """:func:`episode` of each key of ``episode_keys`` ``(B,)``, batched (:func:`play` with ``batched=True``):
    ``(final carries, records)`` batched over ``B`` on the leading axis, the records ``(B, n_steps, ...)``.

    With several devices on JAX's default backend (e.g. the CPU split into one device per core,
    :func:`stp_env.set_cpu_devices`) the episodes are shared out among them (:func:`across_devices`): the same
    outcomes as on one device, not always the same last bits (each share is another compiled program)."""

    def run(keys):
        k_reset, k_steps = jax.vmap(lambda k: _split(k, n_steps))(keys)
        final, records = play(step, jax.vmap(init)(k_reset), jnp.swapaxes(k_steps, 0, 1), stop=stop, record=record,
                              batched=True)
        return final, jax.tree.map(lambda a: jnp.swapaxes(a, 0, 1), records)

    return across_devices(run, episode_keys)


MESH_AXIS = "stp_env_episodes"
"""The name of the mesh axis :func:`across_devices` shares a batch along."""


_SHARING = threading.local()
"""``depth``: how many :func:`across_devices` calls are tracing their function in this thread (a batch inside a
share is not shared again)."""


def shares(n: int) -> int:
    """Among how many devices :func:`across_devices` shares a batch of ``n``: every device of JAX's default backend,
    or one (no sharing) with a single device, fewer than one element per device, or inside a share already. Each
    share is another compiled program than the whole batch, so results are bit for bit the same only for the same
    count."""
    count = len(jax.devices())
    return count if 1 < count <= n and not getattr(_SHARING, "depth", 0) else 1


def across_devices(fn, batch, shared=None):
    """``fn(batch)`` with the batch (a pytree whose leaves have the batch on their leading axis, as do ``fn``'s
    outputs) split into equal shares, one per device of JAX's default backend, run side by side
    (``jax.shard_map``; the devices compute independently, no communication). With one device, or fewer episodes
    than devices, it is ``fn(batch)``. A batch that does not divide evenly is padded with copies of its last
    element, and the padding cut from the outputs.

    Everything ``fn`` closes over is copied to every device at each call. ``shared`` (a pytree, e.g. the
    environment's parameters) is instead passed whole to every share, ``fn(batch, shared)``: a program called again
    and again with the same large arguments takes them this way, put on every device once with :func:`replicate`
    (closed over, an array placed on several devices clashes with the shares' own placement).

    ``fn`` must treat the batch's elements independently (a ``vmap`` over it, as the episode engine does): each
    device then computes the same arithmetic for its elements as one device would, compiled as another program (a
    batch of its share), so the last bits may differ as between batch sizes (``docs/numerics.md``)."""
    n = jax.tree.leaves(batch)[0].shape[0]
    call = fn if shared is None else (lambda b: fn(b, shared))
    if shares(n) == 1:
        return call(batch)
    devices = jax.devices()
    from jax.sharding import Mesh, PartitionSpec

    pad = -n % len(devices)
    if pad:
        batch = jax.tree.map(lambda a: jnp.concatenate([a, jnp.repeat(a[-1:], pad, axis=0)]), batch)
    mesh = Mesh(devices, (MESH_AXIS,))

    def share(*args):
        _SHARING.depth = getattr(_SHARING, "depth", 0) + 1
        try:
            return fn(*args)
        finally:
            _SHARING.depth -= 1

    split = PartitionSpec(MESH_AXIS)
    args, specs = ((batch,), (split,)) if shared is None else ((batch, shared), (split, PartitionSpec()))
    out = jax.shard_map(share, mesh=mesh, in_specs=specs, out_specs=split, check_vma=False)(*args)
    return jax.tree.map(lambda a: a[:n], out) if pad else out


def vmap_across_devices(fn, shared=None):
    """``jax.vmap(fn)`` over the leading axis of every positional argument, the batch shared among the devices of
    JAX's default backend (:func:`across_devices`): what every batched program of independent episodes or
    environments uses (the rollouts above, the vectorised training environments, the co-observation batches, the
    falsifier's populations), so that one device per core speeds them all. With one device it is
    ``jax.vmap(fn)``, the same program. ``shared``: passed whole to every call, ``fn(*elements, shared)``
    (:func:`across_devices`'s ``shared``)."""

    def run(*args):
        if shared is None:
            return across_devices(lambda batch: jax.vmap(fn)(*batch), args)
        return across_devices(lambda batch, s: jax.vmap(lambda *a: fn(*a, s))(*batch), args, shared=shared)

    return run


def replicate(tree):
    """``tree``'s arrays copied onto every device of JAX's default backend when there are several (anything else
    as it is): the ``shared`` arguments (:func:`across_devices`) a program takes call after call, e.g. an
    environment's parameters with their tables. Left on one device, every call would copy them to the others: the
    vectorised training environment's step ran 3x slower on two devices than on one that way."""
    devices = jax.devices()
    if len(devices) == 1:
        return tree
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    sharding = NamedSharding(Mesh(devices, (MESH_AXIS,)), PartitionSpec())
    return jax.tree.map(lambda a: jax.device_put(a, sharding) if isinstance(a, jax.Array) else a, tree)


"""The survivability missions' random tie-breaking in a compiled program, the same draws as numpy's: ``run_mission``
breaks ties with ``numpy.random.default_rng(seed).choice(ties)``, which takes Lemire's bounded integer from the
generator's 32-bit outputs. :func:`tie_streams` pre-draws those outputs on the host and :func:`lemire` repeats the
method, rejections included, in uint32 arithmetic (:mod:`stp_env.survivability.batch`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

STREAM = 256
"""32-bit generator outputs pre-drawn per mission for the tie-breaking (see the module docstring)."""


def tie_streams(seeds) -> np.ndarray:
    """``(len(seeds), STREAM)`` uint32: the first ``STREAM`` 32-bit outputs of ``numpy.random.default_rng(seed)``
    for each seed, in the order ``Generator.choice`` consumes them (low half of each 64-bit PCG64 output, then its
    high half)."""
    out = np.empty((len(seeds), STREAM), np.uint32)
    for i, seed in enumerate(seeds):
        raw = np.random.default_rng(seed).bit_generator.random_raw(STREAM // 2).astype(np.uint64)
        out[i, 0::2] = (raw & np.uint64(0xFFFFFFFF)).astype(np.uint32)
        out[i, 1::2] = (raw >> np.uint64(32)).astype(np.uint32)
    return out


def lemire(stream, cursor, n):
    """Lemire's bounded integer in ``[0, n)`` (numpy's ``buffered_bounded_lemire_uint32``, what
    ``Generator.choice`` of ``n`` items draws) from the 32-bit outputs ``stream`` read from ``cursor``; returns
    ``(value, next cursor)``. ``n`` < 2**16 (a number of primitives). uint32 arithmetic: ``m = u n`` in 64 bits is
    ``hi 2**32 + lo`` with ``lo = u n mod 2**32`` and ``hi = (uh n + (ul n >> 16)) >> 16`` (``u = uh 2**16 + ul``)."""
    n = n.astype(jnp.uint32)
    threshold = (jnp.uint32(0) - n) % n        # (2**32 - n) mod n = (UINT32_MAX - (n - 1)) mod n

    def draw(c):
        u = stream[jnp.minimum(c, stream.shape[0] - 1)]
        lo = u * n
        hi = ((u >> 16) * n + (((u & jnp.uint32(0xFFFF)) * n) >> 16)) >> 16
        return lo, hi

    lo, hi = draw(cursor)

    def again(state):
        c, lo, _ = state
        return (lo < n) & (lo < threshold) & (c < stream.shape[0])

    def redraw(state):
        c, _, _ = state
        lo, hi = draw(c + 1)
        return c + 1, lo, hi

    c, lo, hi = jax.lax.while_loop(again, redraw, (cursor, lo, hi))
    return hi.astype(jnp.int32), c + 1

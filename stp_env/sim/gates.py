"""Skipping work that no episode of a batch needs, exactly.

A batched simulator program is the step ``vmap``-ed over episodes, and under ``vmap`` a ``lax.cond`` whose predicate
differs between episodes becomes a ``select``: both branches are computed for every episode. Much of a step is
needed only in some states (the avoid-table reads only while the intruder is present, a policy only while its agent
can act), and in most steps of a batch no episode is in such a state. :func:`batch_any` reduces a predicate over
every batch axis it is ``vmap``-ed over (a ``custom_vmap`` rule), so that :func:`when_any`'s ``lax.cond`` keeps an
unbatched predicate and stays a branch: the work is skipped when no episode of the batch needs it, and done for the
whole batch otherwise.

Exactness is the caller's contract: ``compute`` must give, for every element whose own predicate is false, exactly
what ``skip`` gives (e.g. it masks its results with the predicate). Then every element's result is the same whichever
branch ran, so an episode's outcome does not depend on the other episodes of its batch (``tests/test_gates.py``).
The gate is differentiable wherever ``compute`` is (``lax.cond``; the predicate carries no gradient).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap


@custom_vmap
def batch_any(pred):
    """``pred`` (a boolean scalar); under ``vmap``, the ``any`` over the batch, unbatched."""
    return jnp.asarray(pred, bool)


@batch_any.def_vmap
def _batch_any_rule(axis_size, in_batched, pred):
    (batched,) = in_batched
    # the result goes through batch_any again, so that an enclosing vmap reduces over its own axis too
    return batch_any(jnp.any(pred) if batched else pred), False


def when_any(pred, compute, skip, *operands):
    """``compute(*operands)`` if ``pred`` holds for some element of the batch, else ``skip(*operands)``
    (``lax.cond`` on :func:`batch_any`). ``pred``: a boolean array of one episode (reduced with ``any``)."""
    return jax.lax.cond(batch_any(jnp.any(pred)), compute, skip, *operands)

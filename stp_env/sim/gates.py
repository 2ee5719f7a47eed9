"""Skipping work that no episode of a batch needs, exactly.

A batched simulator program is the step ``vmap``-ed over episodes, and under ``vmap`` a ``lax.cond`` whose predicate
differs between episodes becomes a ``select``: both branches are computed for every episode. Much of a step is
needed only in some states (the avoid-table reads only while the intruder is present, a policy only while its agent
can act), and in most steps of a batch no episode is in such a state. :func:`batch_any` reduces a predicate over
every batch axis it is ``vmap``-ed over (a ``custom_vmap`` rule), so that :func:`when_any`'s ``lax.cond`` keeps an
unbatched predicate and stays a branch: the work is skipped when no episode of the batch needs it, and done for the
whole batch otherwise.

When some elements of a batch need a computation and most do not (the avoid reads of the few vehicles near an
intruder among thousands of a batch), :func:`where_needed` goes further: its ``custom_vmap`` rule sees the whole
batch, gathers the elements that need the computation into a smaller batch, computes only those, and scatters the
results back.

Exactness is the caller's contract: ``compute`` must give, for every element whose own predicate is false, exactly
what ``skip`` gives (e.g. it masks its results with the predicate). Then every element's result is the same whichever
branch ran, so an episode's outcome does not depend on the other episodes of its batch (``tests/test_gates.py``).
The gate is differentiable wherever ``compute`` is (``lax.cond``; the predicate carries no gradient).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
from jax.custom_batching import custom_vmap
from jax.custom_derivatives import SymbolicZero


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


# ------------------------------------------------------------------------------------------------ where_needed
# The smallest gathered batch. XLA's CPU compiler (jaxlib 0.10.2) hands a reduction of 1,024 rows or more to a
# library kernel that sums in another order than the loop it emits for fewer rows, so the avoid value's last
# contraction rounds differently in a batch of fewer than 1,024 reads: gathered into a smaller batch than the whole
# one, a vehicle's value would depend on how many vehicles of its batch needed reads. Gathering never below 1,024
# keeps every read the one of the whole batch, bit for bit (``tests/test_gates.py`` checks it on the simulator's
# reads, so a compiler that moves the threshold fails there).
MIN_GATHER = 1024
TIERS = (1 / 16, 1 / 4)  # the gathered sizes tried before every element, as fractions of all the elements


def where_needed(pred, fn, fill, elements, shared=()):
    """``fn(element, shared)`` for every element where ``pred`` holds, ``fill`` elsewhere; the work follows how many
    elements of the whole batch need ``fn``, not the batch's size.

    ``pred``: a boolean array; ``elements``: a pytree whose leaves have ``pred``'s shape as their leading axes (one
    element per entry of ``pred``); ``shared``: a pytree every element reads whole (e.g. the tables); ``fill``: a
    pytree like ``fn``'s result for one element, its value where ``pred`` is false. Returns ``fn``'s results with
    ``pred``'s shape as leading axes.

    Under ``vmap`` (any number of nested ones; a ``custom_vmap`` rule, as :func:`batch_any`'s) the elements of the
    whole batch are flattened together, a shared leaf batched by an enclosing ``vmap`` becoming a per-element one.
    The elements that need ``fn`` are counted: none, and ``fn`` does not run; up to one of the gathered sizes
    (:data:`TIERS` of all the elements, at least :data:`MIN_GATHER`), and they are gathered into a batch of that size,
    computed, and scattered back (each size at least twice the one before and at most half of all the elements:
    below 2,048 elements nothing is gathered); more, and every element is computed and masked. Exact when each
    element's result does not depend on the batch it is computed in (see :data:`MIN_GATHER`): every element's result
    is then the same whichever branch ran, so an episode does not depend on its batch-mates. Differentiable: the
    derivatives are those of every element computed and masked (a ``custom_jvp``)."""
    e_leaves, e_tree = jax.tree.flatten(elements)
    s_leaves, s_tree = jax.tree.flatten(shared)
    spec = _Spec(fn, fill, e_tree, s_tree, (False,) * len(s_leaves))
    return _differentiable(spec)(jnp.asarray(pred, bool), list(e_leaves), list(s_leaves))


class _Spec:
    """What :func:`where_needed` maps: ``fn``, ``fill``, the trees of the elements and of the shared inputs, and
    which shared leaves an enclosing ``vmap`` has made per-element leaves (``moved``; they follow the elements' own
    leaves, in the order of the shared tree)."""

    def __init__(self, fn, fill, e_tree, s_tree, moved):
        self.fn, self.fill, self.e_tree, self.s_tree, self.moved = fn, fill, e_tree, s_tree, tuple(moved)

    def call(self, e_leaves, s_leaves):
        """``fn`` of one element."""
        n_e = self.e_tree.num_leaves
        moved, kept = iter(e_leaves[n_e:]), iter(s_leaves)
        shared = [next(moved) if m else next(kept) for m in self.moved]
        return self.fn(jax.tree.unflatten(self.e_tree, e_leaves[:n_e]), jax.tree.unflatten(self.s_tree, shared))

    def map(self, flat, s_leaves):
        """``fn`` of every element of ``flat`` (leaves with one leading axis)."""
        return jax.vmap(self.call, in_axes=(0, None))(flat, s_leaves)

    def filled(self, m, like):
        """``fill`` for ``m`` elements, with the dtypes of ``like`` (one element's results)."""
        return jax.tree.map(lambda f, o: jnp.broadcast_to(jnp.asarray(f, o.dtype), (m, *o.shape)), self.fill, like)


def _flat(pred, e_leaves):
    lead = pred.shape
    return lead, pred.reshape(-1), [a.reshape((-1, *a.shape[len(lead):])) for a in e_leaves]


def _unflat(lead, out):
    return jax.tree.map(lambda o: o.reshape(lead + o.shape[1:]), out)


def _masked(p, out, filled):
    return jax.tree.map(lambda o, f: jnp.where(p.reshape((-1,) + (1,) * (o.ndim - 1)), o, f), out, filled)


def _one(spec, flat, s_leaves):
    """The shapes and dtypes of ``fn``'s results for one element."""
    return jax.eval_shape(spec.call, [jax.ShapeDtypeStruct(a.shape[1:], a.dtype) for a in flat], s_leaves)


def _every(spec, pred, e_leaves, s_leaves):
    """Every element computed, then masked: what :func:`where_needed` equals (and how it differentiates)."""
    lead, p, flat = _flat(pred, e_leaves)
    return _unflat(lead, _masked(p, spec.map(flat, s_leaves), spec.filled(p.shape[0], _one(spec, flat, s_leaves))))


def _gathered(spec, pred, e_leaves, s_leaves):
    """:func:`where_needed` of a batch flattened to one axis: none, a gathered batch, or every element."""
    lead, p, flat = _flat(pred, e_leaves)
    m = p.shape[0]
    one = _one(spec, flat, s_leaves)
    sizes = []  # each at least twice the one before and at most half of all: a branch that saves little is not
    for size in sorted({max(MIN_GATHER, math.ceil(m * f)) for f in TIERS}):  # worth its compiled copy of fn
        if 2 * size <= m and (not sizes or size >= 2 * sizes[-1]):
            sizes.append(size)

    def none(p, flat, s_leaves):
        return spec.filled(m, one)

    def gather(size):
        def run(p, flat, s_leaves):
            idx = jnp.nonzero(p, size=size, fill_value=m)[0]  # past the end: padding, dropped by the scatter
            out = spec.map([a.at[idx].get(mode="clip") for a in flat], s_leaves)
            return jax.tree.map(lambda f, o: f.at[idx].set(o, mode="drop"), spec.filled(m, one), out)
        return run

    def every(p, flat, s_leaves):
        return _masked(p, spec.map(flat, s_leaves), spec.filled(m, one))

    count = jnp.sum(p, dtype=jnp.int32)
    if not sizes:  # too few elements to gather: every element, or none
        return _unflat(lead, jax.lax.cond(count > 0, every, none, p, flat, s_leaves))
    branch = (count > 0).astype(jnp.int32) + sum((count > s).astype(jnp.int32) for s in sizes)
    return _unflat(lead, jax.lax.switch(branch, [none, *(gather(s) for s in sizes), every], p, flat, s_leaves))


def _batched(spec):
    """:func:`_gathered` of ``spec``, and under ``vmap`` the same of the batch (:func:`where_needed`)."""

    @custom_vmap
    def run(pred, e_leaves, s_leaves):
        return _gathered(spec, pred, e_leaves, s_leaves)

    @run.def_vmap
    def rule(axis_size, in_batched, pred, e_leaves, s_leaves):
        p_b, e_b, s_b = in_batched
        lead = pred.shape if p_b else (axis_size, *pred.shape)
        pred = pred if p_b else jnp.broadcast_to(pred, lead)
        e_leaves = [a if b else jnp.broadcast_to(a, lead + a.shape) for a, b in zip(e_leaves, e_b)]
        n_e = spec.e_tree.num_leaves
        before, shared = iter(e_leaves[n_e:]), iter(zip(s_leaves, s_b))
        moved, leaves, kept = [], [], []
        for m in spec.moved:
            a, b = (next(before), True) if m else next(shared)
            moved.append(m or b)
            if m:
                leaves.append(a)
            elif b:  # batched here: repeated over the element axes, one per element from now on
                a = a.reshape((axis_size,) + (1,) * (len(lead) - 1) + a.shape[1:])
                leaves.append(jnp.broadcast_to(a, lead + a.shape[len(lead):]))
            else:
                kept.append(a)
        out = _batched(_Spec(spec.fn, spec.fill, spec.e_tree, spec.s_tree, moved))(pred, e_leaves[:n_e] + leaves,
                                                                                    kept)
        return out, jax.tree.map(lambda _: True, out)

    return run


def _differentiable(spec):
    """:func:`_batched` of ``spec`` with the derivatives of :func:`_every`."""

    @jax.custom_jvp
    def run(pred, e_leaves, s_leaves):
        return _batched(spec)(pred, e_leaves, s_leaves)

    def jvp(primals, tangents):
        # inputs without a tangent (the tables) stay out of the linearisation instead of carrying zeros of their size
        pred, e_leaves, s_leaves = primals
        leaves = [*e_leaves, *s_leaves]
        tangents = [*tangents[1], *tangents[2]]
        live = [i for i, t in enumerate(tangents) if not isinstance(t, SymbolicZero)]
        n_e = len(e_leaves)

        def of(*xs):
            full = list(leaves)
            for i, x in zip(live, xs):
                full[i] = x
            return _every(spec, pred, full[:n_e], full[n_e:])

        if not live:
            out = of()
            return out, jax.tree.map(jnp.zeros_like, out)
        return jax.jvp(of, tuple(leaves[i] for i in live), tuple(tangents[i] for i in live))

    run.defjvp(jvp, symbolic_zeros=True)
    return run

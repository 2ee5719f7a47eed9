"""Convex input sets (controls, disturbances) with closed-form support functions and extreme points.

An input space is a :class:`ProductSet` of blocks, each acting on consecutive input components:

* :class:`Box` ``[lo, hi]`` per component (speeds, turn rates, heading disturbances);
* :class:`Ball` ``{c + r e : ||e||_2 <= 1}`` in ``k`` components (wind of bounded magnitude).

For a direction ``q`` (one array per component, broadcastable), the support function
``max_{u in U} q . u`` and the maximiser are given in closed form; ``min`` is ``-max`` of ``-q``. The solver uses
these to evaluate the Hamiltonian ``p . f(x, u, d)`` of control- and disturbance-affine dynamics over the whole
grid without enumerating inputs.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax.numpy as jnp


def _as_tuple(x) -> tuple[float, ...]:
    if isinstance(x, (int, float)):
        return (float(x),)
    return tuple(float(v) for v in x)


@dataclasses.dataclass(frozen=True)
class Box:
    """Axis-aligned box ``lo <= u <= hi`` (component-wise)."""

    lo: tuple[float, ...]
    hi: tuple[float, ...]

    def __post_init__(self) -> None:
        lo, hi = _as_tuple(self.lo), _as_tuple(self.hi)
        if len(lo) != len(hi) or not lo:
            raise ValueError(f"Box needs lo and hi of equal non-zero length; got {lo} and {hi}.")
        for a, b in zip(lo, hi):
            if not (math.isfinite(a) and math.isfinite(b)) or a > b:
                raise ValueError(f"Box bounds must be finite with lo <= hi; got lo={lo}, hi={hi}.")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @property
    def dim(self) -> int:
        return len(self.lo)

    @property
    def center(self) -> tuple[float, ...]:
        return tuple((a + b) / 2 for a, b in zip(self.lo, self.hi))

    @property
    def half_width(self) -> tuple[float, ...]:
        return tuple((b - a) / 2 for a, b in zip(self.lo, self.hi))

    def support(self, q: Sequence) -> jnp.ndarray:
        """``max_{u in box} q . u = q . c + |q| . r``."""
        return sum(qi * c + jnp.abs(qi) * r for qi, c, r in zip(q, self.center, self.half_width))

    def argmax(self, q: Sequence) -> tuple:
        """Maximiser of ``q . u``: ``hi`` where ``q >= 0``, else ``lo`` (ties go to ``hi``, as in
        ``hj_reachability``)."""
        return tuple(jnp.where(qi < 0, a, b) for qi, a, b in zip(q, self.lo, self.hi))

    def max_abs_linear(self, g: Sequence) -> jnp.ndarray:
        """``max_{u in box} |g . u - g . c|`` = ``sum |g_j| r_j`` (spread of a linear form around the centre)."""
        return sum(jnp.abs(gj) * r for gj, r in zip(g, self.half_width) if r != 0.0)

    def contains(self, u: Sequence, atol: float = 1e-6):
        return jnp.all(jnp.stack([(ui >= a - atol) & (ui <= b + atol)
                                  for ui, a, b in zip(u, self.lo, self.hi)]), axis=0)

    def clip(self, u: Sequence) -> tuple:
        return tuple(jnp.clip(ui, a, b) for ui, a, b in zip(u, self.lo, self.hi))


@dataclasses.dataclass(frozen=True)
class Ball:
    """Euclidean ball ``||u - center||_2 <= radius`` in ``len(center)`` components."""

    center: tuple[float, ...]
    radius: float

    def __post_init__(self) -> None:
        center = _as_tuple(self.center)
        radius = float(self.radius)
        if not center:
            raise ValueError("Ball needs a centre of at least one component.")
        if not math.isfinite(radius) or radius < 0:
            raise ValueError(f"Ball radius must be finite and >= 0; got {radius}.")
        object.__setattr__(self, "center", center)
        object.__setattr__(self, "radius", radius)

    @property
    def dim(self) -> int:
        return len(self.center)

    @staticmethod
    def _norm(q: Sequence) -> jnp.ndarray:
        return jnp.sqrt(sum(qi * qi for qi in q))

    def support(self, q: Sequence) -> jnp.ndarray:
        """``max_{||u - c|| <= r} q . u = q . c + r ||q||``."""
        lin = sum(qi * c for qi, c in zip(q, self.center) if c != 0.0)
        return lin + self.radius * self._norm(q)

    def argmax(self, q: Sequence) -> tuple:
        """Maximiser ``c + r q / ||q||`` (``c`` where ``q = 0``)."""
        norm = self._norm(q)
        safe = jnp.where(norm > 0, norm, 1.0)
        return tuple(c + self.radius * jnp.where(norm > 0, qi / safe, 0.0) for qi, c in zip(q, self.center))

    def max_abs_linear(self, g: Sequence) -> jnp.ndarray:
        """``max_{||e|| <= r} |g . e| = r ||g||``."""
        if self.radius == 0.0:
            return 0.0
        return self.radius * self._norm(g)

    def contains(self, u: Sequence, atol: float = 1e-6):
        return self._norm([ui - c for ui, c in zip(u, self.center)]) <= self.radius + atol

    def clip(self, u: Sequence) -> tuple:
        d = [ui - c for ui, c in zip(u, self.center)]
        norm = self._norm(d)
        scale = jnp.where(norm > self.radius, self.radius / jnp.where(norm > 0, norm, 1.0), 1.0)
        return tuple(c + di * scale for di, c in zip(d, self.center))


@dataclasses.dataclass(frozen=True)
class ProductSet:
    """Cartesian product of blocks; block ``k`` acts on the next ``blocks[k].dim`` input components."""

    blocks: tuple[Box | Ball, ...] = ()

    def __post_init__(self) -> None:
        blocks = tuple(self.blocks)
        for b in blocks:
            if not isinstance(b, (Box, Ball)):
                raise TypeError(f"ProductSet blocks must be Box or Ball; got {type(b).__name__}.")
        object.__setattr__(self, "blocks", blocks)

    @property
    def dim(self) -> int:
        return sum(b.dim for b in self.blocks)

    def _split(self, q: Sequence) -> list[tuple]:
        if len(q) != self.dim:
            raise ValueError(f"Expected {self.dim} input components, got {len(q)}.")
        out, k = [], 0
        for b in self.blocks:
            out.append(tuple(q[k:k + b.dim]))
            k += b.dim
        return out

    def support(self, q: Sequence):
        """``max_{u in U} q . u``."""
        return sum((b.support(qb) for b, qb in zip(self.blocks, self._split(q))), 0.0)

    def argmax(self, q: Sequence) -> tuple:
        out: list = []
        for b, qb in zip(self.blocks, self._split(q)):
            out.extend(b.argmax(qb))
        return tuple(out)

    def extreme(self, q: Sequence, mode: str) -> tuple:
        """Optimiser of ``q . u`` for ``mode`` in ``{"max", "min"}``."""
        if mode == "max":
            return self.argmax(q)
        return self.argmax(tuple(-qi for qi in q))

    def optimum(self, q: Sequence, mode: str):
        """``max`` or ``min`` of ``q . u`` over the set."""
        if mode == "max":
            return self.support(q)
        return -self.support(tuple(-qi for qi in q))

    def center(self) -> tuple[float, ...]:
        out: list[float] = []
        for b in self.blocks:
            out.extend(b.center)
        return tuple(out)

    def contains(self, u: Sequence, atol: float = 1e-6):
        parts = [b.contains(ub, atol) for b, ub in zip(self.blocks, self._split(u))]
        out = parts[0]
        for p in parts[1:]:
            out = out & p
        return out

    def clip(self, u: Sequence) -> tuple:
        out: list = []
        for b, ub in zip(self.blocks, self._split(u)):
            out.extend(b.clip(ub))
        return tuple(out)


EMPTY = ProductSet(())

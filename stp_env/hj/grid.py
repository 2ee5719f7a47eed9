"""Uniform N-D Cartesian grids with optional periodic dimensions.

A :class:`Grid` is an immutable, hashable description (bounds, point counts, periodic dimensions). Because it
is hashable it is passed to jitted functions as a *static* argument: everything derived from it (coordinates,
spacing) is a compile-time constant, so no grid arrays live in device memory until they are used.

Conventions
-----------
* Non-periodic dimension ``i``: ``n_i`` points from ``lo_i`` to ``hi_i`` inclusive, spacing
  ``(hi_i - lo_i) / (n_i - 1)``.
* Periodic dimension ``i`` (for example a heading): ``n_i`` points from ``lo_i`` to ``hi_i`` *exclusive*; the period
  is ``hi_i - lo_i`` and the spacing ``(hi_i - lo_i) / n_i``. Coordinates are wrapped into ``[lo_i, hi_i)``.

These are the conventions of ``hj_reachability`` and of Mitchell's level-set toolbox, so that values computed on
the same grid can be compared node for node.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np


@dataclasses.dataclass(frozen=True)
class Grid:
    """An N-D uniform grid.

    Attributes:
        lo: lower bound of each dimension (state units, e.g. m or rad).
        hi: upper bound of each dimension (inclusive if non-periodic, exclusive if periodic).
        shape: number of points in each dimension.
        periodic: indices of the periodic dimensions.
    """

    lo: tuple[float, ...]
    hi: tuple[float, ...]
    shape: tuple[int, ...]
    periodic: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        lo = tuple(float(x) for x in self.lo)
        hi = tuple(float(x) for x in self.hi)
        shape = tuple(int(n) for n in self.shape)
        periodic = tuple(sorted({int(i) for i in self.periodic}))
        if not (len(lo) == len(hi) == len(shape)) or len(shape) == 0:
            raise ValueError(
                f"Grid needs lo, hi and shape of the same non-zero length; got lengths "
                f"{len(lo)}, {len(hi)}, {len(shape)}."
            )
        for i, (a, b, n) in enumerate(zip(lo, hi, shape)):
            if not (math.isfinite(a) and math.isfinite(b)):
                raise ValueError(f"Grid bounds must be finite; dimension {i} has lo={a}, hi={b}.")
            if not b > a:
                raise ValueError(
                    f"Grid dimension {i} has non-positive extent (lo={a}, hi={b}); hi must exceed lo, "
                    "so that the spacing is positive."
                )
            if n < 2:
                raise ValueError(f"Grid dimension {i} has {n} point(s); at least 2 are needed.")
        for i in periodic:
            if not 0 <= i < len(shape):
                raise ValueError(f"Periodic dimension {i} is out of range for a {len(shape)}-D grid.")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "periodic", periodic)

    @classmethod
    def from_bounds(
        cls,
        lo: Sequence[float],
        hi: Sequence[float],
        shape: Sequence[int],
        periodic: Sequence[int] | int | None = None,
    ) -> Grid:
        """Builds a grid; ``periodic`` may be an index, a sequence of indices or ``None``."""
        if periodic is None:
            periodic = ()
        elif isinstance(periodic, (int, np.integer)):
            periodic = (int(periodic),)
        return cls(tuple(lo), tuple(hi), tuple(shape), tuple(periodic))

    # ------------------------------------------------------------------ geometry
    @property
    def ndim(self) -> int:
        return len(self.shape)

    @property
    def size(self) -> int:
        return int(np.prod(self.shape))

    @property
    def is_periodic(self) -> tuple[bool, ...]:
        return tuple(i in self.periodic for i in range(self.ndim))

    @property
    def spacing(self) -> tuple[float, ...]:
        """Grid spacing per dimension (state units)."""
        return tuple(
            (b - a) / (n if p else n - 1)
            for a, b, n, p in zip(self.lo, self.hi, self.shape, self.is_periodic)
        )

    @property
    def period(self) -> tuple[float | None, ...]:
        return tuple((b - a) if p else None for a, b, p in zip(self.lo, self.hi, self.is_periodic))

    def coordinate_vector(self, dim: int) -> np.ndarray:
        """The 1-D coordinates of dimension ``dim`` (float64 numpy array)."""
        return self.lo[dim] + self.spacing[dim] * np.arange(self.shape[dim], dtype=np.float64)

    def coordinate_vectors(self) -> tuple[np.ndarray, ...]:
        return tuple(self.coordinate_vector(i) for i in range(self.ndim))

    def broadcast_states(self, dtype=jnp.float32) -> tuple[jnp.ndarray, ...]:
        """The grid states as a tuple of ``ndim`` arrays, dimension ``i`` of shape ``(1, .., n_i, .., 1)``.

        Broadcasting instead of materialising ``(n_0, ..., n_{d-1}, d)`` keeps memory at ``sum(n_i)`` numbers;
        functions of the state written with ordinary arithmetic broadcast to the full grid.
        """
        out = []
        for i, c in enumerate(self.coordinate_vectors()):
            shape = [1] * self.ndim
            shape[i] = self.shape[i]
            out.append(jnp.asarray(c.reshape(shape), dtype=dtype))
        return tuple(out)

    def states(self, dtype=jnp.float32) -> jnp.ndarray:
        """All grid states, shape ``(*shape, ndim)``. Uses ``size * ndim`` numbers: prefer
        :meth:`broadcast_states` on large grids."""
        return jnp.stack(jnp.meshgrid(*[jnp.asarray(c, dtype) for c in self.coordinate_vectors()],
                                      indexing="ij"), -1)

    # ------------------------------------------------------------ conversions
    def wrap(self, state):
        """Wraps periodic coordinates of ``state`` (shape ``(..., ndim)``) into ``[lo, hi)``."""
        state = jnp.asarray(state)
        if not self.periodic:
            return state
        lo = jnp.asarray(self.lo, state.dtype)
        per = jnp.asarray([p if p is not None else 1.0 for p in self.period], state.dtype)
        wrapped = lo + jnp.mod(state - lo, per)
        return jnp.where(jnp.asarray(self.is_periodic), wrapped, state)

    def fractional_index(self, state):
        """Continuous index of ``state`` (shape ``(..., ndim)``): ``(state - lo) / spacing``, periodic dims
        taken modulo ``n``."""
        state = jnp.asarray(state)
        lo = jnp.asarray(self.lo, state.dtype)
        dx = jnp.asarray(self.spacing, state.dtype)
        pos = (state - lo) / dx
        n = jnp.asarray(self.shape, state.dtype)
        return jnp.where(jnp.asarray(self.is_periodic), jnp.mod(pos, n), pos)

    def nearest_index(self, state):
        """Nearest grid index of ``state`` (int32, clipped into the grid; periodic dims wrapped)."""
        pos = jnp.round(self.fractional_index(state)).astype(jnp.int32)
        n = jnp.asarray(self.shape, jnp.int32)
        return jnp.where(jnp.asarray(self.is_periodic), jnp.mod(pos, n), jnp.clip(pos, 0, n - 1))

    def index_to_state(self, index):
        """Coordinates of the node ``index`` (shape ``(..., ndim)``, integers)."""
        index = jnp.asarray(index)
        return jnp.asarray(self.lo) + jnp.asarray(self.spacing) * index

    def contains(self, state):
        """True where ``state`` lies inside the bounds of every non-periodic dimension."""
        state = jnp.asarray(state)
        inside = (state >= jnp.asarray(self.lo, state.dtype)) & (state <= jnp.asarray(self.hi, state.dtype))
        return jnp.all(inside | jnp.asarray(self.is_periodic), axis=-1)

    def boundary_faces_min(self, values) -> float:
        """Minimum of ``values`` over the faces of the non-periodic dimensions.

        A reachable set computed on this grid is trustworthy only if this is positive: the set must not touch
        the boundary (see docs/numerics.md)."""
        values = np.asarray(values)
        mins = []
        for i in range(self.ndim):
            if self.is_periodic[i]:
                continue
            mins.append(np.take(values, 0, axis=i).min())
            mins.append(np.take(values, -1, axis=i).min())
        return float(min(mins)) if mins else float("inf")

    def check_values(self, values, name: str = "values") -> None:
        """Raises a clear error if ``values`` does not match the grid or contains NaN."""
        shape = tuple(np.shape(values))
        if shape != self.shape:
            raise ValueError(f"{name} has shape {shape}, but the grid has shape {self.shape}.")
        if isinstance(values, jax.core.Tracer):
            return  # inside jit: only the (static) shape can be checked
        arr = np.asarray(values)
        if np.isnan(arr).any():
            raise ValueError(f"{name} contains NaN at {int(np.isnan(arr).sum())} grid point(s); "
                             "values must be finite or +/-inf.")

"""Pytrees packed into one int32 array: how an adapter crosses the host-device boundary once per call.

An adapter that steps one environment per call (the PettingZoo envs, the single Gymnasium intruder env) pays for every
array that enters or leaves a jitted call: on a CPU each output is a new device array object (about 2 us), each
typed PRNG key also a Python wrapper (about 17 us), each fetched output its own device-to-host copy (about 30 us),
measured on the town step whose own work is a few hundred microseconds. So a step's outputs are returned as one
packed array (:func:`pack`) that the host unpacks with numpy views (:meth:`Layout.unpack`), and what the step
carries to the next call (the key and the state) stays on the device as another (:class:`DeviceCarry`), which the
step unpacks inside ``jit`` (:meth:`Layout.unpack_traced`) and packs again. Packing only bit-casts, pads and
slices: every value comes back bit for bit (tests/test_env.py checks a packed step against the unpacked one).
"""

from __future__ import annotations

import functools
import math
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.sim.jit import sim_jit


def _is_key(x) -> bool:
    return jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key)


@functools.cache
def _key_data(dtype) -> tuple[tuple, np.dtype]:
    """The trailing shape and dtype of the data of one PRNG key of ``dtype`` (traced once per key type: a trace
    at every reset was a third of the PettingZoo env's reset)."""
    data = jax.eval_shape(jax.random.key_data, jax.ShapeDtypeStruct((), dtype))
    return tuple(data.shape), np.dtype(data.dtype)


_UNSIGNED = {1: jnp.uint8, 2: jnp.uint16}
"""The unsigned type of each narrow width: a narrow leaf's bytes travel as these (bools as 0 and 1)."""


def _words(n: int, dtype: np.dtype) -> int:
    """The int32 words ``n`` elements of ``dtype`` take packed: their bytes, rounded up to whole words."""
    return -(-n * dtype.itemsize // 4)


class Layout(NamedTuple):
    """How :func:`pack` laid a pytree out: its structure and, per leaf, ``(shape, dtype, words, key_shape)``
    (``key_shape``: the trailing shape of a typed PRNG key's data, ``None`` for other leaves; ``dtype`` is then
    the data's), the PRNG implementation of its keys (``None`` without keys) and the packed array's length."""

    treedef: Any
    leaves: tuple
    key_impl: str | None = None
    words: int = 0

    @classmethod
    def of(cls, tree, key_impl: str | None = None) -> Layout:
        """The layout of ``tree`` (arrays or ``jax.ShapeDtypeStruct`` leaves, e.g. from ``jax.eval_shape``). The
        PRNG implementation of typed key leaves is read from concrete keys, or given as ``key_impl`` (abstract
        ones carry none); every key of one tree has the same."""
        leaves, treedef = jax.tree.flatten(tree)
        out, impls = [], set() if key_impl is None else {str(key_impl)}
        for x in leaves:
            key_shape = None
            if _is_key(x):
                if isinstance(x, jax.Array):
                    impls.add(str(jax.random.key_impl(x)))
                elif key_impl is None:
                    raise ValueError("an abstract PRNG key leaf has no implementation to record; pass key_impl or "
                                     "concrete keys.")
                key_shape, dtype = _key_data(x.dtype)
                shape = tuple(x.shape)
                n = math.prod(shape + key_shape)
            else:
                dtype, shape = np.dtype(x.dtype), tuple(x.shape)
                n = math.prod(shape)
            out.append((shape, dtype, _words(n, dtype), key_shape))
        if len(impls) > 1:
            raise ValueError(f"the tree's PRNG keys have different implementations {sorted(impls)}.")
        return cls(treedef, tuple(out), impls.pop() if impls else None, sum(n for _, _, n, _ in out))

    def unpack(self, words: np.ndarray):
        """The pytree from the host copy of :func:`pack`'s array. ``words`` is copied once; the leaves are views
        of that copy (writable, each its own bytes: no conversion, so a leaf costs one array header). Trees with
        PRNG keys are unpacked on the device (:meth:`unpack_traced`)."""
        words = np.array(words, np.int32, copy=True)
        if words.shape != (self.words,):
            raise ValueError(f"packed step output of shape {words.shape}; the layout needs ({self.words},).")
        out, offset = [], 0
        for shape, dtype, n, key_shape in self.leaves:
            if key_shape is not None:
                raise ValueError("a tree with PRNG keys is unpacked on the device (Layout.unpack_traced).")
            out.append(np.ndarray(shape, dtype, words, offset))
            offset += 4 * n
        return jax.tree.unflatten(self.treedef, out)

    def unpack_traced(self, words: jax.Array):
        """The pytree from :func:`pack`'s array on the device (inside ``jit``; slices, bit casts and
        comparisons: every value as packed, bit for bit)."""
        if words.shape != (self.words,) or words.dtype != jnp.int32:
            raise ValueError(f"packed array of shape {words.shape} and dtype {words.dtype}; the layout needs "
                             f"({self.words},) int32.")
        out, i = [], 0
        for shape, dtype, n, key_shape in self.leaves:
            chunk = jax.lax.slice_in_dim(words, i, i + n)
            i += n
            if dtype.itemsize < 4:  # the leaf's bytes, padded to whole words (pack)
                per_word = 4 // dtype.itemsize
                raw = jax.lax.bitcast_convert_type(chunk, _UNSIGNED[dtype.itemsize]).reshape(n * per_word)
                raw = raw[:math.prod(shape)]
                x = (raw != 0) if dtype == np.bool_ else jax.lax.bitcast_convert_type(raw, dtype)
                x = x.reshape(shape)
            elif dtype.itemsize == 4:
                x = jax.lax.bitcast_convert_type(chunk, dtype).reshape(shape + (key_shape or ()))
            else:
                x = jax.lax.bitcast_convert_type(chunk.reshape(-1, dtype.itemsize // 4), dtype).reshape(shape)
            if key_shape is not None:
                x = jax.random.wrap_key_data(x, impl=self.key_impl)
            out.append(x)
        return jax.tree.unflatten(self.treedef, out)


def pack(tree):
    """Every leaf of ``tree`` as int32 words in one flat array: its bytes as they are in memory (4- and 8-byte
    leaves bit-cast; bools, as bytes 0 and 1, and narrower leaves padded to whole words; typed PRNG keys as their
    data), so that the host reads each leaf as a view (:meth:`Layout.unpack`); :meth:`Layout.unpack_traced`
    inverts it on the device."""
    parts = []
    for x in jax.tree.leaves(tree):
        if _is_key(x):
            x = jax.random.key_data(x)
        x = jnp.ravel(x)
        if x.dtype.itemsize < 4:  # bools and narrow leaves as their bytes, padded to whole words
            per_word = 4 // x.dtype.itemsize
            raw = (x.astype(jnp.uint8) if x.dtype == jnp.bool_
                   else jax.lax.bitcast_convert_type(x, _UNSIGNED[x.dtype.itemsize]))
            raw = jnp.pad(raw, (0, -raw.shape[0] % per_word))
            parts.append(jax.lax.bitcast_convert_type(raw.reshape(-1, per_word), jnp.int32))
        else:
            parts.append(jnp.ravel(jax.lax.bitcast_convert_type(x, jnp.int32)))
    return jnp.concatenate(parts) if parts else jnp.zeros((0,), jnp.int32)


_pack_jit = sim_jit(pack)
_unpack_jit = sim_jit(lambda words, layout: layout.unpack_traced(words), static_argnames=("layout",))


class DeviceCarry:
    """A pytree (an environment's key and state) kept packed on the device between jitted calls.

    ``set(tree)`` packs a tree (after a reset, or a change made on the host); ``advance(fn, *args, **static)``
    calls ``fn(words, *args, layout=layout, **static)``, which returns ``(words, output)`` or ``(words, output,
    tree)`` (the new tree also unpacked), keeps the new words and returns the output; ``tree`` (the user's reads)
    and ``unpacked()`` (the caller's own) are the unpacked tree (one device call after an ``advance`` that did not
    return it, then kept). ``was_read``: whether ``tree`` was read since the last ``advance`` or ``set``, so that a
    caller whose user reads it after every step can have the step return it."""

    def __init__(self):
        self.words: jax.Array | None = None
        self.layout: Layout | None = None
        self._tree = None
        self.was_read = False

    def set(self, tree) -> None:
        self.layout = Layout.of(tree)
        self.words = _pack_jit(tree)
        self._tree = tree
        self.was_read = False

    def advance(self, fn, *args, **static):
        if self.words is None:
            raise RuntimeError("the carry is empty: set() it (reset the environment) first.")
        result = fn(self.words, *args, layout=self.layout, **static)
        self.words, out = result[0], result[1]
        self._tree = result[2] if len(result) == 3 else None
        self.was_read = False
        return out

    @property
    def tree(self):
        """The unpacked tree, as the user reads it (sets ``was_read``); ``None`` before the first ``set``."""
        if self.words is not None:
            self.was_read = True
        return self.unpacked()

    def unpacked(self):
        """The unpacked tree for the caller's own use (does not set ``was_read``)."""
        if self.words is None:
            return None
        if self._tree is None:
            self._tree = _unpack_jit(self.words, layout=self.layout)
        return self._tree

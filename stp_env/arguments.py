"""One set of argument checks for every entry point: the command line (:mod:`stp_env.cli_kit` wraps these as
argparse types), the configurations, the environments and the loaders of files (events, counterexamples,
checkpoints) use the same functions and the same ranges, which are those the code can compute.

* Integers are Python or NumPy integers, never booleans, floats (even integral ones) or strings; reals are finite
  Python or NumPy reals, never booleans or strings.
* Seeds: :func:`stp_env.seeds.check_seed` (``[0, 2**63 - 1]``, each its own PRNG key).
* Counts that reach JAX (episodes, batch sizes, indices, steps) are at most :data:`INT32_MAX`: without 64-bit mode
  JAX holds integers as ``int32``.
* ``k̄``: :data:`MAX_KBAR`.

Every check raises a one-line ``ValueError`` that names the argument, the range and the value. This module imports
nothing heavy (no JAX, no NumPy), so that the command line can use it cheaply.
"""

from __future__ import annotations

import math
import numbers

INT32_MAX = 2**31 - 1
"""The largest count or index any entry point takes: JAX without 64-bit mode holds integers as ``int32``."""

MAX_KBAR = 1000
"""The largest ``k̄`` (the number of vehicles an intruder may force to avoid) accepted anywhere. It counts vehicles (the
largest scenario has 200), and the buffer horizon ``t_BRD = t_IAT / k̄`` it sets stays at least a thousandth of
``t_IAT`` (10 ms at the papers' 10 s), which the solver resolves."""

MAX_SPEED = 1000.0
"""The largest wind or speed [m/s] accepted anywhere (options, configurations, scenarios, events): three times the
speed of sound, far beyond any vehicle or wind the papers model, and small enough that the solver's and the
simulator's float32 arithmetic stays finite."""

__all__ = ["INT32_MAX", "MAX_KBAR", "MAX_SPEED", "check_int", "check_kbar", "check_real", "contains_bool",
           "parse_spec", "show"]


def show(value) -> str:
    """``repr(value)``, short: a huge integer is described by its size (``repr`` of one over 4,300 digits fails),
    a long text cut."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool) and abs(int(value)) >= 10**30:
        return f"an integer of {int(value).bit_length()} bits"
    text = repr(value)
    return text if len(text) <= 80 else text[:60] + "..." + text[-10:]


def _range(lo, hi, lo_open=False, hi_open=False) -> str:
    if hi == INT32_MAX and lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g} (at most 2**31 - 1)"
    if lo is not None and hi is not None:
        return f"in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    if lo is not None:
        return f"{'>' if lo_open else '>='} {lo:g}"
    if hi is not None:
        return f"{'<' if hi_open else '<='} {hi:g}"
    return ""


def check_int(value, name: str, lo: int | None = None, hi: int | None = INT32_MAX) -> int:
    """``value`` as a Python ``int`` if it is an integer (not a boolean, float or string) in ``[lo, hi]``;
    ``ValueError`` naming ``name`` otherwise. ``hi`` defaults to :data:`INT32_MAX`."""
    ok = isinstance(value, numbers.Integral) and not isinstance(value, bool) and type(value).__name__ != "bool_"
    if ok:
        v = int(value)
        if (lo is None or v >= lo) and (hi is None or v <= hi):
            return v
    where = _range(lo, hi)
    raise ValueError(f"{name} must be an integer{' ' + where if where else ''}; got {show(value)}"
                     f"{'' if ok else f' ({type(value).__name__})'}.")


def check_real(value, name: str, lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
               hi_open: bool = False) -> float:
    """``value`` as a Python ``float`` if it is a finite real number (not a boolean or string) in the range
    (``lo`` / ``hi`` closed unless ``lo_open`` / ``hi_open``); ``ValueError`` naming ``name`` otherwise."""
    ok = isinstance(value, numbers.Real) and not isinstance(value, bool) and type(value).__name__ != "bool_"
    if ok:
        try:
            v = float(value)
        except OverflowError:  # an integer beyond the float range
            v = math.inf
        if math.isfinite(v) and (lo is None or (v > lo if lo_open else v >= lo)) and (
                hi is None or (v < hi if hi_open else v <= hi)):
            return v
    where = _range(lo, hi, lo_open, hi_open)
    raise ValueError(f"{name} must be a finite number{' ' + where if where else ''}; got {show(value)}"
                     f"{'' if ok else f' ({type(value).__name__})'}.")


def contains_bool(value) -> bool:
    """Whether ``value`` is a boolean, or a list, tuple or array holding one (``True`` is not the number 1 where a
    number is expected; NumPy turns ``[True, 0.5]`` into ``[1.0, 0.5]`` without a word)."""
    if isinstance(value, bool) or type(value).__name__ == "bool_":
        return True
    dtype = getattr(value, "dtype", None)
    if dtype is not None:
        return getattr(dtype, "kind", "") == "b" or (getattr(dtype, "kind", "") == "O" and any(
            contains_bool(v) for v in getattr(value, "flat", ())))
    if isinstance(value, (list, tuple)):
        return any(contains_bool(v) for v in value)
    return False


def check_kbar(value, name: str = "kbar") -> int:
    """``k̄``: an integer in ``[1, MAX_KBAR]`` (:data:`MAX_KBAR`)."""
    return check_int(value, name, 1, MAX_KBAR)


def parse_spec(spec, what: str, names, fields) -> tuple[str, dict[str, float]]:
    """``(name, {param: value})`` of a component spec ``"name"`` or ``"name:param=value,..."`` (wind models, plant
    backends): ``name`` one of ``names``, each ``param`` one of ``fields(name)`` (called only when the spec has
    parameters), each value a finite number. A one-line ``ValueError`` naming ``what`` and the spec otherwise; the
    component checks its parameters' ranges itself."""
    if not isinstance(spec, str):
        raise ValueError(f"{what} must be a string 'name' or 'name:param=value,...'; got {show(spec)}.")
    names = list(names)
    name, _, rest = spec.partition(":")
    if name not in names:
        raise ValueError(f"unknown {what} {name!r}; allowed: {', '.join(names)}.")
    values: dict[str, float] = {}
    items = [item.strip() for item in rest.split(",") if item.strip()]
    allowed = sorted(fields(name)) if items else []
    for item in items:
        key, eq, text = (part.strip() for part in item.partition("="))
        if not eq or key not in allowed:
            raise ValueError(f"{what} {spec!r}: {item!r} is not param=value with a parameter of {name!r} "
                             f"(parameters: {', '.join(allowed) or 'none'}).")
        try:
            number = float(text)
        except ValueError:
            number = None
        if number is None or not math.isfinite(number):
            raise ValueError(f"{what} {spec!r}: {key} must be a finite number; got {text!r}.")
        values[key] = number
    return name, values

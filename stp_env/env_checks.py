"""What the PettingZoo adapter (:mod:`stp_env.env`) accepts, checked in one place before anything changes: a
vehicle policy passed as a function, the intruder's appearance window, ``reset`` options and the actions of
``step`` (each with a ``ValueError`` that names what is wrong; docs/environment.md, "Actions" and "Seeds and
options")."""

from __future__ import annotations

import dataclasses
import numbers
import reprlib

import gymnasium
import jax
import jax.numpy as jnp
import numpy as np

from stp_env.arguments import contains_bool
from stp_env.sim import core
from stp_env.sim.backends import with_backend
from stp_env.sim.config import EnvConfig


def clip_unit(x: np.ndarray) -> np.ndarray:
    """``np.clip(x, -1, 1)`` of finite ``x`` as two ufuncs (the same values; ``np.clip``'s Python wrapper cost a
    third of parsing the town's actions)."""
    return np.minimum(np.maximum(x, -1.0), 1.0)


def check_flags(*, keep_finished, render_mode, modes) -> None:
    """``keep_finished`` a bool, ``render_mode`` one of ``modes`` or ``None``."""
    if not isinstance(keep_finished, bool):
        raise ValueError(f"keep_finished must be True or False; got {keep_finished!r}.")
    if render_mode is not None and render_mode not in modes:
        raise ValueError(f"render_mode {render_mode!r} is not supported; allowed: {modes} or None.")


def check_max_cycles(max_cycles) -> int:
    """A positive integer number of steps."""
    if isinstance(max_cycles, bool) or not isinstance(max_cycles, (int, np.integer)) or max_cycles < 1:
        raise ValueError(f"max_cycles must be a positive integer; got {max_cycles!r}.")
    return int(max_cycles)


def env_config(config, overrides: dict, *, spawn: str | None, backend) -> EnvConfig:
    """The environment's :class:`EnvConfig`: ``config`` (default: where a scripted intruder appears by default,
    ``spawn``, when no ``spawn_mode`` is given) with the fields given by name (``overrides``; ``TypeError`` naming
    an unknown one) and the ``backend``'s plant."""
    if config is not None and not isinstance(config, EnvConfig):
        raise ValueError(f"config must be a stp_env.sim.EnvConfig; got {type(config).__name__}.")
    if config is None and spawn is not None and "spawn_mode" not in overrides:
        config = EnvConfig(spawn_mode=spawn)
    config = EnvConfig() if config is None else config
    if overrides:
        fields = {f.name for f in dataclasses.fields(EnvConfig)}
        unknown = sorted(set(overrides) - fields)
        if unknown:
            raise TypeError(f"parallel_env() got unexpected keyword argument(s) {unknown}; besides its own "
                            f"arguments it takes the fields of stp_env.sim.EnvConfig: {sorted(fields)}.")
        config = config.with_overrides(**overrides)
    return with_backend(config, backend)


def check_vehicle_policy(policy, params) -> None:
    """A vehicle policy passed as a function: traced once abstractly on the env's state (nothing computed), it
    must return the vehicles' actions ``(N, action_dim)`` as floats; ``ValueError`` saying what it returned."""
    key = jax.random.key(0)
    name = getattr(policy, "__name__", repr(policy))
    try:
        out = jax.eval_shape(policy, key, jax.eval_shape(core.reset, key, params), params)
    except Exception as err:  # anything the trace raises: the message says which policy and why
        raise ValueError(f"vehicle_policy {name!r} is not a jittable function (key, state, params) -> actions: "
                         f"{type(err).__name__}: {err}") from err
    want = (params.vehicles.n, params.vehicles.model.action_dim)
    shape, dtype = getattr(out, "shape", None), getattr(out, "dtype", None)
    if shape is None or tuple(shape) != want or not jnp.issubdtype(dtype, jnp.floating):
        got = f"shape {tuple(shape)}, dtype {dtype}" if shape is not None else type(out).__name__
        raise ValueError(f"vehicle_policy {name!r} must return the vehicles' actions, floats of shape {want} (one "
                         f"row per vehicle, in [-1, 1]); it returned {got}.")


def check_appear_window(params) -> None:
    """The intruder's appearance window must lie within the episode ``[t_start, t_end]``."""
    lo, hi = (float(v) for v in np.asarray(params.intruder.appear_window))
    t0, t1 = float(params.episode.t_start), float(params.episode.t_end)
    if not (np.isfinite(lo) and np.isfinite(hi) and t0 - 1e-3 <= lo <= hi <= t1 + 1e-3):
        raise ValueError(f"the intruder's appearance window [{lo:.2f}, {hi:.2f}] s (plan time; "
                         "EnvConfig.appear_window is relative to the first departure) is not within the episode "
                         f"[{t0:.2f}, {t1:.2f}] s: the intruder would appear before the episode starts or after it "
                         "ends.")


def check_reset_options(options, params) -> float | None:
    """The ``appear_time`` option of ``reset`` (``None`` if not given), checked against the episode of ``params``;
    unknown options are warned about (PettingZoo's API test passes arbitrary options and expects them ignored)."""
    if options is None:
        return None
    if not isinstance(options, dict):
        raise ValueError(f"options must be a dict (e.g. {{'appear_time': seconds}}) or None; got "
                         f"{type(options).__name__}.")
    unknown = sorted(map(repr, set(options) - {"appear_time"}))
    if unknown:
        gymnasium.logger.warn(f"ignoring unknown reset option(s) {', '.join(unknown)}; known: 'appear_time' "
                              "(seconds, plan time).")
    if "appear_time" not in options:
        return None
    t = options["appear_time"]
    if isinstance(t, (bool, np.bool_)) or not isinstance(t, numbers.Real):
        raise ValueError(f"appear_time must be a real number of seconds (plan time); got {t!r} "
                         f"({type(t).__name__}).")
    t = float(t)
    if not np.isfinite(t):
        raise ValueError(f"appear_time must be finite; got {t}.")
    lo, hi = float(params.episode.t_start), float(params.episode.t_end)
    if not lo <= t <= hi:
        raise ValueError(f"appear_time {t} s is outside the episode [{lo:.2f}, {hi:.2f}] s (plan time): the "
                         "intruder would appear before the episode starts or after it ends.")
    return t


class ActionChecker:
    """The actions of a ``step`` as one array ``(N + 1, width)`` for the core (row ``index[agent]``), every action
    checked: ``possible`` the episode's agents, ``action_dims`` each agent's action size. ``ValueError`` naming the
    agent for an unknown or finished agent, anything but finite real numbers, or a wrong shape; out-of-range values
    are clipped; a live agent left out (or ``None``) applies the zero action."""

    def __init__(self, possible, index: dict[str, int], n_vehicles: int, vehicle_action_dim: int):
        self.possible = list(possible)
        self.index = index
        self.n = n_vehicles
        self.vehicle_dim = vehicle_action_dim

    def action_dim(self, agent) -> int:
        """The intruder flies Dubins (speed, turn rate); the vehicles' action size is their model's."""
        return 2 if agent == "intruder" else self.vehicle_dim

    def check(self, agent, a, live) -> np.ndarray | None:
        """The action of a live ``agent`` as a clipped float32 array (``None``: the zero action);
        ``ValueError`` naming the agent for anything else."""
        if agent not in self.possible:
            raise ValueError(f"action for unknown agent {agent!r}; agents are {self.possible}.")
        if agent not in live:
            raise ValueError(f"action for {agent!r}, which has finished (terminated or truncated); "
                             f"live agents: {list(live)}.")
        if a is None:
            return None
        try:
            arr = np.asarray(a)
        except (TypeError, ValueError) as err:
            raise ValueError(f"action for {agent!r} is not an array of numbers ({err}).") from None
        if arr.dtype.kind not in "iuf" or contains_bool(a):  # [True, 0.5] reads as [1.0, 0.5] in NumPy
            raise ValueError(f"action for {agent!r} must be real numbers (speed, turn rate in [-1, 1]); got "
                             f"{reprlib.repr(a)} (dtype {arr.dtype}).")
        shape = (self.action_dim(agent),)
        if arr.shape != shape:
            raise ValueError(f"action for {agent!r} must have shape {shape} (in [-1, 1]; Dubins: speed, turn rate); "
                             f"got shape {arr.shape}.")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"action for {agent!r} is not finite: {arr.tolist()}; actions must be finite numbers "
                             "in [-1, 1] (out-of-range values are clipped).")
        return np.clip(arr, -1.0, 1.0).astype(np.float32)

    def parse(self, actions, live) -> np.ndarray:
        """The step's action array from the dict ``actions`` of the agents ``live``."""
        if not isinstance(actions, dict):
            raise ValueError(f"actions must be a dict {{agent: action}}; got {type(actions).__name__}.")
        arr = np.zeros((self.n + 1, max(2, self.vehicle_dim)), np.float32)
        if self._parse_plain(actions, arr, live):
            return arr
        for agent, a in actions.items():  # the general path: every action checked on its own, errors named
            checked = self.check(agent, a, live)
            if checked is not None:
                arr[self.index[agent], :checked.shape[0]] = checked
        return arr

    def _parse_plain(self, actions, arr, live) -> bool:
        """The common case in one vectorised check: every action a finite float ``np.ndarray`` of its agent's
        shape, for a live agent; clipped into ``arr``. ``False`` (``arr`` untouched) for anything else, which the
        general path then accepts (lists, ``None``, ints) or rejects with a message naming the agent. The same
        result as the general path, with one finiteness check and one clip per action size instead of one per
        agent (the per-agent checks were a third of an adapter step for the city's 51 agents)."""
        live, index = set(live), self.index
        vehicle_shape = (self.vehicle_dim,)
        rows, values = [], []
        for agent, a in actions.items():
            if type(a) is not np.ndarray or a.dtype.kind != "f" or agent not in live or \
                    a.shape != ((2,) if agent == "intruder" else vehicle_shape):
                return False
            rows.append(index[agent])
            values.append(a)
        if not values:
            return True
        if vehicle_shape == (2,):  # one action size for every agent (Dubins vehicles)
            stacked = np.asarray(values, np.float64)
            if not np.isfinite(stacked).all():
                return False
            arr[rows, :2] = clip_unit(stacked)
            return True
        groups: dict[int, tuple[list, list]] = {}
        for row, a in zip(rows, values):
            group = groups.setdefault(a.shape[0], ([], []))
            group[0].append(row)
            group[1].append(a)
        stacked = {dim: np.asarray(group[1], np.float64) for dim, group in groups.items()}
        if not all(np.isfinite(v).all() for v in stacked.values()):
            return False
        for dim, (group_rows, _) in groups.items():
            arr[group_rows, :dim] = clip_unit(stacked[dim])
        return True

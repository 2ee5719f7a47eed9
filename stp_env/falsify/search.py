"""Batched black-box and gradient search for the input that maximises an objective (falsification).

An attack (one module each: :mod:`~stp_env.falsify.tracking`, :mod:`~stp_env.falsify.avoidance`,
:mod:`~stp_env.falsify.kbar`) is a jittable objective ``f(z) -> scalar`` of a point ``z`` of the unit
box ``[0, 1]^dim``, which it maps to physical inputs (reference controls, winds, intruder controls, spawn states).
Larger is worse for the system under test. Two searchers share one budget of objective evaluations:

* :func:`cross_entropy`: the cross-entropy method with independent restarts: every restart keeps a Gaussian per
  coordinate, samples a population, refits mean and deviation to the elite fraction, and shrinks toward it. All
  restarts and all samples of an iteration run as one ``vmap`` (one compiled program).
* :func:`gradient_ascent`: Adam on ``z = sigmoid(y)`` from random starts (all starts in one ``vmap``), through the
  differentiable JAX core. Bang-bang controllers make the objective piecewise smooth; the gradient flows through
  the dynamics and the disturbances, which is what the attacker controls.

Both return a :class:`SearchResult` with the best point, its value and the history of the best value, and are
deterministic functions of their key.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.sim import engine
from stp_env.sim.jit import sim_jit
from stp_env.sim.types import EnvParams

Objective = Callable[[jax.Array], jax.Array]


@dataclasses.dataclass(frozen=True, kw_only=True)
class SearchConfig:
    """How to search.

    Attributes:
        method: ``"cem"`` (cross-entropy), ``"gradient"`` (Adam through the core) or ``"both"`` (half the budget
            each; the gradient starts include the cross-entropy result).
        budget: objective evaluations in all (each one is a simulated attack).
        population: samples per cross-entropy iteration and restart.
        restarts: independent cross-entropy searches (and gradient starts per population).
        elite_fraction: share of each population the cross-entropy method refits to.
        smoothing: weight of the old distribution in the refit (0: plain refit).
        min_std: floor of the cross-entropy deviation (keeps exploring).
        learning_rate: Adam step in the unconstrained coordinates.
        batch: attacks evaluated at once (memory: the core's state times ``batch``).
    """

    method: str = "cem"
    budget: int = 10_000
    population: int = 250
    restarts: int = 4
    elite_fraction: float = 0.1
    smoothing: float = 0.3
    min_std: float = 0.02
    learning_rate: float = 0.1
    batch: int = 1000

    def __post_init__(self) -> None:
        if self.method not in ("cem", "gradient", "both"):
            raise ValueError(f"method must be 'cem', 'gradient' or 'both'; got {self.method!r}.")
        for name in ("budget", "population", "restarts", "batch"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
                raise ValueError(f"{name} must be an integer >= 1; got {value!r}.")
        if not 0 < self.elite_fraction <= 0.5:
            raise ValueError(f"elite_fraction must lie in (0, 0.5]; got {self.elite_fraction}.")
        if not 0 <= self.smoothing < 1:
            raise ValueError(f"smoothing must lie in [0, 1); got {self.smoothing}.")
        if not (0 < self.min_std < 0.5 and 0 < self.learning_rate < 10):
            raise ValueError(f"min_std must lie in (0, 0.5) and learning_rate in (0, 10); got {self.min_std}, "
                             f"{self.learning_rate}.")


@dataclasses.dataclass(frozen=True)
class SearchResult:
    """Outcome of a search.

    Attributes:
        best_z: the worst input found, shape ``(dim,)`` in ``[0, 1]``.
        best_value: the objective there.
        history: the best value after each iteration (cross-entropy) or step (gradient).
        evaluations: objective evaluations used.
        values: every evaluated objective value (for the distribution of attacks).
        samples: the evaluated points, ``(len(values), dim)`` in the order of ``values`` (to replay any of them).
    """

    best_z: np.ndarray
    best_value: float
    history: tuple[float, ...]
    evaluations: int
    values: np.ndarray
    samples: np.ndarray | None = None


TABLE_FIELDS = {"tables": ("avoid_values", "tracking_table", "sdf"),
                "vehicles": ("nominal_states", "nominal_controls")}
"""The large arrays of an attack's environment (``attack.base``): :func:`compiled` passes them to the compiled
program as arguments. Closed over, they would be baked into it as constants (the avoid table alone is tens of
megabytes), which makes XLA's compilation very slow."""


def compiled(objective: Objective, transform=engine.vmap_across_devices):
    """``sim_jit(transform(objective))`` (by default ``vmap``, the batch shared among the devices:
    :func:`stp_env.sim.engine.vmap_across_devices`), compiled once per call of this function. When ``objective`` is
    a method of an attack whose ``base`` holds the environment, the :data:`TABLE_FIELDS` of ``base`` are arguments of
    the compiled program rather than constants in it (same values, same results)."""
    attack = getattr(objective, "__self__", None)
    base = getattr(attack, "base", None)
    if not isinstance(base, EnvParams):
        return sim_jit(transform(objective))
    name = objective.__name__
    tables = {g: {k: getattr(getattr(base, g), k) for k in keys} for g, keys in TABLE_FIELDS.items()}

    def run(tables, x):
        traced = copy.copy(attack)  # the same attack, its environment's tables traced
        object.__setattr__(traced, "base", base.replace(**tables))
        return transform(getattr(traced, name))(x)

    return functools.partial(sim_jit(run), tables)


def evaluate(objective: Objective, zs, batch: int, *, program=None) -> np.ndarray:
    """``objective`` at each row of ``zs`` ``(M, dim)``, ``batch`` rows at a time (one compiled program:
    ``program``, from :func:`compiled`, or compiled here)."""
    zs = jnp.asarray(zs, jnp.float32)
    f = compiled(objective) if program is None else program
    out = []
    for i in range(0, zs.shape[0], batch):
        chunk = zs[i:i + batch]
        pad = batch - chunk.shape[0] if zs.shape[0] > batch else 0
        if pad:  # keep one shape: no recompilation for the last chunk
            chunk = jnp.concatenate([chunk, jnp.repeat(chunk[-1:], pad, axis=0)])
        vals = np.asarray(f(chunk), np.float64)
        out.append(vals[:vals.shape[0] - pad])
    return np.concatenate(out) if out else np.zeros((0,))


SEED_STD = 0.1
"""Initial deviation of a cross-entropy restart started from a seed (a game's worst strategy): the search looks
around it first."""


def _check_seeds(seeds, dim: int) -> np.ndarray:
    seeds = np.atleast_2d(np.asarray(seeds, np.float64))
    if seeds.ndim != 2 or seeds.shape[1] != dim or not np.all(np.isfinite(seeds)) \
            or np.any((seeds < 0) | (seeds > 1)):
        raise ValueError(f"seeds must be points of [0, 1]^{dim}; got an array of shape {seeds.shape}.")
    return seeds


@dataclasses.dataclass(frozen=True)
class SearchContext:
    """What every restart of a search shares (the context of its job): the objective (an attack shipped with its
    environment as host arrays, :func:`ship`, or a module-level function), the search's key data and settings, and
    the starting points (cross-entropy seeds; the gradient's starts)."""

    token: str
    objective: Any
    dim: int
    key_data: np.ndarray
    config: SearchConfig
    steps: int
    seeds: np.ndarray | None = None
    starts: np.ndarray | None = None


def ship(objective: Objective):
    """``objective`` as it travels to a worker: an attack's method as ``(attack with its environment as host
    arrays, method name)`` (:func:`stp_env.execution.to_host`), anything else as it is."""
    from stp_env import execution

    attack = getattr(objective, "__self__", None)
    if not isinstance(getattr(attack, "base", None), EnvParams):
        return objective
    shipped = copy.copy(attack)
    object.__setattr__(shipped, "base", execution.to_host(attack.base))
    return shipped, objective.__name__


def landed(shipped) -> Objective:
    """The inverse of :func:`ship` (the environment's arrays back on the device, exactly)."""
    from stp_env import execution

    if not isinstance(shipped, tuple):
        return shipped
    attack, name = shipped
    attack = copy.copy(attack)
    object.__setattr__(attack, "base", execution.to_device(attack.base))
    return getattr(attack, name)


def _fingerprint(kind: str, context: SearchContext) -> str:
    from stp_env import execution
    from stp_env.evaluation.report import source_hash

    shipped = context.objective
    if isinstance(shipped, tuple):
        attack, name = shipped
        what = [type(attack).__qualname__, name, {f.name: repr(getattr(attack, f.name))
                                                  for f in dataclasses.fields(attack) if f.name != "base"},
                attack.base]
    else:
        what = [getattr(shipped, "__module__", ""), getattr(shipped, "__qualname__", repr(shipped))]
    shares = engine.shares(context.config.batch)  # another count is another program (left out at one)
    return execution.digest(kind, what, context.dim, context.key_data, dataclasses.asdict(context.config),
                            context.steps, context.seeds, context.starts, source_hash(),
                            *([shares] if shares > 1 else []))


def _search_job(kind: str, function, context: SearchContext, units: int, resumable: bool):
    from stp_env import execution

    restarts = context.config.restarts
    return execution.Job(name=f"falsify-{kind}", function=function, context=context, arguments=tuple(range(restarts)),
                         fingerprint=_fingerprint(kind, context) if resumable else None,
                         units=(units,) * restarts)


def _run(job, executor, out_dir, progress) -> list[dict]:
    from stp_env.execution import check_executor

    return check_executor(executor).run(job, out_dir=out_dir, progress=None if progress is None else progress.update)


def _combine(pieces: list[dict], evaluations: int, default_z) -> SearchResult:
    """A search's result from its restarts' (in restart order), as the one batched loop over every restart found
    it: per iteration, the first restart with the best value of the iteration is kept when it beats the best so
    far; the values iteration by iteration, restarts in order within each."""
    best_v, best_z, history = -math.inf, None, []
    for t in range(pieces[0]["best_values"].shape[0]):
        for piece in pieces:
            if piece["best_values"][t] > best_v:
                best_v, best_z = float(piece["best_values"][t]), piece["best_z"][t].copy()
        history.append(best_v)
    values = np.concatenate([p["values"] for p in pieces], axis=1).ravel()
    samples = np.concatenate([p["samples"] for p in pieces], axis=1)
    return SearchResult(best_z=default_z if best_z is None else best_z, best_value=best_v, history=tuple(history),
                        evaluations=evaluations, values=values, samples=samples.reshape(-1, samples.shape[-1]))


def cross_entropy(objective: Objective, dim: int, key, config: SearchConfig, *, budget: int | None = None,
                  progress=None, seeds=None, executor=None, out_dir=None) -> SearchResult:
    """The cross-entropy method on ``[0, 1]^dim`` (see the module docstring). ``seeds`` ``(S, dim)``: the first
    ``min(S, restarts - 1)`` restarts start from them (mean at the seed, deviation :data:`SEED_STD`; the seed itself
    is the first sample of its restart), the others from the whole box, so that a seeded search also explores.

    The restarts are the pieces of one job (:mod:`stp_env.execution`; :func:`cem_restart`): ``executor`` runs them
    (default: in this process, in order), ``out_dir`` keeps the finished ones for a resumed run. Restart ``r``
    draws row ``r`` of the search's one stream of normal samples (every iteration draws ``(restarts, population,
    dim)`` from the key), so the samples are those of the search whatever runs it."""
    budget = config.budget if budget is None else budget
    iters = max(1, budget // (config.population * config.restarts))
    if seeds is not None:
        seeds = _check_seeds(seeds, dim)
        seeds = seeds[:min(len(seeds), max(config.restarts - 1, 1))]
    from stp_env import execution

    context = SearchContext(token=execution.new_token(), objective=ship(objective), dim=dim,
                            key_data=np.asarray(jax.random.key_data(key)), config=config, steps=iters, seeds=seeds)
    job = _search_job("cem", cem_restart, context, iters * config.population, out_dir is not None)
    pieces = _run(job, executor, out_dir, progress)
    return _combine(pieces, iters * config.population * config.restarts, np.full(dim, 0.5))


def _objective_and_program(context: SearchContext, what: str, transform=engine.vmap_across_devices):
    from stp_env import execution

    return execution.memo(context.token, what, lambda: (lambda f: (f, compiled(f, transform)))(
        landed(context.objective)))


def cem_restart(context: SearchContext, restart) -> dict:
    """Restart ``restart`` of a cross-entropy search (a piece of its job): per iteration its best value and the
    first sample that reached it (``best_values``, ``best_z``), every value (``values``, iteration by row) and the
    points evaluated (``samples``)."""
    config, dim, r = context.config, context.dim, int(restart)
    if not 0 <= r < config.restarts:
        raise ValueError(f"no restart {restart!r} in a search of {config.restarts}.")
    objective, program = _objective_and_program(context, "cem")
    pop, n_elite = config.population, max(2, math.ceil(config.elite_fraction * config.population))
    seeded = context.seeds is not None and r < len(context.seeds)
    mean = context.seeds[r].copy() if seeded else np.full(dim, 0.5)
    std = np.full(dim, SEED_STD if seeded else 0.3)
    rng = np.random.default_rng(np.asarray(context.key_data).ravel().astype(np.uint32))
    best_values, best_z, values, samples = [], [], [], []
    for it in range(context.steps):
        draw = rng.standard_normal((config.restarts, pop, dim))[r]  # the search's whole draw; this restart's row
        zs = np.clip(mean[None, :] + std[None, :] * draw, 0.0, 1.0)
        if it == 0 and seeded:
            zs[0] = context.seeds[r]
        vals = evaluate(objective, zs, config.batch, program=program)
        values.append(vals)
        samples.append(zs)
        finite = np.where(np.isfinite(vals), vals, -np.inf)
        j = int(np.argmax(finite))
        best_values.append(finite[j])
        best_z.append(zs[j].copy())
        elite = zs[np.argsort(-finite)[:n_elite]]
        a = config.smoothing
        mean = a * mean + (1 - a) * elite.mean(axis=0)
        std = np.maximum(a * std + (1 - a) * elite.std(axis=0), config.min_std)
    return {"best_values": np.asarray(best_values, np.float64), "best_z": np.asarray(best_z),
            "values": np.asarray(values, np.float64), "samples": np.asarray(samples, np.float64)}


GRADIENT_STARTS = 8
"""Random starts of the gradient ascent per restart."""


def gradient_ascent(objective: Objective, dim: int, key, config: SearchConfig, *, budget: int | None = None,
                    starts=None, progress=None, executor=None, out_dir=None) -> SearchResult:
    """Adam ascent of ``objective(sigmoid(y))`` from ``config.restarts * 8`` starts (plus ``starts``, points of
    ``[0, 1]^dim`` such as a cross-entropy result, in place of the last random ones), all drawn from ``key`` at
    once; each step costs one value-and-gradient evaluation per start (counted as one evaluation of the budget).

    Restart ``r`` ascends from starts ``8 r .. 8 r + 7`` (a piece of one job, :func:`gradient_restart`, run by
    ``executor``; ``out_dir`` as in :func:`cross_entropy`); every start's ascent is independent of the others."""
    budget = config.budget if budget is None else budget
    n_random = config.restarts * GRADIENT_STARTS
    z0 = np.asarray(jax.random.uniform(key, (n_random, dim)), np.float64)
    if starts is not None:
        z0 = np.concatenate([np.atleast_2d(np.asarray(starts, np.float64)), z0])[:max(n_random, 1)]
    z0 = np.clip(z0, 1e-3, 1 - 1e-3)
    n = z0.shape[0]
    steps = max(1, budget // n)
    from stp_env import execution

    context = SearchContext(token=execution.new_token(), objective=ship(objective), dim=dim,
                            key_data=np.asarray(jax.random.key_data(key)), config=config, steps=steps, starts=z0)
    job = _search_job("gradient", gradient_restart, context, steps * GRADIENT_STARTS, out_dir is not None)
    pieces = _run(job, executor, out_dir, progress)
    return _combine(pieces, steps * n, np.asarray(z0[0]))


def _value_and_grad(g):
    return engine.vmap_across_devices(jax.value_and_grad(lambda yy: g(jax.nn.sigmoid(yy))))


def gradient_restart(context: SearchContext, restart) -> dict:
    """Restart ``restart`` of a gradient ascent (a piece of its job): Adam from its starts; per step the best value
    and the point that reached it first (``best_values``, ``best_z``), every value (``values``) and the points
    evaluated (``samples``)."""
    config, r = context.config, int(restart)
    if not 0 <= r < config.restarts:
        raise ValueError(f"no restart {restart!r} in a search of {config.restarts}.")
    _, value_and_grad = _objective_and_program(context, "gradient", _value_and_grad)
    z0 = context.starts[r * GRADIENT_STARTS:(r + 1) * GRADIENT_STARTS]
    y = jnp.asarray(np.log(z0 / (1 - z0)), jnp.float32)
    m = jnp.zeros_like(y)
    v = jnp.zeros_like(y)
    b1, b2, eps, lr = 0.9, 0.999, 1e-8, config.learning_rate
    best_values, best_z, values, samples = [], [], [], []
    for k in range(1, context.steps + 1):
        vals, g = value_and_grad(y)
        vals = np.asarray(vals, np.float64)
        values.append(vals)
        samples.append(np.asarray(jax.nn.sigmoid(y), np.float64))
        finite = np.where(np.isfinite(vals), vals, -np.inf)
        i = int(np.argmax(finite))
        best_values.append(finite[i])
        best_z.append(np.asarray(jax.nn.sigmoid(y[i]), np.float64))
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        y = y + lr * (m / (1 - b1 ** k)) / (jnp.sqrt(v / (1 - b2 ** k)) + eps)
    return {"best_values": np.asarray(best_values, np.float64), "best_z": np.asarray(best_z),
            "values": np.asarray(values, np.float64), "samples": np.asarray(samples, np.float64)}


def search(objective: Objective, dim: int, key, config: SearchConfig, *, progress=None, seeds=None, executor=None,
           out_dir=None) -> SearchResult:
    """Run ``config.method`` within ``config.budget`` evaluations; ``"both"`` runs the cross-entropy method on
    half the budget and starts the gradient ascent from its result (among random starts). ``seeds`` (points of
    ``[0, 1]^dim``, e.g. an attack's game strategies): where the searches start (see :func:`cross_entropy`).
    ``executor`` runs the restarts (:mod:`stp_env.execution`; default in this process), ``out_dir`` keeps the
    finished ones so that a killed search resumes."""
    run = {"executor": executor, "out_dir": out_dir, "progress": progress}
    if config.method == "cem":
        return cross_entropy(objective, dim, key, config, seeds=seeds, **run)
    if config.method == "gradient":
        return gradient_ascent(objective, dim, key, config, starts=None if seeds is None else _check_seeds(seeds, dim),
                               **run)
    k1, k2 = jax.random.split(key)
    first = cross_entropy(objective, dim, k1, config, budget=config.budget // 2, seeds=seeds, **run)
    second = gradient_ascent(objective, dim, k2, config, budget=config.budget - first.evaluations,
                             starts=first.best_z[None, :], **run)
    best = first if first.best_value >= second.best_value else second
    return SearchResult(best_z=best.best_z, best_value=best.best_value, history=first.history + second.history,
                        evaluations=first.evaluations + second.evaluations,
                        values=np.concatenate([first.values, second.values]),
                        samples=np.concatenate([first.samples, second.samples]))

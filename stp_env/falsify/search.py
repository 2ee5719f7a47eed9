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

import jax
import jax.numpy as jnp
import numpy as np

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


TABLE_FIELDS = {"tables": ("avoid_values", "tracking_grads", "sdf"),
                "vehicles": ("nominal_states", "nominal_controls")}
"""The large arrays of an attack's environment (``attack.base``): :func:`compiled` passes them to the compiled
program as arguments. Closed over, they would be baked into it as constants (the avoid table alone is tens of
megabytes), which makes XLA's compilation very slow."""


def compiled(objective: Objective, transform=jax.vmap):
    """``sim_jit(transform(objective))``, compiled once per call of this function. When ``objective`` is a method
    of an attack whose ``base`` holds the environment, the :data:`TABLE_FIELDS` of ``base`` are arguments of the
    compiled program rather than constants in it (same values, same results)."""
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


def cross_entropy(objective: Objective, dim: int, key, config: SearchConfig, *, budget: int | None = None,
                  progress=None, seeds=None) -> SearchResult:
    """The cross-entropy method on ``[0, 1]^dim`` (see the module docstring). ``seeds`` ``(S, dim)``: the first
    ``min(S, restarts - 1)`` restarts start from them (mean at the seed, deviation :data:`SEED_STD`; the seed itself
    is the first sample of its restart), the others from the whole box, so that a seeded search also explores."""
    budget = config.budget if budget is None else budget
    pop, restarts = config.population, config.restarts
    per_iter = pop * restarts
    iters = max(1, budget // per_iter)
    n_elite = max(2, math.ceil(config.elite_fraction * pop))
    mean = np.full((restarts, dim), 0.5)
    std = np.full((restarts, dim), 0.3)
    n_seeded = 0
    if seeds is not None:
        seeds = _check_seeds(seeds, dim)
        n_seeded = min(len(seeds), max(restarts - 1, 1))
        mean[:n_seeded] = seeds[:n_seeded]
        std[:n_seeded] = SEED_STD
    rng = np.random.default_rng(np.asarray(jax.random.key_data(key)).ravel().astype(np.uint32))
    program = compiled(objective)  # once for the whole search
    best_z, best_v, history, values, samples = None, -math.inf, [], [], []
    for it in range(iters):
        zs = np.clip(mean[:, None, :] + std[:, None, :] * rng.standard_normal((restarts, pop, dim)), 0.0, 1.0)
        if it == 0 and n_seeded:
            zs[:n_seeded, 0] = seeds[:n_seeded]
        vals = evaluate(objective, zs.reshape(-1, dim), config.batch, program=program).reshape(restarts, pop)
        values.append(vals.ravel())
        samples.append(zs.reshape(-1, dim))
        finite = np.where(np.isfinite(vals), vals, -np.inf)
        i, j = np.unravel_index(np.argmax(finite), finite.shape)
        if finite[i, j] > best_v:
            best_v, best_z = float(finite[i, j]), zs[i, j].copy()
        order = np.argsort(-finite, axis=1)[:, :n_elite]
        elite = np.take_along_axis(zs, order[:, :, None], axis=1)
        a = config.smoothing
        mean = a * mean + (1 - a) * elite.mean(axis=1)
        std = np.maximum(a * std + (1 - a) * elite.std(axis=1), config.min_std)
        history.append(best_v)
        if progress is not None:
            progress.update(per_iter)
    if best_z is None:  # every evaluation was -inf or NaN
        best_z = np.full(dim, 0.5)
    return SearchResult(best_z=best_z, best_value=best_v, history=tuple(history), evaluations=iters * per_iter,
                        values=np.concatenate(values), samples=np.concatenate(samples))


def gradient_ascent(objective: Objective, dim: int, key, config: SearchConfig, *, budget: int | None = None,
                    starts=None, progress=None) -> SearchResult:
    """Adam ascent of ``objective(sigmoid(y))`` from ``config.restarts * 8`` starts (plus ``starts``, points of
    ``[0, 1]^dim`` such as a cross-entropy result), all starts in one batch; each step costs one value-and-gradient
    evaluation per start (counted as one evaluation of the budget)."""
    budget = config.budget if budget is None else budget
    n_random = config.restarts * 8
    z0 = np.asarray(jax.random.uniform(key, (n_random, dim)), np.float64)
    if starts is not None:
        z0 = np.concatenate([np.atleast_2d(np.asarray(starts, np.float64)), z0])[:max(n_random, 1)]
    z0 = np.clip(z0, 1e-3, 1 - 1e-3)
    n = z0.shape[0]
    steps = max(1, budget // n)
    y = jnp.asarray(np.log(z0 / (1 - z0)), jnp.float32)

    def transform(g):
        return jax.vmap(jax.value_and_grad(lambda yy: g(jax.nn.sigmoid(yy))))

    value_and_grad = compiled(objective, transform)
    m = jnp.zeros_like(y)
    v = jnp.zeros_like(y)
    b1, b2, eps, lr = 0.9, 0.999, 1e-8, config.learning_rate
    best_v, best_z, history, values = -math.inf, np.asarray(z0[0]), [], []
    for k in range(1, steps + 1):
        vals, g = value_and_grad(y)
        vals = np.asarray(vals, np.float64)
        values.append(vals)
        finite = np.where(np.isfinite(vals), vals, -np.inf)
        i = int(np.argmax(finite))
        if finite[i] > best_v:
            best_v, best_z = float(finite[i]), np.asarray(jax.nn.sigmoid(y[i]), np.float64)
        g = jnp.where(jnp.isfinite(g), g, 0.0)
        m = b1 * m + (1 - b1) * g
        v = b2 * v + (1 - b2) * g * g
        y = y + lr * (m / (1 - b1 ** k)) / (jnp.sqrt(v / (1 - b2 ** k)) + eps)
        history.append(best_v)
        if progress is not None:
            progress.update(n)
    return SearchResult(best_z=best_z, best_value=best_v, history=tuple(history), evaluations=steps * n,
                        values=np.concatenate(values))


def search(objective: Objective, dim: int, key, config: SearchConfig, *, progress=None, seeds=None) -> SearchResult:
    """Run ``config.method`` within ``config.budget`` evaluations; ``"both"`` runs the cross-entropy method on
    half the budget and starts the gradient ascent from its result (among random starts). ``seeds`` (points of
    ``[0, 1]^dim``, e.g. an attack's game strategies): where the searches start (see :func:`cross_entropy`)."""
    if config.method == "cem":
        return cross_entropy(objective, dim, key, config, progress=progress, seeds=seeds)
    if config.method == "gradient":
        return gradient_ascent(objective, dim, key, config, progress=progress,
                               starts=None if seeds is None else _check_seeds(seeds, dim))
    k1, k2 = jax.random.split(key)
    first = cross_entropy(objective, dim, k1, config, budget=config.budget // 2, progress=progress, seeds=seeds)
    second = gradient_ascent(objective, dim, k2, config, budget=config.budget - first.evaluations,
                             starts=first.best_z[None, :], progress=progress)
    best = first if first.best_value >= second.best_value else second
    return SearchResult(best_z=best.best_z, best_value=best.best_value, history=first.history + second.history,
                        evaluations=first.evaluations + second.evaluations,
                        values=np.concatenate([first.values, second.values]))

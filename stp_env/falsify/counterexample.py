"""Running an attack, and the replayable record of the worst input it found.

A counterexample file (``counterexample.json``) holds the attack's specification (a registered attack name, a
registered scenario and plain numbers: nothing in it is code or names code), the search's seed and settings, the
worst input ``z`` (float32 values, exact in JSON) and the objective there, evaluated by one canonical program
(:func:`canonical_value`). :func:`replay` rebuilds the attack from the file and recomputes that value: the same
program on the same inputs gives the same bits.
"""

from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import jax.numpy as jnp
import numpy as np

from stp_env.arguments import INT32_MAX, check_int, check_kbar, check_real, show
from stp_env.falsify import targets
from stp_env.falsify.search import SearchConfig, search
from stp_env.files import atomic_open
from stp_env.loaders import read_json
from stp_env.policies.intruders import is_plugin
from stp_env.seeds import prng_key

TARGETS = tuple(targets.BUILT_IN)
"""The built-in targets' names (every target, registered ones included: :func:`stp_env.falsify.targets.names`)."""
FORMAT = 1
MAX_ATTACK_DIM = 1_000_000
"""The most inputs an attack may have (its ``z``): what a search samples, and what a counterexample file may hold."""
MAX_TEXT = 256
"""The longest name or string option of a specification [characters]."""
MAX_OPTION = 1e6
"""The largest magnitude of a numeric attack option."""


@dataclasses.dataclass(frozen=True, kw_only=True)
class AttackSpec:
    """What to attack.

    Attributes:
        target: ``"tracking"``, ``"avoidance"`` or ``"kbar"``.
        scenario: a registered scenario name (its vehicle, tables and, for ``"kbar"``, its plan).
        kbar: the scenario's k̄ (plan and buffers); ``None``: the scenario's default.
        wind: the scenario's wind bound [m/s] (its tables and bound are those of this wind); ``None``: the
            scenario's default.
        wind_model: the environment's wind model (``"kbar"``; the other attacks choose their wind themselves).
        dt, control_dt: the environment's decision and inner control periods [s].
        options: the attack's own options as ``(name, value)`` pairs (see each attack's dataclass fields).
    """

    target: str
    scenario: str = "town"
    kbar: int | None = None
    wind: float | None = None
    wind_model: str = "worst"
    dt: float = 0.1
    control_dt: float = 0.02
    options: tuple = ()

    def __post_init__(self) -> None:
        if not isinstance(self.target, str) or self.target not in targets.names():
            raise ValueError(f"target must be one of {', '.join(targets.names())}; got {show(self.target)}.")
        for name in ("scenario", "wind_model"):
            value = getattr(self, name)
            if not isinstance(value, str) or not 0 < len(value) <= MAX_TEXT:
                raise ValueError(f"{name} must be a non-empty string of at most {MAX_TEXT} characters; got "
                                 f"{show(value)}.")
        if self.kbar is not None:
            object.__setattr__(self, "kbar", check_kbar(self.kbar))
        if self.wind is not None:
            object.__setattr__(self, "wind", check_real(self.wind, "wind [m/s]", 0.0, 1000.0))
        object.__setattr__(self, "dt", check_real(self.dt, "dt [s]", 0.0, 10.0, lo_open=True))
        object.__setattr__(self, "control_dt", check_real(self.control_dt, "control_dt [s]", 0.0, self.dt,
                                                          lo_open=True))
        if not isinstance(self.options, (tuple, list)) or not all(
                isinstance(o, (tuple, list)) and len(o) == 2 for o in self.options):
            raise ValueError(f"options must be (name, value) pairs; got {show(self.options)}.")
        opts = dict(self.options)
        if len(opts) != len(self.options):
            raise ValueError(f"options repeat a name: {show(self.options)}.")
        for key, value in opts.items():
            if not isinstance(key, str) or not key.isidentifier() or len(key) > MAX_TEXT:
                raise ValueError(f"an option name must be an identifier; got {show(key)}.")
            if isinstance(value, str):
                if len(value) > MAX_TEXT:
                    raise ValueError(f"option {key}: a string of at most {MAX_TEXT} characters; got {show(value)}.")
            elif isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ValueError(f"option {key} must be a number or a string; got {show(value)}.")
            elif isinstance(value, int):
                check_int(value, f"option {key}", -INT32_MAX, INT32_MAX)
            else:
                check_real(value, f"option {key}", -MAX_OPTION, MAX_OPTION)
        object.__setattr__(self, "options", tuple(sorted(opts.items())))

    def to_json(self) -> dict:
        return {"target": self.target, "scenario": self.scenario, "kbar": self.kbar, "wind": self.wind,
                "wind_model": self.wind_model,
                "dt": self.dt, "control_dt": self.control_dt, "options": dict(self.options)}

    @classmethod
    def from_json(cls, data: dict) -> AttackSpec:
        """The spec of a counterexample file's ``spec`` object: known fields only, each checked (``ValueError``)."""
        if not isinstance(data, dict):
            raise ValueError("the attack specification must be a JSON object.")
        if "target" not in data:
            raise ValueError("the attack specification has no target.")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise ValueError(f"unknown attack specification field(s) {unknown}; allowed: {sorted(known)}.")
        data = dict(data)
        opts = data.pop("options", {}) or {}
        if not isinstance(opts, dict):
            raise ValueError("options must be a JSON object.")
        return cls(**data, options=tuple(opts.items()))


def environment(spec: AttackSpec, *, progress: bool = False):
    """The environment the attack runs in (registered scenario, typed config), with the tables its target reads
    (:func:`stp_env.falsify.targets.required_tables`)."""
    from stp_env import assembly, requirements, sim
    from stp_env.scenarios import factory_parameters, make

    overrides = {}
    if spec.kbar is not None:
        if "kbar" not in factory_parameters(spec.scenario):
            raise ValueError(f"scenario {spec.scenario!r} takes no kbar.")
        overrides["kbar"] = spec.kbar
    if spec.wind is not None:
        if "wind" not in factory_parameters(spec.scenario):
            raise ValueError(f"scenario {spec.scenario!r} takes no wind.")
        overrides["wind"] = float(spec.wind)
    scenario = make(spec.scenario, **overrides)
    config = sim.EnvConfig(dt=spec.dt, control_dt=spec.control_dt, wind_model=spec.wind_model)
    tables = targets.required_tables(spec.target, dict(spec.options))  # checked before anything is built
    params = assembly.params_for(scenario, config, progress=progress)
    return requirements.with_required_tables(params, scenario, tables=tables, progress=progress)


def build_attack(spec: AttackSpec, params=None, *, progress: bool = False):
    """The attack object of ``spec`` (in ``params``, or the environment :func:`environment` builds)."""
    cls = targets.attack_class(spec.target)
    params = environment(spec, progress=progress) if params is None else params
    allowed = {f.name for f in dataclasses.fields(cls)} - {"base", "name"}
    opts = dict(spec.options)
    unknown = sorted(set(opts) - allowed)
    if unknown:
        raise ValueError(f"unknown option(s) {unknown} for the {spec.target} attack; allowed: {sorted(allowed)}.")
    attack = cls(base=params, **opts)
    if attack.dim > MAX_ATTACK_DIM:  # e.g. a horizon of 1e6 s in 0.1 s segments: refused before anything is sized
        raise ValueError(f"the {spec.target} attack with options {dict(spec.options)} has {attack.dim} inputs; at "
                         f"most {MAX_ATTACK_DIM} are searched.")
    return attack


def canonical_value(attack, z) -> float:
    """The objective at one input, by the one program replays use (unbatched, float32)."""
    from stp_env.falsify.search import compiled

    return float(compiled(attack.objective, lambda f: f)(jnp.asarray(np.asarray(z, np.float32))))


@dataclasses.dataclass(frozen=True)
class Outcome:
    """A finished search.

    Attributes:
        spec, config, seed: what ran.
        z: the worst input found (float32, in ``[0, 1]^dim``).
        worst: the objective there (:func:`canonical_value`).
        bound: the bound under attack; margin: its distance to ``worst`` (negative: the bound is broken).
        evaluations: attacks simulated; seconds: wall time of :func:`run` (building the attack, the search, the
        worst recomputed; compilation included).
        quantiles: the 50/90/99/100 % quantiles of every attack's objective (the spread of the search).
        details: what the simulator says about the worst attack (attack-specific).
        seed_values: the objective at each of the attack's game seeds (where the search started; empty when the
            attack has none).
    """

    spec: AttackSpec
    config: SearchConfig
    seed: int
    z: np.ndarray
    worst: float
    bound: float
    margin: float
    evaluations: int
    seconds: float
    quantiles: tuple[float, ...]
    details: dict
    seed_values: tuple[float, ...] = ()

    @property
    def violated(self) -> bool:
        return self.margin < 0

    def summary(self) -> dict:
        return {"target": self.spec.target, "scenario": self.spec.scenario, "kbar": self.spec.kbar,
                "options": dict(self.spec.options), "method": self.config.method, "attacks": self.evaluations,
                "worst": round(self.worst, 4), "bound": round(self.bound, 4), "margin": round(self.margin, 4),
                "violated": self.violated, "seconds": round(self.seconds, 1),
                "quantiles_50_90_99_100": [round(q, 4) for q in self.quantiles], "details": self.details,
                "seed_values": [round(v, 4) for v in self.seed_values]}


def run(spec: AttackSpec, config: SearchConfig | None = None, seed: int = 0, *, params=None,
        progress: bool = True, seeded: bool = True, executor=None, pieces_dir=None) -> Outcome:
    """Search ``config.budget`` attacks of ``spec`` and return the worst. ``seed``: an integer in ``[0, 2**63 - 1]``,
    each its own search (:func:`stp_env.seeds.prng_key`; checked before anything is built). ``seeded``: start the
    search from the attack's game strategies (its ``seeds()``, when it has them), as well as from the whole box.
    ``executor`` runs the search's restarts (:mod:`stp_env.execution`; default in this process, the same result
    either way); ``pieces_dir`` keeps the finished restarts, so that a killed search resumes."""
    from stp_env import progress as progress_mod

    config = SearchConfig() if config is None else config
    key = prng_key(seed)
    start = time.perf_counter()
    attack = build_attack(spec, params, progress=progress)
    seeds = None
    if seeded and callable(getattr(attack, "seeds", None)):
        progress_mod.note("flying the game's own worst strategies in closed loop: where the search starts", progress)
        seeds = attack.seeds()
    seeds = None if seeds is None else np.asarray(seeds, np.float32)
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=config.budget, unit="attack", desc=f"falsify {spec.target}")
        progress_mod.compiling_until_first_update(bar, "compiling the attack's batch (once per machine)...")
    try:
        jobs = {k: v for k, v in (("executor", executor), ("out_dir", pieces_dir)) if v is not None}
        result = search(attack.objective, attack.dim, key, config, progress=bar, seeds=seeds, **jobs)
    finally:
        if bar is not None:
            bar.close()
    progress_mod.note("recomputing the worst attack alone and its details (compiles a one-attack program once per "
                      "machine)", progress)
    z = np.asarray(result.best_z, np.float32)
    worst = canonical_value(attack, z)
    finite = result.values[np.isfinite(result.values)]
    quantiles = tuple(float(q) for q in np.quantile(finite, [0.5, 0.9, 0.99, 1.0])) if finite.size else ()
    details = attack.details(z)
    seed_values = () if seeds is None else tuple(canonical_value(attack, s) for s in seeds)
    seconds = time.perf_counter() - start  # the whole run: building the attack, the search, the worst recomputed
    return Outcome(spec=spec, config=config, seed=seed, z=z, worst=worst, bound=attack.bound,
                   margin=attack.margin(worst), evaluations=result.evaluations, seconds=seconds,
                   quantiles=quantiles, details=details, seed_values=seed_values)


def save(outcome: Outcome, directory, *, plot: bool = True, progress: bool | None = None) -> Path:
    """Write ``counterexample.json`` (and ``counterexample.png``) into ``directory``, atomically."""
    from stp_env import progress as progress_mod
    from stp_env.version import __version__

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    record = {"format": FORMAT, "package_version": __version__, "spec": outcome.spec.to_json(),
              "search": dataclasses.asdict(outcome.config), "seed": outcome.seed,
              "z": [float(v) for v in np.asarray(outcome.z, np.float32)], "value": outcome.worst,
              "summary": outcome.summary()}
    path = directory / "counterexample.json"
    with atomic_open(path) as fh:
        fh.write(json.dumps(record, indent=1))
    if plot:
        from stp_env.falsify.plots import plot_attack

        progress_mod.note(f"drawing {directory / 'counterexample.png'} (traces the worst attack)", progress)
        plot_attack(build_attack(outcome.spec), outcome.z, directory / "counterexample.png",
                    title=f"{outcome.spec.target}: worst {outcome.worst:.3f}, bound {outcome.bound:.3f}")
    return path


def load(path) -> tuple[AttackSpec, np.ndarray, float]:
    """``(spec, z, value)`` of a counterexample file, checked before anything is built: the loader contract
    (:func:`stp_env.loaders.read_json`: a regular file of at most 64 MiB, JSON nested at most 64 levels), then a
    JSON object of format :data:`FORMAT`, a valid :class:`AttackSpec`, ``z`` a list of at most
    :data:`MAX_ATTACK_DIM` numbers in ``[0, 1]`` and ``value`` a finite number. Any problem is a one-line
    ``ValueError`` naming the file."""
    path = Path(path)
    record = read_json(path, "counterexample")
    try:
        if not isinstance(record, dict) or record.get("format") != FORMAT:
            raise ValueError(f"not a counterexample file of format {FORMAT}")
        missing = sorted({"spec", "z", "value"} - set(record))
        if missing:
            raise ValueError(f"missing field(s) {missing}")
        spec = AttackSpec.from_json(record["spec"])
        if is_plugin(dict(spec.options).get("intruder")):  # a file never makes this process import code
            raise ValueError(f"the intruder {dict(spec.options)['intruder']!r} is a plug-in spec (code to import), "
                             "which a counterexample file may not name")
        z = record["z"]
        if not isinstance(z, list) or not 0 < len(z) <= MAX_ATTACK_DIM:
            raise ValueError(f"z must be a list of 1 to {MAX_ATTACK_DIM} numbers in [0, 1]")
        z = np.asarray([check_real(v, "every entry of z", 0.0, 1.0) for v in z], np.float32)
        value = check_real(record["value"], "value")
    except (TypeError, ValueError) as err:
        raise ValueError(f"{path}: cannot read the counterexample ({' '.join(str(err).split())}).") from None
    return spec, z, value


def replay(path, *, params=None) -> tuple[float, float]:
    """``(recorded value, recomputed value)`` of a counterexample file; equal bit for bit when the code and the
    scenario's artifacts are those it was made with."""
    spec, z, value = load(path)
    attack = build_attack(spec, params)
    if attack.dim != z.shape[0]:
        raise ValueError(f"{path}: the attack takes {attack.dim} inputs; the file has {z.shape[0]}.")
    return value, canonical_value(attack, z)

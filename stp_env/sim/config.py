"""Typed configuration of the simulation: frozen dataclasses with checked fields (unknown fields are a
``TypeError``, as for any dataclass)."""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from stp_env.reach.closed_loop import CERTIFIED_CONTROL_DT
from stp_env.sim import winds
from stp_env.sim.types import SPAWN_MODES, RewardWeights
from stp_env.sim.vehicle_models import Dubins, VehicleModel


def _finite(name: str, value, *, positive: bool = False, nonneg: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise ValueError(f"{name} must be a number; got {value!r}.")
    value = float(value)
    if not math.isfinite(value):
        raise ValueError(f"{name} must be finite; got {value}.")
    if positive and value <= 0:
        raise ValueError(f"{name} must be > 0; got {value}.")
    if nonneg and value < 0:
        raise ValueError(f"{name} must be >= 0; got {value}.")
    return value


@dataclasses.dataclass(frozen=True, kw_only=True)
class RewardConfig:
    """Rewards per step.

    Vehicles: ``progress`` times the decrease of the distance to the target [per m]; ``arrival`` once on
    arrival (``late_arrival`` instead if after the STA); ``collision`` once on a collision (negative).
    Intruder: ``forced`` per vehicle newly forced to avoid (eq. 39); ``intruder_collision`` per vehicle it
    collides with or that collides because of it; ``shaping`` times the decrease of the smallest avoid-region value
    ``min_i V^A_i`` over unforced flying vehicles [per m] (a potential-based shaping, 0 by default);
    ``kbar_reached`` once in the step where ``|N^RP|`` reaches k̄ (the k̄-th forced vehicle, on top of its
    ``forced``; 0 by default).
    """

    progress: float = 0.01
    arrival: float = 1.0
    late_arrival: float = 0.5
    collision: float = -10.0
    forced: float = 1.0
    intruder_collision: float = 10.0
    shaping: float = 0.0
    kbar_reached: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            _finite(f.name, getattr(self, f.name))

    def weights(self) -> RewardWeights:
        """The weights as float32 arrays, by name (what :class:`~stp_env.sim.types.EnvParams` holds)."""
        return RewardWeights(**{f.name: jnp.asarray(getattr(self, f.name), jnp.float32)
                                for f in dataclasses.fields(self)})


@dataclasses.dataclass(frozen=True, kw_only=True)
class EnvConfig:
    """How an environment is simulated (the scenario and its plan say *what* is simulated).

    Attributes:
        dt: step length [s], the decision period: agents act once per step and their actions are held over it
            (zero-order hold).
        control_dt: period of the vehicles' low-level control loop inside a step [s] (``dt`` must be a whole
            multiple of it): the tracker ``kappa`` (SPP eq. 26), ``u^A`` (eq. 15), the avoid-start check (eqs.
            17-18), a vehicle feedback policy passed to the core, and the ``"worst"`` wind run at this rate. It must
            lie in :data:`CERTIFIED_CONTROL_DT` (0.005-0.02 s), where the tracking-error bound and the avoid margin
            are certified in closed loop: held for 0.1 s, the bang-bang tracker leaves its error bound and ``u^A``
            lets the optimal intruder inside ``R_c`` (``docs/numerics.md``). Other periods need
            ``allow_uncertified=True``.
        wind_model: a registered wind model (:mod:`stp_env.sim.winds`), by name with its default parameters
            (``"uniform"``: a new wind uniformly in the disk of radius ``d_r`` every step, as in the papers;
            ``"constant"``: one wind per episode; ``"gusts"``: Ornstein-Uhlenbeck, clipped to the disk; ``"worst"``:
            from the HJ value gradients, against tracking while on the plan, against avoidance while avoiding), by
            spec (``"gusts:time_constant=3"``) or as an instance (``Gusts(time_constant=3.0)``); stored as the
            instance.
        appear_window: the intruder appears at ``t_`` drawn uniformly from this window, in seconds relative to
            the first departure; ``None``: while the most vehicles are in the air (see ``make_params``).
        spawn_mode: ``"outside"`` (uniform within ``spawn_radius`` of a flying vehicle, outside every avoid
            region: Assumption 3) or ``"boundary"`` (on the boundary of a random flying vehicle's avoid region,
            Observation 1, and outside the others'), or ``"mixed"`` (either, with probability 1/2 per episode).
        spawn_radius: [m] (``None``: 1.5 d^A).
        safety_filter: replace each vehicle's action by ``u^A`` from its avoid-start time until the intruder
            leaves (eq. 38). Off: vehicles do what their policy says (the avoid start is still recorded).
        avoid_margin: [m] a vehicle starts avoiding when ``V^A <= avoid_margin``; ``None``: the certified margin,
            one inner step of the fastest fall of the interpolated value near its zero level, plus the table's
            closed-loop error and a rounding allowance (:func:`stp_env.sim.margins.default_avoid_margin`), so that
            the boundary is not stepped over between two checks and ``u^A`` wins from wherever the check fires. The
            fall rate is not a closing speed: the vehicle's own turn rotates the relative state and the relative
            heading moves the value too. A margin below the certified one needs ``allow_uncertified=True``.
        d_sense: sensing range for observations [m] (``None``: 1.5 d^A); must be >= d^A.
        episode: ``"window"`` (start ``lead`` seconds before the intruder can appear and end ``tail`` seconds
            after it leaves: the part of a flight that matters for k̄) or ``"full"`` (first departure to the last
            STA plus ``tail``).
        lead, tail: [s].
        n_nearest: other vehicles listed in each observation.
        rewards: :class:`RewardConfig`.
        vehicle_model: the vehicles' plant (:mod:`stp_env.sim.vehicle_models`; the papers' :class:`Dubins` by
            default). The plans, the reachability sets and the papers' controllers stay those of the scenario's
            HJ model; the plant follows their commands through ``VehicleModel.command_to_action``.
        allow_uncertified: simulate settings outside what the proofs certify (an inner period outside
            :data:`CERTIFIED_CONTROL_DT`, an avoid margin below the certified one, a decision step ``dt`` longer
            than the scenario's ``t_IAT``, a plan whose trajectories are not flights of the planning dynamics
            ``U^p``) instead of refusing them. The vehicles concerned (all of them
            for a setting of the simulator) then have ``EnvParams.vehicles.certified`` false: their collisions and
            tracking violations are booked as assumption failures, not guarantee violations.
    """

    dt: float = 0.1
    control_dt: float = 0.02
    wind_model: str | winds.WindModel = "uniform"
    appear_window: tuple[float, float] | None = None
    spawn_mode: str = "outside"
    spawn_radius: float | None = None
    safety_filter: bool = True
    avoid_margin: float | None = None
    d_sense: float | None = None
    episode: str = "window"
    lead: float = 5.0
    tail: float = 10.0
    n_nearest: int = 4
    rewards: RewardConfig = dataclasses.field(default_factory=RewardConfig)
    vehicle_model: VehicleModel = dataclasses.field(default_factory=Dubins)
    allow_uncertified: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.allow_uncertified, bool):
            raise ValueError(f"allow_uncertified must be True or False; got {self.allow_uncertified!r}.")
        _finite("dt", self.dt, positive=True)
        _finite("control_dt", self.control_dt, positive=True)
        ratio = self.dt / self.control_dt
        if round(ratio) < 1 or abs(ratio - round(ratio)) > 1e-6 * ratio:
            raise ValueError(f"dt ({self.dt} s) must be a whole multiple of control_dt ({self.control_dt} s).")
        if not self.control_dt_certified and not self.allow_uncertified:
            lo, hi = CERTIFIED_CONTROL_DT
            raise ValueError(f"control_dt {self.control_dt} s lies outside {lo}-{hi} s, the inner control periods "
                             "at which the tracking-error bound and the avoid margin are certified; pass "
                             "allow_uncertified=True to simulate it anyway (violations then count as assumption "
                             "failures).")
        object.__setattr__(self, "wind_model", winds.make(self.wind_model))
        if self.spawn_mode not in SPAWN_MODES:
            raise ValueError(f"spawn_mode {self.spawn_mode!r} is not known; allowed: {', '.join(SPAWN_MODES)}.")
        if self.appear_window is not None:
            if isinstance(self.appear_window, (str, bytes)) or not hasattr(self.appear_window, "__len__") \
                    or len(self.appear_window) != 2:
                raise ValueError(f"appear_window must be (lo, hi) in seconds; got {self.appear_window!r}.")
            lo, hi = (_finite("appear_window", v) for v in self.appear_window)
            if hi < lo:
                raise ValueError(f"appear_window must have lo <= hi; got {self.appear_window!r}.")
            object.__setattr__(self, "appear_window", (lo, hi))
        for name in ("spawn_radius", "d_sense"):
            if getattr(self, name) is not None:
                _finite(name, getattr(self, name), positive=True)
        if self.avoid_margin is not None:
            _finite("avoid_margin", self.avoid_margin, nonneg=True)
        if not isinstance(self.safety_filter, bool):
            raise ValueError(f"safety_filter must be True or False; got {self.safety_filter!r}.")
        if self.episode not in ("window", "full"):
            raise ValueError(f"episode must be 'window' or 'full'; got {self.episode!r}.")
        _finite("lead", self.lead, nonneg=True)
        _finite("tail", self.tail, nonneg=True)
        if isinstance(self.n_nearest, bool) or not isinstance(self.n_nearest, int) or self.n_nearest < 0:
            raise ValueError(f"n_nearest must be an integer >= 0; got {self.n_nearest!r}.")
        if not isinstance(self.rewards, RewardConfig):
            raise ValueError(f"rewards must be a RewardConfig; got {type(self.rewards).__name__}.")
        if not isinstance(self.vehicle_model, VehicleModel):
            raise ValueError(f"vehicle_model must be a stp_env.sim.vehicle_models.VehicleModel; got "
                             f"{type(self.vehicle_model).__name__}.")

    @property
    def control_dt_certified(self) -> bool:
        """Whether ``control_dt`` lies in :data:`CERTIFIED_CONTROL_DT` (up to float rounding)."""
        lo, hi = CERTIFIED_CONTROL_DT
        return lo * (1 - 1e-6) <= self.control_dt <= hi * (1 + 1e-6)

    @property
    def control_substeps(self) -> int:
        """Inner control steps per step, ``dt / control_dt``."""
        return round(self.dt / self.control_dt)

    def with_overrides(self, **overrides) -> EnvConfig:
        names = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise ValueError(f"unknown EnvConfig field(s) {unknown}; allowed: {sorted(names)}.")
        return dataclasses.replace(self, **overrides)

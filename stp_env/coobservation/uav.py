"""The co-observation study in the UAV simulator: a team flying in formation past forbidden zones.

:class:`FormationScenario` (frozen, checked) is the typed configuration: the project's UAV (``v in [0, 25] m/s``,
``|omega| <= 2 rad/s``, wind ``6 m/s``, ``R_c = 100 m``: the city vehicle, whose reachability artifacts the simulator
already has), a straight route flown in line abreast at ``speed`` (inside the tracker's planning set ``U^p = [11,
13] m/s``), the forbidden convex polygons, the observation radius, and the observation schedules:

* :meth:`FormationScenario.schedule` ``(times)``: at each time the neighbours of the line co-observe (``(0, 1)``,
  ``(1, 2)``, ...); the start and the goal are fixed-point observations (a base station) at the first and last
  time.
* :meth:`FormationScenario.secured_times`: the fewest observation times (greedy on a time grid) such that every
  vehicle's reachability region between consecutive observations misses every forbidden zone, for a given test
  (the ellipse of Def. 3 grown by the observation radius and the observers' tracking margin, with speed
  ``v_max + wind``; or the exact region, :mod:`stp_env.coobservation.exact`).
* :meth:`FormationScenario.uniform_times`: observations every ``period`` seconds, whatever the zones (unsecured
  when the period is long).

:meth:`FormationScenario.params` builds the simulator's :class:`~stp_env.sim.EnvParams` by composition (the
core's ``make_params`` with this scenario, its straight-line plan, and the cached avoid-region and tracking
artifacts), with the intruder removed (it never appears).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import warnings

import jax.numpy as jnp
import numpy as np

from stp_env.coobservation.schedule import Observation, segments

DEFAULT_FORBIDDEN = (
    ((600.0, 1736.0), (1100.0, 1736.0), (1100.0, 2300.0), (600.0, 2300.0)),
    ((1900.0, 250.0), (2500.0, 250.0), (2500.0, 769.0), (1900.0, 769.0)),
)
"""Zone A north-west of the route (its nearest corner 450 m from the centre line, 330 m from the left vehicle's
path) and zone B south-east (800 m, 680 m from the right vehicle's path)."""


def _polygon(vertices) -> tuple[tuple[float, float], ...]:
    v = tuple((float(x), float(y)) for x, y in vertices)
    if len(v) < 3 or not all(math.isfinite(c) for p in v for c in p):
        raise ValueError(f"a forbidden zone needs at least 3 finite vertices; got {vertices!r}.")
    from stp_env.coobservation.admm import polygon_halfplanes

    polygon_halfplanes(v)  # raises if not convex
    return v


@dataclasses.dataclass(frozen=True, kw_only=True)
class FormationScenario:
    """See the module docstring. Units: m, s, rad.

    Attributes:
        domain_lo, domain_hi: the airspace [m].
        start, goal: the formation centre's route (a straight line) [m].
        speed: ground speed of the nominal trajectories [m/s].
        offsets: lateral offset of each vehicle from the centre line (left positive) [m]; neighbours co-observe.
        forbidden: convex polygons [m].
        observation_radius: two vehicles (or a vehicle and a base station) observe each other within it [m].
        tracking_margin: how far an honest observer may be from its nominal position [m] (the tracking bound is
            ``r_e = 5.3 m`` for this UAV; honest vehicles stayed within 4.4 m in closed loop, see
            ``docs/coobservation.md``).
        target_radius: the goal disk each vehicle lands in [m].
        v_max, omega_max, wind: the vehicle (the city UAV of the intruder paper, eq. 43 bounds).
        wind_model: how the wind in each vehicle's disk of radius ``wind`` is drawn (a registered model of
            :mod:`stp_env.sim.winds`, by name): ``"uniform"`` (anew every step, the papers'), or ``"tailwind"``
            (full strength along each vehicle's heading: a compromised vehicle flies over the ground at
            ``v_max + wind``, the speed the reachability ellipses assume).
        dt: simulator step [s]; control_dt: the core's inner control period [s] (the tracker runs at every inner
            step; the attacker's action is held over a step); sample_period: nominal trajectory samples [s].
    """

    domain_lo: tuple[float, float] = (0.0, 0.0)
    domain_hi: tuple[float, float] = (3000.0, 3000.0)
    start: tuple[float, float] = (400.0, 400.0)
    goal: tuple[float, float] = (2600.0, 2600.0)
    speed: float = 12.0
    offsets: tuple[float, ...] = (120.0, 0.0, -120.0)
    forbidden: tuple = DEFAULT_FORBIDDEN
    observation_radius: float = 200.0
    tracking_margin: float = 20.0
    target_radius: float = 40.0
    v_max: float = 25.0
    omega_max: float = 2.0
    wind: float = 6.0
    dt: float = 0.2
    control_dt: float = 0.02
    sample_period: float = 0.5
    wind_model: str = "uniform"

    def __post_init__(self):
        from stp_env.sim import winds

        if not isinstance(self.wind_model, str):
            raise ValueError(f"wind_model must be the name of a registered wind model; got {self.wind_model!r}.")
        winds.make(self.wind_model)  # raises ValueError naming the registered models
        for name in ("speed", "observation_radius", "target_radius", "v_max", "omega_max", "dt", "control_dt",
                     "sample_period"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v > 0):
                raise ValueError(f"{name} must be a finite number > 0; got {v!r}.")
        for name in ("tracking_margin", "wind"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not (math.isfinite(v) and v >= 0):
                raise ValueError(f"{name} must be a finite number >= 0; got {v!r}.")
        if len(self.offsets) < 2:
            raise ValueError(f"offsets: a formation needs at least 2 vehicles; got {self.offsets!r}.")
        spacing = np.diff(sorted(self.offsets))
        if np.any(spacing > self.observation_radius):
            raise ValueError(f"offsets {self.offsets}: neighbours {spacing.max():g} m apart cannot observe each other "
                             f"within observation_radius {self.observation_radius:g} m.")
        if self.speed > self.v_max:
            raise ValueError(f"speed {self.speed} exceeds v_max {self.v_max}.")
        object.__setattr__(self, "forbidden", tuple(_polygon(p) for p in self.forbidden))
        if math.dist(self.start, self.goal) <= 0:
            raise ValueError("start and goal must differ.")

    # -------------------------------------------------------------------------------------------- nominal plan
    @property
    def n_vehicles(self) -> int:
        return len(self.offsets)

    @property
    def duration(self) -> float:
        """Flight time of the route [s], rounded up to a whole simulator step."""
        t = math.dist(self.start, self.goal) / self.speed
        return math.ceil(t / self.dt - 1e-9) * self.dt

    @property
    def attacker_speed(self) -> float:
        """The fastest a compromised vehicle moves over the ground: ``v_max + wind`` [m/s]."""
        return self.v_max + self.wind

    @property
    def ellipse_radius(self) -> float:
        """The ellipse's growth: the observation radius plus the observers' tracking margin [m]."""
        return self.observation_radius + self.tracking_margin

    def _frame(self):
        d = np.asarray(self.goal, float) - np.asarray(self.start, float)
        u = d / np.linalg.norm(d)
        left = np.array([-u[1], u[0]])
        return u, left, math.atan2(u[1], u[0])

    def positions(self, times) -> np.ndarray:
        """Nominal positions ``(n_vehicles, len(times), 2)`` at ``times`` [s] (clamped to the route)."""
        u, left, _ = self._frame()
        length = math.dist(self.start, self.goal)
        s = np.clip(np.asarray(times, float) * self.speed, 0.0, length)
        centre = np.asarray(self.start, float) + s[:, None] * u
        return np.stack([centre + off * left for off in self.offsets])

    def starts(self) -> np.ndarray:
        return self.positions([0.0])[:, 0]

    def goals(self) -> np.ndarray:
        return self.positions([self.duration])[:, 0]

    def plan(self):
        """The nominal trajectories as a :class:`stp_env.planning.stp.Plan` (straight, constant speed)."""
        from stp_env.planning.single import SinglePlan
        from stp_env.planning.stp import Plan, VehiclePlan

        t_end = self.duration
        times = np.arange(0.0, t_end + self.sample_period - 1e-9, self.sample_period)
        pos = self.positions(times)
        _, _, heading = self._frame()
        vehicles = []
        for i in range(self.n_vehicles):
            states = np.concatenate([pos[i], np.full((len(times), 1), heading)], axis=1).astype(np.float32)
            controls = np.tile(np.array([self.speed, 0.0], np.float32), (len(times), 1))
            controls[-1] = 0.0
            plan = SinglePlan(t_ldt=0.0, sta=t_end, times=times, states=states, controls=controls,
                              arrival_time=t_end, n_steps=0)
            vehicles.append(VehiclePlan(index=i, priority=i, plan=plan, obstacle_lags=np.zeros(0),
                                        obstacle_radii=np.zeros(0)))
        return Plan(vehicles=tuple(vehicles), tracking_bound=0.0, collision_radius=100.0, kbar=None)

    def scenario(self):
        """The :class:`stp_env.scenarios.Scenario` the simulator builds from (vehicles, domain, UAV bounds)."""
        from stp_env.dynamics import DubinsWind
        from stp_env.scenarios import Scenario, VehicleSpec
        from stp_env.scenarios.paper import BEACLS_PLANNING_OMEGA_MAX, BEACLS_PLANNING_V

        _, _, heading = self._frame()
        starts, goals = self.starts(), self.goals()
        vehicles = tuple(VehicleSpec(start=(*starts[i], heading), target=tuple(goals[i]),
                                     target_radius=self.target_radius, sta=self.duration, priority=i)
                         for i in range(self.n_vehicles))
        span = max(self.domain_hi[0] - self.domain_lo[0], self.domain_hi[1] - self.domain_lo[1])
        points = math.ceil(span / (2 * self.target_radius / 6)) + 1
        return Scenario(
            name="coobservation-formation",
            domain_lo=self.domain_lo, domain_hi=self.domain_hi,
            vehicle=DubinsWind(v_min=0.0, v_max=self.v_max, omega_max=self.omega_max, wind=self.wind),
            planning_v=BEACLS_PLANNING_V, planning_omega_max=BEACLS_PLANNING_OMEGA_MAX, collision_radius=100.0,
            vehicles=vehicles, method="rtt", kbar=None, t_iat=10.0, grid_points=(points, points, 24),
            time_step=self.sample_period, seed=0,
            description="Co-observation study: a formation on a straight route past forbidden zones (no intruder).")

    def params(self, *, store=None, progress: bool = False, artifacts=None):
        """The simulator's ``EnvParams``: the core's ``make_params`` with the cached avoid-region and tracking
        artifacts of the UAV (or ``artifacts = (avoid, tracking)``, e.g. :meth:`coarse_artifacts`), then the episode
        window set to the flight (start at 0, end one step after the goal observation) and the intruder's
        appearance moved out of reach (it never appears)."""
        from stp_env import assembly, sim

        scenario = self.scenario()
        if artifacts is None:
            avoid, tracking = assembly.load_artifacts(scenario, store=store, progress=progress)
        else:
            avoid, tracking = artifacts
        # The co-observation study does not rest on the STP guarantees (no intruder appears; the honest vehicles'
        # tracking is checked by its own closed-loop tests): coarse, uncertified tables and the schedule's routes are
        # simulated as they are, every vehicle's violations then counting as assumption failures.
        config = sim.EnvConfig(dt=self.dt, control_dt=self.control_dt, episode="full", appear_window=(0.0, 0.0),
                               tail=0.0, wind_model=self.wind_model, allow_uncertified=True)
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message=".*assumption failures", category=UserWarning)
            params = assembly.make_params(scenario, self.plan(), avoid, tracking, config)
        never = jnp.asarray([1e9, 1e9], jnp.float32)
        return params.replace(intruder=dict(appear_window=never),
                              episode=dict(t_start=jnp.asarray(0.0, jnp.float32),
                                           t_end=jnp.asarray(self.duration + self.dt, jnp.float32)))

    def coarse_artifacts(self, *, store=None, progress: bool = False):
        """``(avoid, tracking)`` on coarse grids (first-order scheme; seconds to compute, for tests): the avoid
        region is never used (no intruder appears) and the tracker only has to keep honest vehicles well inside
        :attr:`tracking_margin`, which the closed-loop tests check."""
        import dataclasses

        from stp_env.artifacts import ArtifactStore
        from stp_env.reach.avoid import compute_avoid_region
        from stp_env.reach.defaults import default_avoid_config
        from stp_env.reach.tracking import compute_tracking_bound, default_tracking_config

        sc = self.scenario()
        store = ArtifactStore() if store is None else store
        avoid_cfg = dataclasses.replace(default_avoid_config(sc.vehicle, sc.collision_radius, sc.t_iat),
                                        grid_points=(21, 21, 17), n_slices=3, accuracy="low", certify=False)
        track_cfg = default_tracking_config(sc.vehicle, tuple(sc.planning_v), sc.planning_omega_max)
        track_cfg = dataclasses.replace(track_cfg, grid_points=(31, 31, 30), accuracy="low", certify=False)
        return (compute_avoid_region(avoid_cfg, store=store, progress=progress),
                compute_tracking_bound(track_cfg, store=store, progress=progress))

    # -------------------------------------------------------------------------------------------- schedules
    def schedule(self, times) -> tuple[Observation, ...]:
        """Observations at ``times`` [s]: neighbours co-observe at every time; the first and last times are also
        fixed-point observations of every vehicle at its start and goal (the base stations). ``times`` must begin
        at 0 and end at :attr:`duration`."""
        times = sorted(float(t) for t in times)
        if not times or abs(times[0]) > 1e-6 or abs(times[-1] - self.duration) > 1e-6:
            raise ValueError(f"observation times must start at 0 and end at the flight's end {self.duration:g} s; "
                             f"got {times[:1]} ... {times[-1:]}.")
        order = np.argsort(self.offsets)
        obs = [Observation(time=0.0, agent=i, point=tuple(self.starts()[i])) for i in range(self.n_vehicles)]
        for t in times:
            obs.extend(Observation(time=t, agent=int(a), partner=int(b)) for a, b in itertools.pairwise(order))
        obs.extend(Observation(time=self.duration, agent=i, point=tuple(self.goals()[i]))
                   for i in range(self.n_vehicles))
        return tuple(obs)

    def uniform_times(self, period: float) -> list[float]:
        """Every ``period`` seconds from 0, and the end."""
        if not period > 0:
            raise ValueError(f"period must be > 0; got {period!r}.")
        times = [*list(np.arange(0.0, self.duration - 1e-06, period)), self.duration]
        return [round(float(t), 6) for t in times]

    def segments_between(self, t1: float, t2: float):
        """Every vehicle's reachability segment between co-observations at ``t1`` and ``t2``."""
        return segments(self.schedule_pair(t1, t2), self.n_vehicles)

    def schedule_pair(self, t1, t2):
        order = np.argsort(self.offsets)
        return tuple(Observation(time=t, agent=int(a), partner=int(b)) for t in (t1, t2)
                     for a, b in itertools.pairwise(order))

    def segment_foci(self, seg) -> tuple[np.ndarray, np.ndarray]:
        """The two observers' nominal positions of a segment."""
        out = []
        for obs in (seg.observer1, seg.observer2):
            if obs[0] == "point":
                out.append(np.asarray(obs[1], float))
            else:
                out.append(self.positions([obs[2]])[obs[1], 0])
        return out[0], out[1]

    def secured_times(self, secure, step: float = 1.0) -> list[float]:
        """The fewest co-observation times on a grid of ``step`` seconds (greedy farthest-first, optimal since
        reachability regions are monotone in the interval) such that ``secure(q1, t1, q2, t2)`` holds for every
        vehicle's segment (foci: its observers' nominal positions). Raises ``ValueError`` if even one step is
        not secure."""
        grid = [*list(np.arange(0.0, self.duration - 1e-06, step)), self.duration]

        def ok(t1, t2):
            for seg in self.segments_between(t1, t2):
                q1, q2 = self.segment_foci(seg)
                if not secure(q1, t1, q2, t2):
                    return False
            return True

        chosen = [0]
        while chosen[-1] < len(grid) - 1:
            k = chosen[-1]
            if not ok(grid[k], grid[k + 1]):
                raise ValueError(f"the route cannot be secured between t = {grid[k]:g} and {grid[k + 1]:g} s: even "
                                 "neighbouring observation times leave a forbidden zone reachable.")
            j = k + 1
            while j + 1 < len(grid) and ok(grid[k], grid[j + 1]):
                j += 1
            chosen.append(j)
        return [round(float(grid[k]), 6) for k in chosen]

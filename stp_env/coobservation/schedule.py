"""Co-observation schedules and the reachability segments they define (co-observation paper, Sections II-E, II-F).

A schedule lists *observations*: at time ``t`` robot ``agent`` must be within the observation radius of an
observer, either another robot (``partner``: a co-observation, eqs. 22-24) or a fixed point (``point``: a security
checkpoint, a base station at the start or the goal). Between two consecutive observations of a robot, a
compromised robot can only have been inside the reachability ellipse whose foci are the two *observers*' positions
and whose semi-major axis is ``v_max (t2 - t1) / 2 + radius`` (:func:`stp_env.coobservation.ellipse.semi_major`):
the observers are honest (one robot is compromised at a time) and the robot was within ``radius`` of each.
"""

from __future__ import annotations

import dataclasses
import itertools
import math

import numpy as np


def _is_int(x) -> bool:
    return isinstance(x, (int, np.integer)) and not isinstance(x, (bool, np.bool_))


@dataclasses.dataclass(frozen=True, kw_only=True)
class Observation:
    """One scheduled observation.

    Attributes:
        time: when [steps of the plan, or s in the simulator].
        agent: the observed robot (index).
        partner: the observing robot (a co-observation; it observes ``agent`` and is observed by it), or ``None``.
        point: the observer's fixed position ``(x, y)`` (a checkpoint or a base station), when ``partner`` is None.
    """

    time: float
    agent: int
    partner: int | None = None
    point: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        if isinstance(self.time, bool) or not isinstance(self.time, (int, float, np.integer, np.floating)) or \
                not math.isfinite(float(self.time)):
            raise ValueError(f"time must be a finite number; got {self.time!r}.")
        if not _is_int(self.agent) or self.agent < 0:
            raise ValueError(f"agent must be an integer >= 0; got {self.agent!r}.")
        if (self.partner is None) == (self.point is None):
            raise ValueError("an observation needs exactly one observer: a partner robot or a fixed point; got "
                             f"partner={self.partner!r}, point={self.point!r}.")
        if self.partner is not None and (not _is_int(self.partner) or self.partner < 0 or self.partner == self.agent):
            raise ValueError(f"partner must be another robot's index; got {self.partner!r} for agent {self.agent}.")
        if self.point is not None:
            pt = tuple(float(v) for v in self.point)
            if len(pt) != 2 or not all(math.isfinite(v) for v in pt):
                raise ValueError(f"point must be two finite numbers (x, y); got {self.point!r}.")
            object.__setattr__(self, "point", pt)


@dataclasses.dataclass(frozen=True)
class Segment:
    """Robot ``agent`` between two consecutive observations: observer 1 at ``t1``, observer 2 at ``t2``. An
    observer is ``("agent", j, t)`` (robot ``j``'s position at ``t``) or ``("point", (x, y))``."""

    agent: int
    t1: float
    t2: float
    observer1: tuple
    observer2: tuple


def observations_of(observations, agent: int) -> list[tuple[float, tuple]]:
    """The observations robot ``agent`` takes part in, in time order: ``(time, observer)``. A co-observation
    ``(agent=a, partner=b)`` counts for both robots: each observes the other."""
    out = []
    for ob in observations:
        if ob.agent == agent:
            out.append((float(ob.time), ("agent", ob.partner, float(ob.time)) if ob.partner is not None
                        else ("point", ob.point)))
        elif ob.partner == agent:
            out.append((float(ob.time), ("agent", ob.agent, float(ob.time))))
    out.sort(key=lambda item: item[0])
    return out


def segments(observations, n_agents: int) -> list[Segment]:
    """Every robot's reachability segments: one per pair of its consecutive observations (the start and the goal
    must be in ``observations`` as fixed-point observations if they are observed)."""
    out = []
    for i in range(n_agents):
        obs = observations_of(observations, i)
        for (t1, o1), (t2, o2) in itertools.pairwise(obs):
            if t2 > t1:
                out.append(Segment(i, t1, t2, o1, o2))
    return out


def observer_position(observer: tuple, positions) -> np.ndarray:
    """The observer's position from ``positions`` ``(n_agents, n_times, 2)`` sampled at integer times (plan steps)."""
    if observer[0] == "point":
        return np.asarray(observer[1], float)
    _, j, t = observer
    return np.asarray(positions[j, round(t)], float)

"""One mission under receding-horizon control (survivability paper, Section IV-A, eqs. 5-12).

At each decision point the ownship knows the partially known intruders' nominal paths and uncertainty (through the
segment robustness ``p``, :mod:`stp_env.survivability.robustness`) and the actual paths of the intruders revealed so
far (their cells are blocked for the counts). It

1. recomputes the DP tables (:mod:`stp_env.survivability.dp`) if its knowledge changed;
2. widens the terminal set ``Omega`` from the goal to the goal and the alternative sites if no known-feasible
   trajectory reaches the goal any more (the paper's rule after constraint 12); the widening is permanent;
3. keeps the primitives whose segment is known-feasible and whose successor can still reach ``Omega``; if none is
   left the mission fails (outcome ``L``, an emergency landing);
4. picks the primitive with the best objective (:func:`stp_env.survivability.dp.scores`; ties are broken at random);
5. checks the chosen segment against the actual traffic: if an intruder's actual path blocks one of its cells, the
   conflict reveals that intruder (its whole actual path becomes known, Section III-B: an unknown intruder is
   unseen "until the ownship encounters a conflict"; a partially known intruder's actual path is revealed the same
   way) and the decision is made again with the new knowledge; otherwise the ownship flies the segment.

It lands as soon as it reaches a terminal state of ``Omega``: the goal (outcome ``G``, success) or an alternative
site (``A``, survival). A mission never flies into a blocked cell, so the outcome is decided by whether some
known-feasible way to ``Omega`` remains at every decision.

Step 5 is the default reveal model, ``PlannerConfig(reveal="segment")``: a conflict anywhere on the next segment,
up to ``window_min`` ahead, reveals the intruder at the decision point. The other models
(:data:`stp_env.survivability.config.REVEAL_MODELS`) look less far ahead:

- ``reveal="step"`` reads "until the ownship encounters a conflict" literally: at each whole time step ``t`` (the
  decision point and every minute of the segment after it) the ownship checks only the cells it occupies in the next
  time cell ``[t, t + cell_min)``; an intruder whose actual path blocks one of them is revealed at ``t``. Found at the
  decision point, the decision is made again (step 5). Found later, it cannot be avoided: "the vehicle maintains
  constant heading and speed until it reaches the next decision point" (Section II), so the mission ends there as an
  emergency landing (``L``, :attr:`MissionResult.conflict_minute`).
- ``reveal="radius"`` adds sensing: at each whole time step the intruders whose actual position lies closer than
  ``sense_km`` to the ownship's are revealed too (their whole actual path: the paper knows an intruder either by
  its nominal path and tube or, "if r = 0", by its exact path, Section III-B, so a sensed intruder becomes a known
  one). Sensed at the decision point, the decision uses it; sensed mid-segment on a cell of the rest of the
  segment, it is an unavoidable conflict as above; otherwise the next decision uses it.
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from stp_env.survivability import dp
from stp_env.survivability.config import POLICIES, MissionConfig, PlannerConfig, TrafficConfig
from stp_env.survivability.graph import Graph, segments_through
from stp_env.survivability.robustness import segment_robustness
from stp_env.survivability.traffic import Traffic, curve_points, occupancy, sample_traffic

OUTCOMES = ("G", "A", "L")
SWEEP_FROM_CURRENT_ABOVE = 20_000   # graph states
CONE_STATES_MAX = 4_000             # a recomputation over at most this many reachable states runs in numpy


@dataclasses.dataclass(frozen=True, eq=False)
class Instance:
    """One traffic instance and what every policy's mission shares: the segment robustness and the actual paths'
    cells."""

    traffic: Traffic
    robustness: np.ndarray     # (n_seg,) float32
    occupancy: np.ndarray      # (n_cells, N) bool: cells of each intruder's actual path
    blocked_bits: np.ndarray | None = None   # (n_seg, W) uint32: realisations blocking each segment (pi_S's R)
    known_key: bytes = b""     # digest of everything the robustness depends on (see make_instance's ``reuse``)


def make_instance(graph: Graph, traffic_config: TrafficConfig, planner: PlannerConfig, seed,
                  reuse: Instance | None = None) -> Instance:
    """Draw the traffic of ``seed`` (see :func:`stp_env.survivability.traffic.sample_traffic`) and compute its
    segment robustness with ``planner.n_mc`` realisations.

    ``reuse``: an instance of the same graph whose robustness (and ``pi_S``'s realisation bits) this one may
    share. The robustness depends only on the partially known intruders, the Monte Carlo stream of ``seed`` and the
    Monte Carlo settings, so the instances of one seed in scenarios that differ only in ``N_u`` share it (common
    random numbers). It is shared only when a digest of all of these (the partially known intruders' arrays
    included) matches; otherwise it is computed."""
    seq = np.random.SeedSequence(seed)
    traffic_seq, mc_seq = seq.spawn(2)
    mission = graph.net.mission
    traffic = sample_traffic(traffic_seq, mission, traffic_config)
    key = _known_key(traffic, traffic_config, planner, mc_seq)
    if reuse is not None and reuse.known_key == key:
        p, bits = reuse.robustness, reuse.blocked_bits
    else:
        out = segment_robustness(np.random.default_rng(mc_seq), graph, traffic,
                                 uncertainty_km=traffic_config.uncertainty_km, n_mc=planner.n_mc,
                                 samples_per_min=traffic_config.samples_per_min, keep=planner.n_survival,
                                 model=traffic_config.model)
        p, bits = out if planner.n_survival else (out, None)
    occ = occupancy(traffic, mission, traffic_config.samples_per_min, graph.cell_id, graph.n_cells)
    return Instance(traffic, p, occ, bits, key)


def _known_key(traffic: Traffic, config: TrafficConfig, planner: PlannerConfig, mc_seq) -> bytes:
    """Digest of what :func:`segment_robustness` reads: the partially known intruders' nominal curves and times,
    the uncertainty, realisation model and rasterisation settings, the Monte Carlo settings and the Monte Carlo
    stream's seed."""
    n = traffic.n_partial
    h = hashlib.sha256()
    for a in (traffic.nominal[:n], traffic.t_in[:n], traffic.duration[:n]):
        a = np.ascontiguousarray(a)
        h.update(repr((a.dtype.str, a.shape)).encode())
        h.update(a.tobytes())
    h.update(repr((n, config.uncertainty_km, config.samples_per_min, config.model, planner.n_mc, planner.n_survival,
                   mc_seq.entropy, mc_seq.spawn_key)).encode())
    return h.digest()


@dataclasses.dataclass(frozen=True)
class MissionResult:
    outcome: str                  # "G" (goal), "A" (alternative site) or "L" (no way left: emergency landing)
    path: tuple[int, ...]         # graph state indices flown, from the origin
    revealed: tuple[int, ...]     # intruders revealed (by conflicts, or sensed), in order
    omega_switch: int | None      # window at which Omega was widened to the alternative sites (None: never)
    n_dp: int                     # DP sweeps computed
    reveal_minutes: tuple[int, ...] = ()   # minute (since departure) at which each of ``revealed`` was revealed
    conflict_minute: int | None = None     # time cell of an unavoidable conflict that ended the mission (``L``)

    @property
    def success(self) -> bool:
        return self.outcome == "G"

    @property
    def survival(self) -> bool:
        return self.outcome in ("G", "A")


class Knowledge:
    """What the ownship knows of the blocked cells: the actual paths of the revealed intruders."""

    def __init__(self, graph: Graph, instance: Instance):
        self.graph, self.instance = graph, instance
        self.blocked = np.zeros(graph.n_cells + 1, bool)      # last entry: the padding cell, never blocked
        self.revealed: list[int] = []
        self.minutes: list[int] = []                         # when each of ``revealed`` was revealed
        self.feasible = np.ones(graph.n_segments, bool)

    def reveal(self, intruders, minute: int = -1) -> None:
        """Make the whole actual paths of ``intruders`` known (``minute``: when, since departure)."""
        for i in intruders:
            self.revealed.append(int(i))
            self.minutes.append(int(minute))
        new = self.instance.occupancy[:, list(intruders)].any(axis=1) & ~self.blocked[:-1]
        self.blocked[:-1] |= new
        # Only the segments through a newly blocked cell change (a new array: earlier ones may be held elsewhere).
        feasible = self.feasible.copy()
        feasible[segments_through(self.graph, np.flatnonzero(new))] = False
        self.feasible = feasible

    def conflicts(self, segment: int, minute: int | None = None) -> np.ndarray:
        """Intruders whose actual path blocks a cell of ``segment`` (only its cells of time cell ``minute``, since
        departure, if given)."""
        cells = self.graph.seg_cells[segment]
        cells = cells[cells >= 0]
        if minute is not None:
            cells = cells[self.graph.cells[cells, 2] == minute]
        return np.nonzero(self.instance.occupancy[cells].any(axis=0))[0]

    def sense(self, minute: int, position_km, radius_km: float) -> np.ndarray:
        """Intruders not yet revealed whose actual position at ``minute`` (since departure; an intruder is present
        from ``t_in`` to ``t_in + duration``) lies closer than ``radius_km`` to ``position_km``."""
        traffic = self.instance.traffic
        t = float(minute) * self.graph.net.mission.cell_min
        unseen = np.ones(traffic.n, bool)
        unseen[self.revealed] = False
        who = np.flatnonzero(unseen & (traffic.t_in <= t) & (t <= traffic.t_in + traffic.duration))
        if not who.size:
            return who
        s = np.clip((t - traffic.t_in[who]) / traffic.duration[who], 0.0, 1.0)
        pts, _ = curve_points(traffic.actual, who, s)
        return who[np.linalg.norm(pts - np.asarray(position_km, float), axis=1) < radius_km]


def choose(graph: Graph, g: int, policy: str, beta: float, tables, feasible, robustness, omega: str,
           rng: np.random.Generator) -> int | None:
    """The primitive of ``policy`` at state ``g`` (``None``: no known-feasible primitive keeps ``Omega`` in
    reach). ``tables``: numpy :class:`stp_env.survivability.dp.Tables`."""
    succ, seg = graph.succ[g], graph.seg[g]
    ok = succ >= 0
    s = np.where(ok, succ, 0)
    n_om = tables.n_goal if omega == "goal" else tables.n_all
    ok &= feasible[np.where(ok, seg, 0)] & (n_om[s] > 0)
    if not ok.any():
        return None
    p1 = np.where(ok, robustness[np.where(ok, seg, 0)], 0.0)
    score = np.where(ok, dp.scores(policy, beta, tables, s, p1), -np.inf)
    best = score.max()
    ties = np.flatnonzero(ok & (score >= best - 1e-6 * max(1.0, abs(best))))
    return int(ties[0] if len(ties) == 1 else rng.choice(ties))


def run_mission(graph: Graph, instance: Instance, policy: str, planner: PlannerConfig, seed=0,
                initial_tables: dp.Tables | None = None) -> MissionResult:
    """Fly one mission of ``policy`` through ``instance``'s traffic (see the module docstring); ``seed`` drives
    the tie-breaking. ``initial_tables``: the policy's tables with nothing revealed and ``Omega`` = goal (numpy),
    if already computed (:func:`initial_tables`, with the same ``planner.nf_count``)."""
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; allowed: {', '.join(POLICIES)}.")
    rng = np.random.default_rng(seed)
    know = Knowledge(graph, instance)
    omega, switch, n_dp = "goal", None, 0
    g, path = graph.origin, [graph.origin]

    def compute():
        nonlocal n_dp
        n_dp += 1
        # Only the states reachable from here matter from now on: from the third window on they are a few percent
        # of the graph, and a numpy sweep over them gives the same entries as the compiled sweep over all states.
        if graph.window_of(g) > 0 and dp.cone_applies(policy, instance.blocked_bits, planner.nf_count):
            layers = dp.cone(graph, g, limit=CONE_STATES_MAX)
            if layers is not None:
                return dp.cone_tables(graph, know.feasible, instance.robustness, policy, omega, g,
                                      instance.blocked_bits, layers, planner.nf_count)
        # Windows before the current one do not matter; on small graphs a full sweep is cheaper than compiling
        # one program per starting window.
        start = graph.window_of(g) if graph.n_states > SWEEP_FROM_CURRENT_ABOVE else 0
        return _numpy(dp.tables(graph, know.feasible, instance.robustness, policy, omega, start,
                                instance.blocked_bits, planner.nf_count))

    tables, stale = initial_tables, initial_tables is None
    sensed, conflict = -1, None
    while True:
        if graph.term_goal[g] or (omega == "all" and graph.term_alt[g]):
            outcome = "G" if graph.term_goal[g] else "A"
            break
        if g != sensed:                     # reveal="radius": what is within sense_km on arrival at g
            sensed = g
            stale |= sense_here(graph, know, g, planner)
        if stale:
            tables, stale = compute(), False
        if omega == "goal" and tables.n_goal[g] == 0:
            omega, switch = "all", graph.window_of(g)
            tables = compute()
        a = choose(graph, g, policy, planner.beta, tables, know.feasible, instance.robustness, omega, rng)
        if a is None:
            outcome = "L"
            break
        hit, minute = check_before(graph, know, g, a, planner)
        if hit.size:
            know.reveal(hit, minute)
            tables = compute()
            continue
        conflict, stale = fly(graph, know, g, a, planner)
        if conflict is not None:
            outcome = "L"
            break
        g = int(graph.succ[g, a])
        path.append(g)
    return MissionResult(outcome, tuple(path), tuple(know.revealed), switch, n_dp, tuple(know.minutes), conflict)


def decision_minute(graph: Graph, g: int) -> int:
    """The time step (minute since departure, in ``cell_min`` cells) of decision point ``g``."""
    return graph.net.window_start_minute(graph.window_of(g))


def position_km(graph: Graph, g: int, a: int | None = None, j: int = 0) -> np.ndarray:
    """The ownship's position [km] ``j`` time steps after decision point ``g`` along primitive ``a``'s segment: on
    the straight line between the two cell centres (Assumption II.2), ``j / minutes_per_window`` of the way."""
    xy = graph.states[g, :2].astype(np.float64)
    p = xy + 0.5
    if a is not None and j:
        p = p + (graph.states[graph.succ[g, a], :2] - xy) * (j / graph.net.minutes_per_window)
    return p * graph.net.mission.cell_km


def sense_here(graph: Graph, know: Knowledge, g: int, planner: PlannerConfig) -> bool:
    """With ``planner.reveal == "radius"``, reveal the intruders within ``planner.sense_km`` of the ownship at
    decision point ``g``; whether any was (always ``False`` with the other reveal models)."""
    if planner.reveal != "radius":
        return False
    minute = decision_minute(graph, g)
    near = know.sense(minute, position_km(graph, g), planner.sense_km)
    if near.size:
        know.reveal(near, minute)
    return bool(near.size)


def check_before(graph: Graph, know: Knowledge, g: int, a: int, planner: PlannerConfig) -> tuple[np.ndarray, int]:
    """The intruders a conflict reveals at decision point ``g`` before primitive ``a`` is flown, and the minute:
    those blocking any cell of its segment (``reveal="segment"``) or only its cells of the first time step
    (``step``, ``radius``)."""
    minute = decision_minute(graph, g)
    seg = graph.seg[g, a]
    return (know.conflicts(seg) if planner.reveal == "segment" else know.conflicts(seg, minute)), minute


def fly(graph: Graph, know: Knowledge, g: int, a: int, planner: PlannerConfig) -> tuple[int | None, bool]:
    """Fly primitive ``a``'s segment from decision point ``g`` after its first time step, one time step at a time
    (``reveal="step"`` or ``"radius"``; nothing happens with ``"segment"``, whose decision point saw the whole
    segment). At each whole time step ``t`` inside the segment the intruders whose actual path blocks the segment's
    cells of time cell ``t`` are revealed, and with ``radius`` those within ``sense_km``. If a revealed path blocks
    a cell of the segment at ``t`` or later, the ownship cannot avoid it (its primitive holds until the next
    decision point, Section II). Returns ``(minute of that cell or None, whether anything was revealed)``."""
    if planner.reveal == "segment":
        return None, False
    seg = graph.seg[g, a]
    cells = graph.seg_cells[seg]
    cells = cells[cells >= 0]
    minutes = graph.cells[cells, 2]
    t0 = decision_minute(graph, g)
    changed = False
    for j in range(1, graph.net.minutes_per_window):
        t = t0 + j
        new = know.conflicts(seg, t)
        if planner.reveal == "radius":
            new = np.union1d(new, know.sense(t, position_km(graph, g, a, j), planner.sense_km))
        new = new[~np.isin(new, know.revealed)]
        if not new.size:
            continue
        know.reveal(new, t)
        changed = True
        ahead = minutes >= t
        hit = know.blocked[cells[ahead]]
        if hit.any():
            return int(minutes[ahead][hit].min()), True
    return None, changed


def _numpy(t: dp.Tables) -> dp.Tables:
    return dp.Tables(*(np.asarray(x) for x in t))


def initial_tables(graph: Graph, instance: Instance, policies, nf_count: str = "landing") -> dict[str, dp.Tables]:
    """Every policy's tables before any conflict (``Omega`` = goal), in one sweep (``nf_count``: what ``pi_Nf``
    counts, :attr:`stp_env.survivability.config.PlannerConfig.nf_count`)."""
    out = dp.tables_many(graph, np.ones(graph.n_segments, bool), instance.robustness, tuple(policies), "goal",
                         blocked_bits=instance.blocked_bits, nf_count=nf_count)
    return {q: _numpy(t) for q, t in out.items()}


def default_graph(mission: MissionConfig | None = None) -> Graph:
    from stp_env.survivability.graph import build_graph
    from stp_env.survivability.network import build_network

    return build_graph(build_network(mission))

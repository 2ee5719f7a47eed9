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
"""

from __future__ import annotations

import dataclasses
import hashlib

import numpy as np

from stp_env.survivability import dp
from stp_env.survivability.config import POLICIES, MissionConfig, PlannerConfig, TrafficConfig
from stp_env.survivability.graph import Graph, segments_through
from stp_env.survivability.robustness import segment_robustness
from stp_env.survivability.traffic import Traffic, occupancy, sample_traffic

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
    revealed: tuple[int, ...]     # intruders revealed by conflicts, in order
    omega_switch: int | None      # window at which Omega was widened to the alternative sites (None: never)
    n_dp: int                     # DP sweeps computed

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
        self.feasible = np.ones(graph.n_segments, bool)

    def reveal(self, intruders) -> None:
        for i in intruders:
            self.revealed.append(int(i))
        new = self.instance.occupancy[:, list(intruders)].any(axis=1) & ~self.blocked[:-1]
        self.blocked[:-1] |= new
        # Only the segments through a newly blocked cell change (a new array: earlier ones may be held elsewhere).
        feasible = self.feasible.copy()
        feasible[segments_through(self.graph, np.flatnonzero(new))] = False
        self.feasible = feasible

    def conflicts(self, segment: int) -> np.ndarray:
        """Intruders whose actual path blocks a cell of ``segment``."""
        cells = self.graph.seg_cells[segment]
        cells = cells[cells >= 0]
        return np.nonzero(self.instance.occupancy[cells].any(axis=0))[0]


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
        if graph.window_of(g) > 0:
            layers = dp.cone(graph, g)
            if sum(len(x) for x in layers) <= CONE_STATES_MAX:
                out = dp.cone_tables(graph, know.feasible, instance.robustness, policy, omega, g,
                                     instance.blocked_bits, layers, planner.nf_count)
                if out is not None:
                    return out
        # Windows before the current one do not matter; on small graphs a full sweep is cheaper than compiling
        # one program per starting window.
        start = graph.window_of(g) if graph.n_states > SWEEP_FROM_CURRENT_ABOVE else 0
        return _numpy(dp.tables(graph, know.feasible, instance.robustness, policy, omega, start,
                                instance.blocked_bits, planner.nf_count))

    tables = compute() if initial_tables is None else initial_tables
    while True:
        if graph.term_goal[g] or (omega == "all" and graph.term_alt[g]):
            outcome = "G" if graph.term_goal[g] else "A"
            break
        if omega == "goal" and tables.n_goal[g] == 0:
            omega, switch = "all", graph.window_of(g)
            tables = compute()
        a = choose(graph, g, policy, planner.beta, tables, know.feasible, instance.robustness, omega, rng)
        if a is None:
            outcome = "L"
            break
        hit = know.conflicts(graph.seg[g, a])
        if hit.size:
            know.reveal(hit)
            tables = compute()
            continue
        g = int(graph.succ[g, a])
        path.append(g)
    return MissionResult(outcome, tuple(path), tuple(know.revealed), switch, n_dp)


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

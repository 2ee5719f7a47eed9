"""Missions in batches: the receding-horizon missions of many traffic instances and policies in one compiled
program (survivability paper, Section IV-A, eqs. 5-12; the per-mission reference is
:func:`stp_env.survivability.mission.run_mission`).

:func:`run_batch` flies every policy through every instance of a batch with the same decisions as
:func:`~stp_env.survivability.mission.run_mission` (one mission per ``(instance, policy)``), in a single jitted
``lax.while_loop`` over decision steps, with no Python per decision, on CPU and unchanged on a GPU:

1. the policies' first DP tables (nothing revealed, ``Omega`` = goal; :func:`stp_env.survivability.dp.tables_jit`)
   for every distinct robustness of the batch at once (``jax.vmap``; instances that share their robustness, one
   instance of the scenarios with the same ``N_p``, share these tables, as in
   :func:`stp_env.survivability.study.run_instance`);
2. then, while a mission flies, either **one recomputation** (when some mission's knowledge or ``Omega`` changed:
   the one with the lowest index has its segment feasibility recomputed from the intruders it knows, and its
   policy's DP sweep for its ``Omega`` from its current window, the same ``tables_jit`` program the per-mission
   path runs; a ``lax.switch`` over (``Omega``, policy) really branches, since it is not under ``vmap``), or **one
   decision step of every mission** (``jax.vmap``): landing at a terminal state of ``Omega``; widening ``Omega``
   to the alternative sites when the goal is out of reach (the rule after constraint 12); the choice of the
   primitive with the best objective (eq. 5, :func:`stp_env.survivability.dp.scores`) among the known-feasible
   ones that keep ``Omega`` in reach (constraints 10-12), ties broken at random; the check of its segment against
   the actual traffic (Section III-B: a conflict reveals the intruder's whole actual path) or the flight to the
   successor.

Each mission goes through the same sequence of states as alone: the batch only interleaves them. What makes the
results **bit for bit** those of ``run_mission``:

* the DP tables come from the same compiled sweep (``dp.tables_jit``, same static arguments: ``exact`` only for
  ``pi_S`` with the realisation bits, as :func:`stp_env.survivability.dp.tables_many` sets it). Where the
  per-mission path recomputes over the states reachable from the current one in numpy
  (:func:`stp_env.survivability.dp.cone_tables`), those entries equal the compiled sweep's (its docstring), and
  a mission reads no other entry;
* the objective is evaluated in float32 with the same operations as :func:`stp_env.survivability.dp.scores` and
  :func:`stp_env.survivability.mission.choose` (the tie tolerance ``1e-6 max(1, |best|)`` included);
* the tie-breaking consumes the same random numbers: ``run_mission`` draws ``rng.choice(ties)`` from
  ``numpy.random.default_rng(seed)``, i.e. Lemire's bounded integer on the generator's 32-bit outputs (each
  64-bit PCG64 output gives its low then its high half). The batch pre-draws those outputs on the host
  (``STREAM`` per mission) and repeats Lemire's method, rejections included, in uint32 arithmetic
  (:mod:`stp_env.survivability.ties`). A mission that would need more outputs than it was given (never seen; it
  would take over ``STREAM / 2`` ties) is flown again by ``run_mission``;
* segment feasibility from the revealed intruders' occupied cells (intruder bit sets per cell) equals
  :class:`stp_env.survivability.mission.Knowledge`'s incremental update (a segment is infeasible iff one of its
  cells is occupied by a revealed intruder's actual path).

Only the default reveal model ``reveal="segment"`` is batched (:data:`BATCHED_REVEALS`); with ``step`` or
``radius`` (mid-segment reveals and sensing) :func:`run_batch` flies the missions with ``run_mission``.
``tests/test_survivability_batch.py`` checks the equality mission by mission (every field of
:class:`~stp_env.survivability.mission.MissionResult`).

:func:`batch_robustness` is the Monte Carlo segment robustness (Section III-B, Fig. 4;
:func:`stp_env.survivability.robustness.segment_robustness`) of several instances' realisations in one vmapped
program, from the same host draws of each instance's Monte Carlo stream; the realisation bits are set by a
scatter of ``True`` (order-free), so the robustness is equal bit for bit.

Cost. The decision steps are cheap; a recomputation is a sweep over every state from the mission's current window.
The per-mission path sweeps only the states reachable from the current one after the first window, in numpy
(:func:`stp_env.survivability.dp.cone_tables`), so on a CPU the batch is slower than one mission at a time
(0.5-0.9x on the paper's mission, ``benchmarks/survivability_batch.py``, BENCHMARKS.md) and the study does not
use it by default (:data:`stp_env.survivability.study.BATCH_GROUPS`). Each distinct shape (missions in the batch,
distinct robustness arrays, intruder words) is one compilation, about 10-45 s; the study pads its batches to
one shape per number of groups (``pad_instances``) and the intruders to a power of two.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from stp_env.survivability import dp
from stp_env.survivability import robustness as rob
from stp_env.survivability.config import POLICIES, PlannerConfig
from stp_env.survivability.graph import Graph
from stp_env.survivability.mission import Instance, MissionResult, _known_key, initial_tables, run_mission
from stp_env.survivability.ties import STREAM, lemire, tie_streams
from stp_env.survivability.traffic import occupancy, sample_traffic

BATCHED_REVEALS = ("segment",)
"""The reveal models (:data:`stp_env.survivability.config.REVEAL_MODELS`) flown in the compiled batch."""
_OUTCOMES = ("G", "A", "L")


class _Consts(NamedTuple):
    """A graph's arrays for the decision steps (device arrays, arguments of the jitted program)."""

    succ: jax.Array         # (S, A) int32, -1: none
    seg: jax.Array          # (S, A) int32, -1: none
    term_goal: jax.Array    # (S,) bool
    term_alt: jax.Array     # (S,) bool
    window: jax.Array       # (S,) int32: window of each state
    minute: jax.Array       # (S,) int32: decision minute of each state
    seg_cells: jax.Array    # (n_seg, O) int32, padding -> n_cells (a row of no intruder)


@functools.lru_cache(maxsize=4)
def _graph_consts(graph: Graph) -> _Consts:
    ws = graph.window_start
    K = graph.net.n_windows
    window = np.repeat(np.arange(K + 1), np.diff(ws)).astype(np.int32)
    starts = np.array([graph.net.window_start_minute(k) for k in range(K + 1)], np.int32)
    seg_cells = np.where(graph.seg_cells >= 0, graph.seg_cells, graph.n_cells).astype(np.int32)
    return _Consts(jnp.asarray(graph.succ, jnp.int32), jnp.asarray(graph.seg, jnp.int32),
                   jnp.asarray(graph.term_goal), jnp.asarray(graph.term_alt), jnp.asarray(window),
                   jnp.asarray(starts[window]), jnp.asarray(seg_cells))


class _State(NamedTuple):
    g: jax.Array            # (B,) current state
    omega: jax.Array        # (B,) 0: goal, 1: goal and alternative sites
    need: jax.Array         # (B,) bool: the tables must be recomputed before the next decision
    done: jax.Array         # (B,) bool
    outcome: jax.Array      # (B,) 0 G, 1 A, 2 L
    n_dp: jax.Array         # (B,)
    switch: jax.Array       # (B,) window of the Omega widening (-1: never)
    fresh: jax.Array        # (B,) bool: Omega was just widened, the next decision chooses without landing first
    path: jax.Array         # (B, K + 1)
    n_path: jax.Array       # (B,) states in path
    cursor: jax.Array       # (B,) next output of the tie-breaking stream
    revealed: jax.Array     # (B, NW) uint32 bit set of the revealed intruders
    event: jax.Array        # (B, N) int32: reveal event at which each intruder was revealed (-1: never)
    rminute: jax.Array      # (B, N) int32: minute of that reveal
    n_events: jax.Array     # (B,)
    feasible: jax.Array     # (B, n_seg) bool
    tables: jax.Array       # (B, 4, S) float32: n_goal, n_all, value, future of the mission's policy


@functools.partial(jax.jit, static_argnums=(0, 1, 2, 3, 4, 5, 6))
def _run(meta, policies, exact, nf_count, beta, n_path, n_intruders, c, gc, robustness, bits, occ, known_of,
         inst_of, policy_of, streams):
    """The batch's missions (see the module docstring). ``robustness`` ``(U, n_seg)`` and ``bits`` ``(U, n_seg,
    W)`` uint32 of the distinct robustness inputs, ``known_of`` ``(I,)`` which one each instance has (their first
    tables are computed once), ``occ`` ``(I, n_cells + 1, NW)`` uint32 intruder bit sets per cell (last row
    empty); ``inst_of``, ``policy_of`` ``(B,)``: each mission's instance and policy index; ``streams``
    ``(B, STREAM)`` uint32."""
    n_seg = robustness.shape[1]
    B = inst_of.shape[0]
    P = len(policies)
    ones = jnp.ones(n_seg, bool)
    beta32 = jnp.float32(beta)

    def first(r, b):
        return dp.tables_jit(meta, c, ones, r, jnp.int32(0), b, policies, "goal", exact, nf_count)

    tabs = jax.vmap(first)(robustness, bits)                 # per policy: Tables of (U, S)
    stacked = jnp.stack([jnp.stack(list(t), 1) for t in tabs], 1)     # (U, P, 4, S)
    tables0 = stacked[known_of[inst_of], policy_of]          # (B, 4, S)
    NW = occ.shape[-1]

    st = _State(g=jnp.zeros(B, jnp.int32), omega=jnp.zeros(B, jnp.int32), need=jnp.zeros(B, bool),
                done=jnp.zeros(B, bool), outcome=jnp.zeros(B, jnp.int32), n_dp=jnp.zeros(B, jnp.int32),
                switch=jnp.full(B, -1, jnp.int32), fresh=jnp.zeros(B, bool),
                path=jnp.full((B, n_path), -1, jnp.int32).at[:, 0].set(0),
                n_path=jnp.ones(B, jnp.int32), cursor=jnp.zeros(B, jnp.int32),
                revealed=jnp.zeros((B, NW), jnp.uint32), event=jnp.full((B, n_intruders), -1, jnp.int32),
                rminute=jnp.full((B, n_intruders), -1, jnp.int32), n_events=jnp.zeros(B, jnp.int32),
                feasible=jnp.ones((B, n_seg), bool), tables=tables0)

    no_bits = jnp.zeros((1, 1), jnp.uint32)

    def sweep_branch(omega, q):
        """The per-mission recomputation for ``Omega`` index ``omega`` and policy ``q``: the segment feasibility
        from the intruders the mission knows (a segment is infeasible iff one of its cells is occupied by a revealed
        intruder's actual path), then ``dp.tables`` from the current window."""
        exact_q = exact and policies[q] == "S"

        def f(i, revealed, start, feasible_old, tables_old):
            cell_hit = jnp.any((occ[i] & revealed[None]) != 0, axis=1)                 # (n_cells + 1,)
            feasible = ~jnp.any(cell_hit[gc.seg_cells], axis=1)
            k = known_of[i]
            t = dp.tables_jit(meta, c, feasible, robustness[k], start, bits[k] if exact_q else no_bits, (policies[q],),
                              ("goal", "all")[omega], exact_q, nf_count)[0]
            return feasible, jnp.stack(list(t))
        return f

    def keep(i, revealed, start, feasible_old, tables_old):
        return feasible_old, tables_old

    branches = [keep] + [sweep_branch(o, q) for o in (0, 1) for q in range(P)]

    def decide_one(g, omega, done, outcome, switch, fresh, path, n_path, cursor, revealed, event, rminute, n_events,
                   feasible, tables, i, q, stream):
        """One decision step of one mission (nothing happens when it is done)."""
        # Gathers straight from the batch's arrays (a slice per mission would copy whole tables every step).
        tg, ta = gc.term_goal[g], gc.term_alt[g]
        # Right after widening Omega the per-mission loop chooses at once (it checks for a landing at its next
        # decision point only).
        lands = ~fresh & (tg | ((omega == 1) & ta))
        widen = ~lands & (omega == 0) & (tables[0, g] == 0)
        succ, seg = gc.succ[g], gc.seg[g]
        ok = succ >= 0
        s = jnp.where(ok, succ, 0)
        sg = jnp.where(ok, seg, 0)
        n_om = jnp.where(omega == 0, tables[0, s], tables[1, s])
        ok = ok & feasible[sg] & (n_om > 0)
        p1 = jnp.where(ok, robustness[known_of[i], sg], jnp.float32(0.0))
        fut, val = tables[3, s], tables[2, s]
        name = jnp.asarray([POLICIES.index(p) for p in policies], jnp.int32)[q]
        score_r = p1 + beta32 * fut
        score_nf = val + beta32 * fut
        score_v = p1 + beta32 * (val + fut)
        score = jnp.where(name == POLICIES.index("R"), score_r, jnp.where(name == POLICIES.index("Nf"), score_nf,
                                                                          score_v))
        score = jnp.where(ok, score, -jnp.inf)
        best = jnp.max(score)
        tol = jnp.float32(1e-6) * jnp.maximum(jnp.float32(1.0), jnp.abs(best))
        ties = ok & (score >= best - tol)
        n_ties = jnp.sum(ties.astype(jnp.int32))
        pick, cursor2 = lemire(stream, cursor, jnp.maximum(n_ties, 1))
        rank = jnp.cumsum(ties.astype(jnp.int32)) - 1
        a = jnp.where(n_ties == 1, jnp.argmax(ties), jnp.argmax(ties & (rank == pick))).astype(jnp.int32)
        chooses = ~done & ~lands & ~widen
        stuck = chooses & ~ok.any()
        acts = chooses & ok.any()
        cursor = jnp.where(acts & (n_ties > 1), cursor2, cursor)
        seg_a = seg[a]
        hits = jax.lax.reduce(occ[i, gc.seg_cells[seg_a]], np.uint32(0), jax.lax.bitwise_or, (0,))      # (NW,)
        conflict = acts & jnp.any(hits != 0)
        flies = acts & ~conflict
        # Reveal: the intruders of ``hits``, all new (the chosen segment is feasible given those already known).
        idx = jnp.arange(event.shape[0])
        bit = ((hits[idx // 32] >> (idx % 32).astype(jnp.uint32)) & 1).astype(bool) & conflict
        event = jnp.where(bit, n_events, event)
        rminute = jnp.where(bit, gc.minute[g], rminute)
        n_events = n_events + conflict.astype(jnp.int32)
        revealed = jnp.where(conflict, revealed | hits, revealed)
        g2 = jnp.where(flies, succ[a], g)
        path = jnp.where(flies, path.at[n_path].set(g2), path)
        n_path = n_path + flies.astype(jnp.int32)
        finish = ~done & (lands | stuck)
        outcome = jnp.where(finish, jnp.where(lands, jnp.where(tg, 0, 1), 2), outcome)
        switch = jnp.where(~done & widen, gc.window[g], switch)
        omega = jnp.where(~done & widen, 1, omega)
        need = ~done & (widen | conflict)
        fresh = ~done & widen
        return (g2, omega, need, done | finish, outcome, switch, fresh, path, n_path, cursor, revealed, event, rminute,
                n_events)

    decided = ("g", "omega", "need", "done", "outcome", "switch", "fresh", "path", "n_path", "cursor", "revealed",
               "event", "rminute", "n_events")

    def body(s: _State) -> _State:
        """One recomputation, if a mission needs one (the lowest-indexed: its feasibility and tables are replaced
        in place, outside any branch, so that no copy of the batch's tables is made), else one decision step of
        every mission."""
        waiting = s.need & ~s.done
        busy = jnp.any(waiting)
        j = jnp.argmax(waiting)
        which = jnp.where(busy, 1 + s.omega[j] * P + policy_of[j], 0)
        feasible_j, tables_j = jax.lax.switch(which, branches, inst_of[j], s.revealed[j], gc.window[s.g[j]],
                                              s.feasible[j], s.tables[j])
        s = s._replace(feasible=s.feasible.at[j].set(feasible_j), tables=s.tables.at[j].set(tables_j),
                       need=s.need.at[j].set(s.need[j] & ~busy), n_dp=s.n_dp.at[j].add(busy.astype(jnp.int32)))
        out = jax.vmap(decide_one)(s.g, s.omega, s.done | busy, s.outcome, s.switch, s.fresh, s.path, s.n_path,
                                   s.cursor, s.revealed, s.event, s.rminute, s.n_events, s.feasible, s.tables,
                                   inst_of, policy_of, streams)
        return s._replace(**{name: jnp.where(busy, getattr(s, name), new) for name, new in zip(decided, out)})

    s = jax.lax.while_loop(lambda s: ~jnp.all(s.done), body, st)
    return s.outcome, s.path, s.n_path, s.switch, s.n_dp, s.event, s.rminute, s.cursor


@dataclasses.dataclass(frozen=True)
class BatchInputs:
    """The host arrays of a batch of instances (:func:`stack_instances`)."""

    robustness: np.ndarray      # (U, n_seg) float32: the distinct robustness arrays
    bits: np.ndarray            # (U, n_seg, W) uint32 (W = 1, zeros, without pi_S's realisation bits)
    known_of: np.ndarray        # (I,) int32: each instance's row of ``robustness`` and ``bits``
    occ: np.ndarray             # (I, n_cells + 1, NW) uint32
    n_intruders: tuple[int, ...]
    exact: bool


def stack_instances(graph: Graph, instances, policies) -> BatchInputs:
    """Stack instances of ``graph`` for :func:`run_batch`: their segment robustness, ``pi_S``'s realisation bits
    (when every instance has them and ``S`` flies; the per-mission path's ``exact``) and the actual paths'
    occupied cells as intruder bit sets (``NW`` uint32 words, padded to the largest instance)."""
    instances = list(instances)
    have_bits = [inst.blocked_bits is not None for inst in instances]
    if any(have_bits) and not all(have_bits):
        raise ValueError("the instances of a batch must all have pi_S's realisation bits, or none.")
    exact = all(have_bits) and "S" in policies
    n_max = max(max(inst.occupancy.shape[1] for inst in instances), 1)
    nw = 1 << max(math.ceil(math.log2(-(-n_max // 32))), 0)         # words: a power of two
    occ = np.zeros((len(instances), graph.n_cells + 1, nw), np.uint32)
    for k, inst in enumerate(instances):
        o = np.zeros((graph.n_cells, nw * 32), bool)
        o[:, :inst.occupancy.shape[1]] = inst.occupancy
        occ[k, :-1] = np.packbits(o, axis=1, bitorder="little").view("<u4")
    # Instances that share their robustness (the same arrays, as make_instance's ``reuse`` and make_instances
    # give them) share one row and one first sweep.
    rows: dict = {}
    known_of, firsts = [], []
    for k, inst in enumerate(instances):
        key = (id(inst.robustness), id(inst.blocked_bits))
        if key not in rows:
            rows[key] = len(rows)
            firsts.append(k)
        known_of.append(rows[key])
    bits = (np.stack([instances[k].blocked_bits for k in firsts]) if exact
            else np.zeros((len(firsts), 1, 1), np.uint32))
    return BatchInputs(np.stack([np.asarray(instances[k].robustness, np.float32) for k in firsts]), bits,
                       np.asarray(known_of, np.int32), occ,
                       tuple(int(inst.occupancy.shape[1]) for inst in instances), exact)


def run_batch(graph: Graph, instances, policies, planner: PlannerConfig, seeds,
              pad_instances: int | None = None) -> list[dict[str, MissionResult]]:
    """Every policy's mission through every instance, in one compiled program (the module docstring): the same
    :class:`~stp_env.survivability.mission.MissionResult` as ``run_mission(graph, instances[i], policy, planner,
    seed=seeds[i], initial_tables=initial_tables(graph, instances[i], policies, planner.nf_count)[policy])`` for
    each ``i`` and policy (what :func:`stp_env.survivability.study.run_instance` flies; without ``initial_tables``
    ``run_mission`` counts the first sweep in ``n_dp``, one more). Returns one ``{policy: result}`` per instance.
    ``pad_instances``: fly at least this many instances (copies of the last, whose missions are dropped), so
    that batches of different sizes share one compiled program; the intruders are padded to a power of two
    (at least 32) for the same reason."""
    instances, seeds = list(instances), list(seeds)
    policies = tuple(policies)
    if len(instances) != len(seeds):
        raise ValueError(f"one seed per instance: {len(instances)} instances, {len(seeds)} seeds.")
    for p in policies:
        if p not in POLICIES:
            raise ValueError(f"unknown policy {p!r}; allowed: {', '.join(POLICIES)}.")
    if not instances:
        return []
    if planner.reveal not in BATCHED_REVEALS:
        return [_alone(graph, inst, policies, planner, seed) for inst, seed in zip(instances, seeds)]
    n_real = len(instances)
    if pad_instances is not None and pad_instances > n_real:
        instances = instances + [instances[-1]] * (pad_instances - n_real)
        seeds = seeds + [seeds[-1]] * (pad_instances - n_real)
    x = stack_instances(graph, instances, policies)
    n_inst, P = len(instances), len(policies)
    inst_of = np.repeat(np.arange(n_inst), P).astype(np.int32)
    policy_of = np.tile(np.arange(P), n_inst).astype(np.int32)
    streams = tie_streams(seeds)[inst_of]
    meta, c = dp._consts(graph)
    n_int = x.occ.shape[-1] * 32
    out = _run(meta, policies, x.exact, planner.nf_count, float(planner.beta), graph.net.n_windows + 1, n_int, c,
               _graph_consts(graph), jnp.asarray(x.robustness), jnp.asarray(x.bits), jnp.asarray(x.occ),
               jnp.asarray(x.known_of),
               jnp.asarray(inst_of), jnp.asarray(policy_of), jnp.asarray(streams))
    outcome, path, n_path, switch, n_dp, event, rminute, cursor = (np.asarray(v) for v in out)
    results: list[dict[str, MissionResult]] = [{} for _ in range(n_real)]
    for m in range(n_real * P):
        i, p = int(inst_of[m]), policies[policy_of[m]]
        if cursor[m] > STREAM:      # ran out of pre-drawn outputs: fly this one alone (see the module docstring)
            results[i][p] = _alone(graph, instances[i], (p,), planner, seeds[i], policies)[p]
            continue
        who = np.flatnonzero(event[m] >= 0)
        order = who[np.lexsort((who, event[m, who]))]
        results[i][p] = MissionResult(
            _OUTCOMES[int(outcome[m])], tuple(int(v) for v in path[m, :n_path[m]]), tuple(int(v) for v in order),
            None if switch[m] < 0 else int(switch[m]), int(n_dp[m]), tuple(int(v) for v in rminute[m, order]), None)
    return results


def _alone(graph: Graph, instance: Instance, policies, planner: PlannerConfig, seed, first_policies=None):
    """The per-mission path for ``policies`` (their first tables from one sweep of ``first_policies``, default
    ``policies``, as :func:`stp_env.survivability.study.run_instance` computes them)."""
    first = initial_tables(graph, instance, first_policies or policies, planner.nf_count)
    return {p: run_mission(graph, instance, p, planner, seed=seed, initial_tables=first[p]) for p in policies}


# ---------------------------------------------------------------------------------------------------------------
# Monte Carlo robustness of several instances in one program


def make_instances(graph: Graph, traffic_configs, planner: PlannerConfig, seeds) -> list[Instance]:
    """:func:`stp_env.survivability.mission.make_instance` of each ``(traffic_config, seed)``, with the Monte Carlo
    realisations of all of them in one vmapped program (:func:`batch_robustness`); consecutive instances whose
    robustness inputs are equal (:func:`~stp_env.survivability.mission._known_key`: the same seed and partially
    known traffic, e.g. one instance of scenarios that differ only in ``N_u``) share it, as with ``reuse``."""
    mission = graph.net.mission
    drawn = []
    for config, seed in zip(traffic_configs, seeds):
        traffic_seq, mc_seq = np.random.SeedSequence(seed).spawn(2)
        traffic = sample_traffic(traffic_seq, mission, config)
        drawn.append((config, traffic, mc_seq, _known_key(traffic, config, planner, mc_seq)))
    todo = {}
    for config, traffic, mc_seq, key in drawn:
        todo.setdefault(key, (config, traffic, mc_seq))
    keys = list(todo)
    outs = batch_robustness(graph, [todo[k] for k in keys], planner)
    by_key = dict(zip(keys, outs))
    instances = []
    for config, traffic, _, key in drawn:
        p, bits = by_key[key]
        occ = occupancy(traffic, mission, config.samples_per_min, graph.cell_id, graph.n_cells)
        instances.append(Instance(traffic, p, occ, bits, key))
    return instances


def batch_robustness(graph: Graph, items, planner: PlannerConfig):
    """``[(p, bits)]``: :func:`stp_env.survivability.robustness.segment_robustness` of each ``(traffic_config,
    traffic, mc_seq)`` (``bits`` ``None`` when ``planner.n_survival`` is 0), the realisations of all of them in
    one vmapped ``_cell_bits`` program. Each instance draws its uniforms from its own Monte Carlo stream exactly as
    alone (same shapes, same order); they are padded (points far outside the area, unused intruders) to common
    shapes, which changes no bit: a padded point blocks no cell and a padded intruder is never sampled."""
    keep = planner.n_survival
    prepared, direct = [], {}
    for j, (config, traffic, mc_seq) in enumerate(items):
        n_mc = planner.n_mc
        k = traffic.nominal.shape[1] - 1
        if k < 2 or config.uncertainty_km == 0:
            n_mc = 1
        pts, weights, who, minute = rob.candidate_points(graph, traffic, config.uncertainty_km,
                                                         config.samples_per_min, None, config.model)
        if len(pts) == 0 or n_mc != planner.n_mc:
            # No candidate point, or no uncertainty: the per-instance path (cheap, and its own special cases).
            direct[j] = rob.segment_robustness(np.random.default_rng(mc_seq), graph, traffic,
                                               uncertainty_km=config.uncertainty_km, n_mc=planner.n_mc,
                                               samples_per_min=config.samples_per_min, keep=keep,
                                               model=config.model)
            continue
        if weights.shape[1] == 0:
            weights = np.zeros((len(pts), 1), np.float32)
        used, who = np.unique(who, return_inverse=True)
        n_used = -(-len(used) // 16) * 16
        n_chunks = -(-n_mc // rob.CHUNK)
        u = np.random.default_rng(mc_seq).random((n_chunks, rob.CHUNK, n_used, weights.shape[1], 2),
                                                 dtype=np.float32)
        prepared.append((j, config, u, pts, weights, who.astype(np.int32), minute))
    groups: dict = {}
    for item in prepared:
        j, config, u, pts, weights, who, minute = item
        groups.setdefault((config.uncertainty_km, weights.shape[1]), []).append(item)
    results = dict(direct)
    for (radius, _), group in groups.items():
        n_used = max(it[2].shape[2] for it in group)
        size = max(rob._bucket(len(it[3])) for it in group)
        us, ps, ws, whos, mins = [], [], [], [], []
        for _, _, u, pts, weights, who, minute in group:
            pad = size - len(pts)
            us.append(np.pad(u, ((0, 0), (0, 0), (0, n_used - u.shape[2]), (0, 0), (0, 0))))
            ps.append(np.pad(pts, ((0, pad), (0, 0)), constant_values=-1e6))
            ws.append(np.pad(weights, ((0, pad), (0, 0))))
            whos.append(np.pad(who, (0, pad)))
            mins.append(np.pad(minute, (0, pad)))
        bits = np.asarray(_cell_bits_many(rob._graph_arrays(graph), planner.n_mc, jnp.asarray(np.stack(us)),
                                          jnp.asarray(np.stack(ps)), jnp.asarray(np.stack(ws)),
                                          jnp.asarray(np.stack(whos)), jnp.asarray(np.stack(mins)),
                                          jnp.float32(radius), jnp.float32(graph.net.mission.cell_km)))
        for (j, *_), b in zip(group, bits):
            counts, first = rob.blocked_counts(graph, b, keep)
            p = (1.0 - counts / planner.n_mc).astype(np.float32)
            results[j] = (p, first) if keep else p
    return [results[j] if keep else (results[j], None) for j in range(len(items))]


@functools.partial(jax.jit, static_argnums=(0, 1))
def _cell_bits_many(g, n_mc, u, pts, weights, who, minute, radius, cell_km):
    """:func:`stp_env.survivability.robustness._cell_bits` over a leading instance axis."""
    return jax.vmap(lambda u, p, w, h, m: rob._cell_bits(g, u, p, w, h, m, n_mc, radius, cell_km))(
        u, pts, weights, who, minute)


def run_instances(graph: Graph, traffic_configs, planner: PlannerConfig, seeds, policies):
    """Instances drawn and flown in batches: :func:`make_instances` then :func:`run_batch`. Returns the instances
    and their missions."""
    instances = make_instances(graph, traffic_configs, planner, seeds)
    return instances, run_batch(graph, instances, policies, planner, seeds)



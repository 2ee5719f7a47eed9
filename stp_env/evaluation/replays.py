"""Replaying an evaluated episode bit for bit: :func:`replay` runs again the batch that held it (the same compiled
program and inputs as in :func:`stp_env.evaluation.runner.evaluate`), :func:`replay_event` does so for a saved
event (untrusted data, checked first: :mod:`stp_env.evaluation.events`), and :func:`same_outcome` compares two
final states."""

from __future__ import annotations

import numbers

import jax.numpy as jnp
import numpy as np

from stp_env.evaluation.runner import (
    MAX_EPISODES,
    batch_indices,
    build_params,
    episode_order,
    host_state,
    pad_plan,
    run_batch,
    simulated_vehicles,
)
from stp_env.seeds import check_seed, prng_key
from stp_env.sim import engine
from stp_env.sim.metrics import n_forced as count_forced


def replay(seed: int, index: int, params, vehicle_policy, intruder_policy, n_steps: int, *, batch_size: int = 1,
           record: bool = True, airborne_only: bool = True, progress: bool | None = None,
           episodes: int | None = None, devices: int | None = None):
    """Episode ``index`` of the run with ``seed``: ``(final state, trajectory)`` as numpy dicts (the trajectory
    ``None`` without ``record``).

    The batch of ``batch_size`` episodes that held ``index`` in the evaluation of ``episodes`` episodes
    (:func:`episode_order`) runs again (the same compiled program and inputs as in :func:`evaluate` when ``params``,
    ``n_steps``, ``batch_size`` and ``record`` are the same), so the replay is bit for bit the evaluated episode.
    Without ``episodes`` (a record written before the batches were ordered) the batch is the ``batch_size``
    consecutive indices that hold ``index``: the same program with other batch-mates, which do not change an
    episode (``tests/test_gates.py``). Another batch size is another compiled program, which XLA may vectorize
    differently (10 of 10 town episodes of a batch of 250 replayed alone ended identically). Either
    way the reachability artifacts must be the same as in the evaluation. ``devices``: among how many devices the
    evaluation shared its batches (:func:`stp_env.sim.engine.shares`, saved with each event; ``None``: not known);
    on another count the batch is another program, and a ``RuntimeWarning`` says so. ``airborne_only`` as in
    :func:`evaluate` (the whole fleet or part of it are also different programs). ``progress``: announce the
    replay on standard error (:mod:`stp_env.progress`; ``None``: in a terminal).
    """
    from stp_env import progress as progress_mod

    check_seed(seed)
    checks = [("index", index, 0, MAX_EPISODES - 1), ("batch_size", batch_size, 1, MAX_EPISODES),
              ("n_steps", n_steps, 1, None)]
    if episodes is not None:
        checks.append(("episodes", episodes, 1, MAX_EPISODES))
    for name, value, lo, hi in checks:
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < lo or (
                hi is not None and value > hi):
            raise ValueError(f"{name} must be an integer >= {lo}" + ("" if hi is None else f" and <= {hi}")
                             + f"; got {value!r}.")
    index, batch_size, n_steps = int(index), int(batch_size), int(n_steps)
    if episodes is None:
        first = (index // batch_size) * batch_size
        indices = np.arange(first, first + batch_size, dtype=np.int32)
    else:
        if index >= episodes:
            raise ValueError(f"index {index} is not an episode of a run of {episodes}.")
        order = episode_order(seed, int(episodes), params)
        position = int(np.flatnonzero(order == index)[0])
        indices = batch_indices(order, (position // batch_size) * batch_size, batch_size)
    here = engine.shares(batch_size)
    if devices is not None and int(devices) != here:
        import warnings

        warnings.warn(f"episode {index} was evaluated with its batch shared among {int(devices)} device(s) and is "
                      f"replayed on {here}: another compiled program, so the outcome agrees but the last bits may not "
                      "(set the same count with stp_env.set_cpu_devices before JAX starts for a bit-for-bit replay).",
                      RuntimeWarning, stacklevel=2)
    progress_mod.note(f"replaying episode {index} of seed {seed} in its batch of {batch_size} (compiles the "
                      "simulator's batch once per machine)", progress)
    final, traj = run_batch(prng_key(seed), jnp.asarray(indices), params, vehicle_policy, intruder_policy, n_steps,
                            record=record, active=simulated_vehicles(params, airborne_only))
    j = int(np.flatnonzero(indices == index)[0])
    state = {k: v[j] for k, v in host_state(final).items()}
    state["n_forced"] = count_forced(state["avoid_start"])
    return state, (None if traj is None else {k: np.asarray(v[j]) for k, v in traj.items()})


def prepare_event(event: dict, *, store=None, progress: bool = False, intruder_policy=None,
                  where: str = "event"):
    """What replaying a saved event needs: ``(configuration, params, vehicle policy, intruder policy)``.

    The record is untrusted data (:mod:`stp_env.evaluation.events`): it is checked first, and its intruder must be
    registered or learned; a plug-in spec is refused before any work unless ``intruder_policy`` is given."""
    from stp_env.evaluation.events import check_replay_sizes, event_configuration

    config, vehicle_policy, intruder_policy = event_configuration(event, intruder_policy=intruder_policy,
                                                                  where=where)
    params = build_params([config], store=store, progress=progress)[0]
    check_replay_sizes(event, params, where)
    return config, pad_plan(params, event["plan_samples"]), vehicle_policy, intruder_policy


def replay_event(event: dict, *, store=None, progress: bool = False, intruder_policy=None):
    """Replay a saved event (an entry of ``ConfigResult.events`` or of ``events.json``) in its evaluation batch.

    A record whose intruder is a plug-in spec (``package.module:attribute``) is not imported from the record:
    pass ``intruder_policy`` (e.g. ``resolve_intruder(spec)`` of a spec you trust); see
    :mod:`stp_env.evaluation.events`."""
    _, params, vehicle_policy, intruder_policy = prepare_event(event, store=store, progress=progress,
                                                               intruder_policy=intruder_policy)
    return replay(event["seed"], event["index"], params, vehicle_policy, intruder_policy, event["n_steps"],
                  batch_size=event["batch_size"], record=event["recorded"],
                  airborne_only=event.get("airborne_only", False), episodes=event.get("episodes"),
                  devices=event.get("devices"))


def same_outcome(a: dict, b: dict, *, atol: float = 1e-3) -> bool:
    """Whether two final states (numpy dicts) are the same outcome: equal statuses, modes, forced set and flags,
    and times and states within ``atol``."""
    exact = ("status", "mode", "complied", "assumption_ok", "collided_with_intruder", "guarantee_violation",
             "intruder_status", "step_count")
    if any(not np.array_equal(a[k], b[k]) for k in exact):
        return False
    if not np.array_equal(np.isfinite(a["avoid_start"]), np.isfinite(b["avoid_start"])):
        return False
    for k in ("avoid_start", "arrival_time", "collision_time", "t_appear", "x", "intruder_x", "min_separation"):
        x, y = np.asarray(a[k], float), np.asarray(b[k], float)
        if not np.allclose(np.where(np.isfinite(x), x, 0.0), np.where(np.isfinite(y), y, 0.0), atol=atol, rtol=0):
            return False
    return True


"""Reading saved bad episodes back (``events.json`` / ``events.npz`` written by
:func:`stp_env.evaluation.report.write_events`), as untrusted data.

An events file is meant to be shared, so it is data and never a way to run code: a record's intruder must be a
registered scripted intruder (:data:`stp_env.policies.INTRUDERS`) or a learned one (``learned:NAME_OR_PATH``, a
shipped intruder or an ``.npz`` exported by :func:`stp_env.policies.learned.export_mlp`, read with
``allow_pickle=False``). A plug-in spec ``package.module:attribute`` is code: it is never imported because a file
names it. Replaying such a record needs the policy from the caller (``replay_event(..., intruder_policy=...)``, or
``stp-env render --events FILE --intruder SPEC`` with the same spec typed on the command line); otherwise it is
refused before any work is done.

Every record is checked (types and ranges of what a replay uses) when the file is loaded, and every problem is
a one-line ``ValueError`` naming the file (and the record) and what is wrong.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from stp_env.arguments import INT32_MAX, MAX_SPEED, check_int, check_real
from stp_env.evaluation.config import LEARNED_PREFIX, Configuration
from stp_env.loaders import read_json, read_npz
from stp_env.policies import INTRUDERS
from stp_env.policies.intruders import is_plugin
from stp_env.resources import check_count, cpu_limit_reason, max_cpu_devices
from stp_env.seeds import check_seed

MAX_REPLAY_BATCH = 16384
"""The largest evaluation batch a saved event replays in (the whole batch runs again, with its trajectories:
about 45 MB per 250 town episodes)."""

_CONFIG_FIELDS = {f.name for f in dataclasses.fields(Configuration)}
_REPLAY_FIELDS = ("config", "seed", "index", "n_steps", "plan_samples", "batch_size", "recorded")


def is_plugin_spec(spec: str) -> bool:
    """Whether an intruder spec names code to import (``package.module:attribute[=ARG]``)."""
    return is_plugin(spec)


def _int(value, name: str, where: str, lo: int, hi: int = INT32_MAX) -> int:
    try:
        return check_int(value, name, lo, hi)
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None


def check_event(record, where: str = "event") -> dict:
    """``record`` (an ``events.json`` entry) checked for what a replay uses: a ``config`` of
    :class:`Configuration` fields whose intruder is registered, learned or a plug-in spec (see the module
    docstring), a seed, an index, the step count, plan length and batch size, the ``recorded`` flag, the
    optional ``airborne_only`` flag (absent in records written before it existed: the whole fleet) and the optional
    run size ``episodes`` (which finds the episode's batch; absent in older records: its consecutive indices) and the
    optional ``devices`` its batch was shared among (absent in older records: one; at most
    :func:`stp_env.resources.max_cpu_devices`, as the replay splits this machine's CPU into as many). A ``wind`` in
    the config is at most :data:`stp_env.arguments.MAX_SPEED`.
    Returns it unchanged; ``ValueError`` starting with ``where`` otherwise."""
    if not isinstance(record, dict):
        raise ValueError(f"{where}: a record must be a JSON object; got a {type(record).__name__}.")
    missing = [k for k in _REPLAY_FIELDS if k not in record]
    if missing:
        raise ValueError(f"{where}: missing field(s) {missing}.")
    config = record["config"]
    if not isinstance(config, dict):
        raise ValueError(f"{where}: 'config' must be a JSON object; got a {type(config).__name__}.")
    unknown = sorted(set(config) - _CONFIG_FIELDS)
    if unknown:
        raise ValueError(f"{where}: unknown config field(s) {unknown}; allowed: {sorted(_CONFIG_FIELDS)}.")
    intruder = config.get("intruder", Configuration.intruder)
    if not isinstance(intruder, str) or not (intruder in INTRUDERS or intruder.startswith(LEARNED_PREFIX)
                                             or is_plugin_spec(intruder)):
        raise ValueError(f"{where}: unknown intruder {intruder!r}; a saved event names a registered intruder "
                         f"({', '.join(INTRUDERS)}) or 'learned:NAME_OR_PATH'.")
    if config.get("wind") is not None:  # the simulator's range (Configuration checks only that it is finite)
        try:
            check_real(config["wind"], "wind [m/s]", 0.0, MAX_SPEED)
        except ValueError as err:
            raise ValueError(f"{where}: bad config: {err}") from None
    try:
        Configuration(**config)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: bad config: {err}") from None
    try:
        check_seed(record["seed"])
    except ValueError as err:
        raise ValueError(f"{where}: {err}") from None
    _int(record["index"], "index", where, 0)
    _int(record["n_steps"], "n_steps", where, 1)
    _int(record["plan_samples"], "plan_samples", where, 1)
    _int(record["batch_size"], "batch_size", where, 1, MAX_REPLAY_BATCH)
    if "episodes" in record:  # absent in records written before the batches were ordered by appearance time
        _int(record["episodes"], "episodes", where, 1)
        if record["index"] >= record["episodes"]:
            raise ValueError(f"{where}: index {record['index']} is not an episode of a run of {record['episodes']}.")
    if "devices" in record:  # absent in records written before batches were shared among devices: one
        _int(record["devices"], "devices", where, 1)
        try:  # the replay splits this machine's CPU into as many devices: within what it can start
            check_count("devices", record["devices"], limit=max_cpu_devices(), why=cpu_limit_reason())
        except ValueError as err:
            raise ValueError(f"{where}: {err}") from None
    if not isinstance(record["recorded"], bool):
        raise ValueError(f"{where}: recorded must be true or false; got {record['recorded']!r}.")
    if not isinstance(record.get("airborne_only", False), bool):
        raise ValueError(f"{where}: airborne_only must be true or false; got {record['airborne_only']!r}.")
    if "npz_prefix" in record and not isinstance(record["npz_prefix"], str):
        raise ValueError(f"{where}: npz_prefix must be a string; got {record['npz_prefix']!r}.")
    return record


def load_events(path) -> list[dict]:
    """The records of an ``events.json``, each checked by :func:`check_event`; a one-line ``ValueError`` naming
    the file for a missing, unreadable or malformed file (the loader contract, :mod:`stp_env.loaders`: a regular
    file of at most 256 MiB, JSON nested at most 64 levels)."""
    path = Path(path)
    records = read_json(path, "events")
    if not isinstance(records, list):
        raise ValueError(f"{path}: not an events file (a JSON {type(records).__name__}, expected a list of "
                         "records).")
    return [check_event(r, f"{path}, record {n}") for n, r in enumerate(records)]


def event_configuration(record, *, intruder_policy=None, where: str = "event"):
    """``(configuration, vehicle policy, intruder policy)`` of a checked record. A plug-in intruder spec is
    never imported: it needs ``intruder_policy`` from the caller (``ValueError`` otherwise, before any work)."""
    from stp_env.evaluation.config import resolve_intruder, resolve_vehicle_policy

    record = check_event(record, where)
    config = Configuration(**record["config"])
    if intruder_policy is None:
        if is_plugin_spec(config.intruder):
            raise ValueError(f"{where}: the intruder {config.intruder!r} is a plug-in spec (code to import); a "
                             "saved event never imports code it names. Pass the policy yourself "
                             "(replay_event(..., intruder_policy=...), or `stp-env render --events FILE "
                             f"--intruder '{config.intruder}'` if you trust that module).")
        intruder_policy = resolve_intruder(config.intruder, allow_plugins=False)
    return config, resolve_vehicle_policy(config.vehicle_policy), intruder_policy


def check_replay_sizes(record, params, where: str = "event") -> None:
    """The record's step count and plan length against the configuration's own (at most twice as many: a run's
    configurations share the longest of them); ``ValueError`` otherwise."""
    from stp_env.sim import steps_for

    own_steps, own_samples = steps_for(params), int(params.vehicles.nominal_states.shape[1])
    if record["n_steps"] > 2 * own_steps:
        raise ValueError(f"{where}: n_steps {record['n_steps']} is more than twice this configuration's episode "
                         f"({own_steps} steps).")
    if not own_samples <= record["plan_samples"] <= 2 * own_samples:
        raise ValueError(f"{where}: plan_samples {record['plan_samples']} does not fit this configuration's plan "
                         f"({own_samples} samples).")


def load_event_state(npz_path, record: dict) -> dict:
    """The saved final state of one ``events.json`` record (numeric arrays only, read under the loader contract:
    :func:`stp_env.loaders.read_npz`)."""
    prefix = record.get("npz_prefix") if isinstance(record, dict) else None
    if not isinstance(prefix, str):
        raise ValueError(f"{npz_path}: the record has no npz_prefix string.")
    arrays = read_npz(npz_path, "event-states")
    state = {k[len(prefix):]: v for k, v in arrays.items() if k.startswith(prefix)}
    if not state:
        raise ValueError(f"{npz_path}: no arrays with prefix {prefix!r}.")
    bad = sorted(k for k, v in state.items() if v.dtype.kind not in "biuf")
    if bad:
        raise ValueError(f"{npz_path}: non-numeric arrays {bad}.")
    return state

"""Which tables a run reads beyond the scenario's own, decided in one place for the environment, the evaluator and
the falsifier: the policies' records say what they read (:class:`stp_env.policies.record` ``needs_buffer``;
an intruder's by :func:`stp_env.policies.intruders.capabilities`, plug-ins included), and
:func:`with_required_tables` loads it into the run's ``EnvParams``.

Today one such table exists: the relative buffer region ``V^B`` of the buffer game (the ``worst`` vehicles, the
``optimal-max-k`` intruder), computed for the run's k̄ (:func:`stp_env.assembly.load_buffer`).
"""

from __future__ import annotations

from stp_env import assembly


def needs_buffer(vehicle_policy=None, intruder=None, observation: str | None = None) -> bool:
    """Whether the vehicles' policy (a name of :data:`stp_env.policies.VEHICLE_POLICIES`, a resolved policy or
    ``None``), the intruder (a spec, a record, a policy or ``None``: the agent) or a learner's ``observation``
    (:data:`stp_env.policies.observations.NEEDS_BUFFER`) plays the buffer game (reads ``V^B``)."""
    from stp_env.policies import BUFFER_GAME_VEHICLE_POLICIES, VEHICLE_POLICIES
    from stp_env.policies.intruders import capabilities
    from stp_env.policies.observations import NEEDS_BUFFER

    if observation is not None and observation in NEEDS_BUFFER:
        return True

    if isinstance(vehicle_policy, str):
        vehicles_read = vehicle_policy in BUFFER_GAME_VEHICLE_POLICIES
    else:
        vehicles_read = vehicle_policy is not None and vehicle_policy in [VEHICLE_POLICIES[name] for name in
                                                                          BUFFER_GAME_VEHICLE_POLICIES]
    return vehicles_read or (intruder is not None and capabilities(intruder).needs_buffer)


def with_required_tables(params, scenario, *, vehicle_policy=None, intruder=None, observation: str | None = None,
                         kbar: int | None = None, store=None, progress: bool | None = None):
    """``params`` with every table the policies read that it lacks (the buffer table of ``kbar``, the scenario's
    when ``None``, for a buffer-game policy: :func:`needs_buffer`); ``params`` itself when nothing is missing."""
    if needs_buffer(vehicle_policy, intruder, observation) and params.tables.buffer_values is None:
        params = assembly.with_buffer(params, assembly.load_buffer(scenario, kbar, store=store, progress=progress))
    return params

"""The names and defaults the ``survivability`` subcommand lists, as plain tables (its ``--help`` imports no JAX):
the policies, traffic models, ``N_f`` counts, reveal models and scenario levels of the study
(:mod:`stp_env.survivability.config`, :mod:`stp_env.survivability.study` use them from here)."""

POLICIES = ("R", "Nf", "S", "AvgR")
"""The planning policies of the survivability paper, Section IV-B: ``pi_R`` (segment robustness), ``pi_Nf``
(number of feasible trajectories), ``pi_S`` (survivability) and ``pi_Avg(R)`` (average trajectory robustness)."""

TRAFFIC_MODELS = ("paper", "local")
"""Intruder traffic models (:mod:`stp_env.survivability.traffic`): ``paper`` (the default), the survivability
paper's Section III-B model (control points anywhere in the area, control times in the mission window
``(t_0, t_fu)``, a share of hovering degree-1 intruders, realisations using the whole tube), and ``local``, this
project's earlier short hops around a uniform entry point with entry times spread over the endurance (the default
of studies before the paper's model was; kept as a named variant)."""

NF_COUNTS = ("goal", "landing")
"""What ``pi_Nf``'s ``N_f`` counts (:mod:`stp_env.survivability.dp`): ``goal`` (the default), the paper's ``c.N_f``
of Algorithm 1: the trajectories to the current terminal set ``Omega`` summed over every state of the successor's
*cell*, or ``landing``, the project's earlier count of the trajectories from the successor *state* to any landing
site (kept as a named variant)."""

REVEAL_MODELS = ("segment", "step", "radius")
"""When an intruder whose actual path the ownship does not know (an unknown one, or a partially known one's actual
path) becomes known (:mod:`stp_env.survivability.mission`; the survivability paper, Section III-B: "the ownship is
unaware of the intruder's existence until the ownship encounters a conflict with the intruder"): ``segment``, when
its actual path blocks the segment chosen at a decision point (a look-ahead of one decision window; the default
until the study is re-run); ``step``, when it blocks a cell the ownship occupies in the next time step (a conflict
one step ahead, the sentence read literally); ``radius``, also when it comes within ``sense_km`` of the ownship.
In every model a revealed intruder's whole actual path becomes known."""

LEVELS = (50, 100, 150, 200, 250, 300)
"""The intruder counts of the study's scenarios (each level of ``N_p`` and ``N_u``)."""

BATCH_GROUPS = 0
"""The default of :func:`stp_env.survivability.study.run_study`'s ``batch_groups``: one mission at a time (the
batched path, :mod:`stp_env.survivability.batch`, flies the same missions in one compiled program per piece)."""

"""Compromised vehicles and co-observation: reachability-secured schedules (the co-observation paper of Yang and
Tron), on this project's solver, scenarios and simulator. ``docs/coobservation.md`` is the guide.

Planning (the paper's Sections II-III):

* :mod:`~stp_env.coobservation.ellipse`: reachability ellipses (Defs. 2-4), the Householder frame (Props. 1-2),
  the point, plane, segment and polygon constraints with their projections (Sections II-F to II-J).
* :mod:`~stp_env.coobservation.admm`: the generalised ADMM (eqs. 8-11) and its constraints (eqs. 12-58).
* :mod:`~stp_env.coobservation.exploration`: the map-exploration cost of Example 1 (Kalman-filter variances).
* :mod:`~stp_env.coobservation.schedule`: observations and the reachability segments between them.
* :mod:`~stp_env.coobservation.checkpoints`, :mod:`~stp_env.coobservation.rrt`,
  :mod:`~stp_env.coobservation.flows`: Algorithms 1-2, RRT*, and the multi-flow problem (60) on HiGHS.
* :mod:`~stp_env.coobservation.paper`: the paper's two experiments as typed tasks.

The threat in the UAV simulator (by composition around :mod:`stp_env.sim`):

* :mod:`~stp_env.coobservation.uav`: the formation scenario, its plan and schedules (typed config).
* :mod:`~stp_env.coobservation.threat`: the compromised-vehicle step, co-observation events, detections,
  forbidden-region entries, batched rollouts.
* :mod:`~stp_env.coobservation.attackers`, :mod:`~stp_env.coobservation.learned`: scripted and learned attackers.
* :mod:`~stp_env.coobservation.env`: the PettingZoo environment.
* :mod:`~stp_env.coobservation.exact`: exact reachability regions of a Dubins vehicle in wind (HJ solver).
* :mod:`~stp_env.coobservation.evaluation`, :mod:`~stp_env.coobservation.cli`: ``stp-env coobservation``.
"""

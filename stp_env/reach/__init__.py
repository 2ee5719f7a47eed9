"""The papers' reachability sets around a single vehicle, each computed by the generic solver in
:mod:`stp_env.hj` and cached as a versioned artifact (:mod:`stp_env.artifacts`). One module per concept:

* :mod:`~stp_env.reach.avoid`: avoid region ``V^A``, avoidance and pursuit controls, detection range ``d^A``;
* :mod:`~stp_env.reach.tracking`: robust-trajectory-tracking error bound and tracker;
* :mod:`~stp_env.reach.buffer`: ``t_BRD``, relative buffer region ``V^B``, separation/buffer disk radii;
* :mod:`~stp_env.reach.obstacles`: induced obstacles while avoiding (lag profiles) and static augmentation ``V^S``;
* :mod:`~stp_env.reach.defaults`: build all artifacts of a scenario; :mod:`~stp_env.reach.plots`: figures.
"""

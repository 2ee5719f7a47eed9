"""The package's single-agent views, registered with Gymnasium by entry point (importing :mod:`stp_env` registers
them; nothing heavy is imported until :func:`gymnasium.make` builds one):

* ``"stp_env/Intruder-v0"``: :class:`stp_env.rl.gym_env.IntruderEnv` (the intruder against the vehicles of a
  scenario, ``"town"`` by default; keyword arguments as the class's, e.g. ``scenario="tiny-intruder"``);
* ``"stp_env/Survivability-v0"``: :class:`stp_env.survivability.gym_env.SurvivabilityEnv` (the survivability
  paper's mission as motion primitives, with action masks).

``gymnasium.make("stp_env:stp_env/Intruder-v0")`` imports the package first (Gymnasium's ``module:id`` form).
The multi-agent environment is PettingZoo's: :func:`stp_env.parallel_env`.
"""

from __future__ import annotations

ENVIRONMENTS = {
    "stp_env/Intruder-v0": "stp_env.rl.gym_env:IntruderEnv",
    "stp_env/Survivability-v0": "stp_env.survivability.gym_env:SurvivabilityEnv",
}


def register_envs() -> None:
    """Register :data:`ENVIRONMENTS` with Gymnasium (again: a no-op for ids already registered)."""
    import gymnasium

    for env_id, entry_point in ENVIRONMENTS.items():
        if env_id not in gymnasium.registry:
            gymnasium.register(id=env_id, entry_point=entry_point)

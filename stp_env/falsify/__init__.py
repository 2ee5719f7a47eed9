"""Falsification: adversarial search for the inputs that break the project's claimed bounds, through the
simulator itself.

One small module per attack, each a jittable objective on the unit box (larger is worse for the system):

* :mod:`~stp_env.falsify.tracking`: reference controls in ``U^p`` and wind against the tracker (the bound
  ``r_e`` of SPP eqs. 24-26);
* :mod:`~stp_env.falsify.avoidance`: intruder starts outside ``V^A``, intruder controls and winds against ``u^A``
  (the danger zone ``R_c``, intruder paper eqs. 13-18);
* :mod:`~stp_env.falsify.kbar`: intruder appearance, spawn and trajectory against a planned scenario (the bound
  k̄ on ``|N^RP|``, eq. 39).

:mod:`~stp_env.falsify.targets` names them (a new target is a module whose attack class it registers);
:mod:`~stp_env.falsify.search` holds the searchers (cross-entropy with restarts, Adam through the differentiable
core), :mod:`~stp_env.falsify.counterexample` the replayable record of the worst attack found. ``stp-env
falsify`` runs them from the command line::

    spec = AttackSpec(target="tracking", scenario="town", kbar=2)
    outcome = run(spec, SearchConfig(budget=10_000), seed=0)
    outcome.worst, outcome.margin    # the worst value found and its margin to the bound (negative: broken)
"""

import importlib

_EXPORTS = {
    "AttackSpec": "counterexample", "Outcome": "counterexample", "build_attack": "counterexample",
    "load": "counterexample", "replay": "counterexample", "run": "counterexample", "save": "counterexample",
    "SearchConfig": "search", "SearchResult": "search", "cross_entropy": "search", "gradient_ascent": "search",
    "search": "search",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    # Lazy: the command line's parser imports this package without paying for JAX.
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"stp_env.falsify.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'stp_env.falsify' has no attribute {name!r}")

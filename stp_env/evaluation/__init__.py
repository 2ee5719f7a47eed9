"""Monte Carlo evaluation of the k̄ bound on the batched core (``stp-env evaluate``).

* :mod:`~stp_env.evaluation.config`: :class:`Configuration` (scenario, k̄, intruder, wind, spawn mode, vehicle
  policy) and :func:`resolve_intruder` (scripted names, or ``module:policy`` for learned intruders).
* :mod:`~stp_env.evaluation.runner`: :func:`evaluate` (batches of episodes, one compile), :func:`summarize`;
  :mod:`~stp_env.evaluation.replays`: :func:`replay` / :func:`replay_event` (an episode from its seed and index).
* :mod:`~stp_env.evaluation.events`: reading saved events back as untrusted data (:func:`load_events`; a plug-in
  intruder named in a file is never imported).
* :mod:`~stp_env.evaluation.stats`: exact Clopper-Pearson bounds.
* :mod:`~stp_env.evaluation.report`, :mod:`~stp_env.evaluation.plots`, :mod:`~stp_env.evaluation.render`:
  JSON / CSV / markdown, figures, GIFs.
* :mod:`~stp_env.evaluation.pipeline`: :func:`run`, everything the ``evaluate`` subcommand writes.
"""

from stp_env.evaluation.config import Configuration, resolve_intruder, resolve_vehicle_policy
from stp_env.evaluation.events import load_events
from stp_env.evaluation.pipeline import run
from stp_env.evaluation.replays import replay, replay_event, same_outcome
from stp_env.evaluation.runner import (
    ConfigResult,
    build_params,
    evaluate,
    pad_plan,
    run_batch,
    summarize,
)
from stp_env.evaluation.stats import (
    beta_ppf,
    betainc,
    clopper_pearson_interval,
    clopper_pearson_lower,
    clopper_pearson_upper,
)

__all__ = [
    "ConfigResult", "Configuration", "beta_ppf", "betainc", "build_params", "clopper_pearson_interval",
    "clopper_pearson_lower", "clopper_pearson_upper", "evaluate", "load_events", "pad_plan", "replay", "replay_event",
    "resolve_intruder", "resolve_vehicle_policy", "run", "run_batch", "same_outcome", "summarize",
]

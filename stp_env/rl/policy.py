"""The learned intruder's reader, :mod:`stp_env.baselines.learned` (a policy of the core like the scripted ones),
under the name it had: ``from stp_env.rl.policy import load_intruder`` keeps working."""

from stp_env.baselines.learned import (
    ACTIVATIONS,
    FORMAT_VERSION,
    MAX_LAYERS,
    MLPIntruder,
    export_mlp,
    load_intruder,
    load_mlp,
    mlp_intruder,
    shipped_intruders,
)

__all__ = ["ACTIVATIONS", "FORMAT_VERSION", "MAX_LAYERS", "MLPIntruder", "export_mlp", "load_intruder", "load_mlp",
           "mlp_intruder", "shipped_intruders"]

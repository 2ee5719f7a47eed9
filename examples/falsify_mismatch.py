"""The falsifier's tracking attack (a legal reference and the wind against the tracker, bound r_e) run on the pymunk
rigid-body plant: the environment of the JAX attack with its vehicle model replaced, searched with the
cross-entropy method (the pymunk step has no gradient). Prints one JSON line per backend.

    nice -n 10 python examples/falsify_mismatch.py --attacks 64 --backend jax pymunk-dynamic:speed_time_constant=0.3
"""

from __future__ import annotations

import argparse
import json

from stp_env.falsify.counterexample import AttackSpec, environment, run
from stp_env.falsify.search import SearchConfig
from stp_env.sim.backends import vehicle_model


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--scenario", default="town")
    p.add_argument("--backend", nargs="+", default=["jax", "pymunk-dynamic"])
    p.add_argument("--attacks", type=int, default=64)
    p.add_argument("--horizon", type=float, default=10.0)
    p.add_argument("--seed", type=int, default=0)
    args = p.parse_args(argv)
    spec = AttackSpec(target="tracking", scenario=args.scenario, options=(("horizon", args.horizon),))
    base = environment(spec, progress=False)
    config = SearchConfig(method="cem", budget=args.attacks, population=max(4, args.attacks // 4), restarts=2,
                          batch=max(4, args.attacks // 4))
    for backend in args.backend:
        params = base.replace(vehicles=dict(model=vehicle_model(backend)))
        outcome = run(spec, config, args.seed, params=params, progress=False)
        summary = outcome.summary()
        print(json.dumps({"backend": backend, "worst_tracking_error_m": summary.get("worst"),
                          "bound_r_e_m": summary.get("bound"), "margin_m": summary.get("margin"),
                          "attacks": outcome.evaluations, "seconds": round(outcome.seconds, 1)}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

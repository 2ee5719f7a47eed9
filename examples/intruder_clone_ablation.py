"""How close a clone of a scripted intruder comes to its teacher: clone it (with DAgger rounds) on the training
environment, then measure the clone's agreement with the teacher on held-out states and both intruders' held-out
episodes side by side (one JSON line each).

    python examples/intruder_clone_ablation.py --observation game      # docs/learned_intruders.md, "What mattered"
    python examples/intruder_clone_ablation.py --observation core

Defaults: the crossing at k̄ = 2, worst vehicles, boundary spawns, teacher ``optimal-max-k``, 256 envs, 200 steps
per round, 2 DAgger rounds, 30 epochs, a 64 x 64 tanh MLP; agreement on 100 steps of 256 envs from seed 777;
2,048 episodes from the training evaluations' seeds (``1,000,000 + i``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time

from stp_env.policies import INTRUDERS
from stp_env.rl.imitation import agreement, clone_intruder, intruder_demonstrations, scripted_predict
from stp_env.rl.ppo import make_model
from stp_env.rl.train import TrainConfig, build_params, evaluate_on_vec_env, summarize
from stp_env.rl.vec_env import IntruderVecEnv


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--observation", choices=["core", "game"], default="game")
    ap.add_argument("--teacher", default="optimal-max-k", choices=sorted(INTRUDERS))
    ap.add_argument("--scenario", default="crossing")
    ap.add_argument("--kbar", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--episodes", type=int, default=2048)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    config = TrainConfig(scenario=args.scenario, kbar=args.kbar, vehicle_policy="worst", spawn_mode="boundary",
                         observation=args.observation, n_envs=256, n_steps=64, batch_size=4096)
    params = build_params(config, progress=True)
    kw = {"params": params, "horizon": "intruder", "vehicle_policy": "worst", "observation": args.observation}
    model = make_model(config, IntruderVecEnv(256, **kw))
    teacher = INTRUDERS[args.teacher]
    record = clone_intruder(model, IntruderVecEnv(256, **kw), teacher, n_steps=200, dagger_rounds=args.rounds,
                            epochs=30, gamma=config.gamma, seed=0)
    print(json.dumps({"clone": record}), flush=True)
    venv = IntruderVecEnv(256, **kw)
    obs, act, _ = intruder_demonstrations(venv, teacher, 100, config.gamma, seed=777, progress=False)

    def clone(o):
        return model.predict(o, deterministic=True)[0]

    print(json.dumps({"agreement_within_0.1": agreement(clone, obs, act, 0.1),
                      "agreement_within_0.05": agreement(clone, obs, act, 0.05)}), flush=True)

    for name, predict in (("clone", clone), (args.teacher, scripted_predict(venv, teacher))):
        row = summarize(evaluate_on_vec_env(predict, venv, args.episodes, config.eval_seed), args.kbar)
        print(json.dumps({"intruder": name, "observation": args.observation, **row}), flush=True)
    print(json.dumps({"seconds": round(time.perf_counter() - t0, 1)}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

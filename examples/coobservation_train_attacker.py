"""Train the learned attacker (SB3 PPO) of the co-observation study and export it (numpy weights, no pickle).

The attacker controls a compromised vehicle of the UAV formation (:mod:`stp_env.coobservation.uav`) from a random
compromise time; its reward is entering a forbidden zone without missing an observation
(:mod:`stp_env.coobservation.learned`). It trains against the unsecured schedule (every 90 s), where such attacks
exist, or with ``--schedule secured`` against the ellipse-secured one (an attacker that must try where the ellipses
say it cannot win), and is evaluated afterwards on every schedule by
``stp-env coobservation --attackers learned:<npz>``.

``python examples/coobservation_train_attacker.py --out runs/attacker`` trains the shipped attacker's recipe: 500 k
decisions of 1 s, PPO started from a behaviour-cloned copy of the ``opportunistic`` scripted attacker
(``--teacher none``: from scratch), exploration noise std ``e^-2`` and learning rate ``1e-4`` so that PPO refines
the clone instead of drowning it in noise (8 minutes on 2 cores); ``--ship`` copies the result to
``stp_env/data/coobservation/attacker.npz``.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def main(argv=None):
    from stp_env.coobservation import learned, threat
    from stp_env.coobservation.env import UNSECURED_PERIOD
    from stp_env.coobservation.uav import FormationScenario

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--timesteps", type=int, default=500_000, help="attacker decisions (1 s each)")
    ap.add_argument("--n-envs", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--teacher", default="opportunistic",
                    help="a scripted attacker to imitate before PPO, or 'none' (PPO from scratch)")
    ap.add_argument("--learning-rate", type=float, default=1e-4)
    ap.add_argument("--log-std-init", type=float, default=-2.0, help="log of the initial exploration noise std")
    ap.add_argument("--schedule", choices=["unsecured", "secured"], default="unsecured",
                    help="the schedule it trains against (secured: the ellipse-secured one, where no attack the "
                         "ellipses allow exists; start from a teacher that tries, e.g. --teacher reckless)")
    ap.add_argument("--margin-reward", type=float, default=0.0,
                    help="reward an entry by its time margin (stp_env.coobservation.learned; > 1 makes a detected "
                         "entry worth more than no attempt: an attacker that must try, against --schedule secured)")
    ap.add_argument("--out", default="runs/attacker")
    ap.add_argument("--ship", action="store_true", help="copy the exported attacker into the package data")
    args = ap.parse_args(argv)
    from stp_env.coobservation.cli import schedules_for

    sc = FormationScenario()
    params = sc.params()
    times = schedules_for(sc, [args.schedule], UNSECURED_PERIOD)[args.schedule]
    tp = threat.threat_params(sc.schedule(times), sc.forbidden, sc.observation_radius)
    teacher = None if args.teacher == "none" else args.teacher
    cfg = learned.AttackerTrainConfig(total_timesteps=args.timesteps, n_envs=args.n_envs, seed=args.seed,
                                      teacher=teacher, learning_rate=args.learning_rate,
                                      log_std_init=args.log_std_init, margin_reward=args.margin_reward)
    start = time.time()
    path = learned.train(params, tp, (0.0, sc.duration - 10.0), cfg, args.out)
    print(f"wrote {path} after {time.time() - start:.0f} s")
    if args.ship:
        dest = ROOT / "stp_env" / "data" / "coobservation" / "attacker.npz"
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(path, dest)
        print(f"shipped to {dest}")


if __name__ == "__main__":
    main()

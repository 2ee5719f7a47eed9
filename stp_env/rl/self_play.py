"""Self-play: the intruder and the vehicles trained in turn with the JAX PPO, the vehicles inside the HJ filters.

Round ``r`` (``1 .. rounds``) of :func:`self_play`:

1. **Intruder**: :func:`stp_env.rl.jax_train.train_jax` against the vehicles of round ``r - 1`` (round 1: ``u*``,
   the papers' ``switching`` controller), every vehicle flying that policy inside both HJ filters (eq. 38 while
   forced, the tube-keeping filter on its plan; :func:`stp_env.policies.hj_filter`), the intruder appearing on a
   vehicle's avoid boundary and seeing the game observation; it starts from round ``r - 1``'s intruder (round 1:
   a fresh network, or ``intruder_start``'s actor).
2. **Vehicles**: PPO on the ego vehicle's gymnax view (:class:`stp_env.rl.gymnax_env.VehicleGymnaxEnv`: the
   vehicle forced first flies the policy after the intruder leaves; the papers leave that flight to replanning, so
   it is where a learned vehicle policy may differ from ``u*`` without losing a guarantee) against round ``r``'s
   intruder, from round ``r - 1``'s vehicle policy (round 1: a fresh network). The trained network flies every
   vehicle of the fleet (``learned:PATH``, parameter sharing).
3. **Evaluation**: ``stp-env evaluate``'s library on ``eval_episodes`` episodes (seed ``eval_seed``, the same
   episodes every round) of the pair (intruder ``r``, vehicles ``r``), of each learned side against the other's
   script, and of the scripted pair (``optimal-max-k`` against ``u*``) once: episodes reaching k̄, above k̄,
   collisions, guarantee violations, on-time arrivals of the vehicles due in the window; and the vehicle forced
   first, after its avoidance, flying the learned policy and ``u*`` on the same :data:`FORCED_EPISODES` episodes
   against the round's intruder (:func:`evaluate_forced`): on time, collided.

Everything lands in ``out_dir``: ``round-R/intruder/`` and ``round-R/vehicle/`` (each a training run's folder,
``intruder.npz`` / ``vehicle.npz``), ``rounds.jsonl`` (one line per evaluated pair) and ``self_play.md`` (the
table). A killed run started again with the same options resumes each training from its checkpoint (a finished
one is not trained again; its last evaluation is rerun) and evaluates the pairs again.

``python -m stp_env.rl.self_play --help`` runs it from the shell.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import jax
import numpy as np

from stp_env.arguments import check_int, check_real
from stp_env.files import atomic_open, write_text
from stp_env.rl import jax_ppo
from stp_env.rl.jax_train import PPORun, held_out_keys, make_evaluator, run_ppo

EGO_STATS = ("empty", "arrived", "on_time", "ego_collided", "collisions", "guarantee_violations")


@dataclasses.dataclass(frozen=True, kw_only=True)
class SelfPlayConfig:
    """The rounds and each side's training (unknown fields are a ``TypeError``; bad values a ``ValueError``).

    Attributes:
        scenario, kbar: the scenario and its bound (its plan is planned for it).
        rounds: how many intruder-then-vehicles rounds.
        intruder_steps, vehicle_steps: environment steps of each side's training per round.
        n_envs, n_steps, batch_size: the intruder's PPO rollout and minibatch; vehicle_n_envs, vehicle_n_steps,
            vehicle_batch_size: the vehicles'.
        kbar_reward: the intruder's reward for the k̄-th vehicle (``TrainConfig.kbar_reward``).
        vehicle_log_std_init: the vehicle policy's initial log standard deviation; energy, late_limit: the ego
            env's energy weight and truncation after the STA [s].
        eval_episodes, eval_seed: the evaluated episodes (the same each round).
        intruder_start: an intruder ``.npz`` whose actor starts round 1 (``None``: a fresh network).
        seed: the training runs' seed; out_dir: where everything goes.
    """

    scenario: str = "crossing"
    kbar: int = 2
    rounds: int = 3
    intruder_steps: int = 2_097_152
    vehicle_steps: int = 524_288
    n_envs: int = 256
    n_steps: int = 64
    batch_size: int = 4096
    vehicle_n_envs: int = 128
    vehicle_n_steps: int = 64
    vehicle_batch_size: int = 2048
    kbar_reward: float = 5.0
    vehicle_log_std_init: float = -0.5
    energy: float = 0.002
    late_limit: float = 60.0
    eval_episodes: int = 1000
    eval_seed: int = 20240601
    intruder_start: str | None = None
    seed: int = 0
    out_dir: str = "runs/self-play"

    def __post_init__(self) -> None:
        for name in ("kbar", "rounds", "intruder_steps", "vehicle_steps", "n_envs", "n_steps", "batch_size",
                     "vehicle_n_envs", "vehicle_n_steps", "vehicle_batch_size", "eval_episodes"):
            check_int(getattr(self, name), name, 1, None)
        check_int(self.seed, "seed", 0, None)
        check_int(self.eval_seed, "eval_seed", 0, None)
        for name in ("kbar_reward", "vehicle_log_std_init", "energy", "late_limit"):
            check_real(getattr(self, name), name)
        if self.energy < 0 or self.late_limit < 0:
            raise ValueError("energy and late_limit must be >= 0.")
        for n, m, b in ((self.n_envs, self.n_steps, self.batch_size),
                        (self.vehicle_n_envs, self.vehicle_n_steps, self.vehicle_batch_size)):
            if (n * m) % b:
                raise ValueError(f"n_envs * n_steps ({n * m}) must be a multiple of the batch size ({b}).")
        if self.intruder_start is not None and not Path(self.intruder_start).is_file():
            raise ValueError(f"intruder_start {self.intruder_start!r} is not a file.")

    def intruder_config(self, round_: int, vehicles: str):
        from stp_env.rl.train import TrainConfig

        return TrainConfig(scenario=self.scenario, kbar=self.kbar, vehicle_policy=vehicles, spawn_mode="boundary",
                           observation="game", kbar_reward=self.kbar_reward, trainer="jax",
                           total_timesteps=self.intruder_steps, n_envs=self.n_envs, n_steps=self.n_steps,
                           batch_size=self.batch_size, eval_every=0, eval_episodes=1024,
                           checkpoint_every=self.intruder_steps // 4, seed=self.seed + round_,
                           out_dir=str(Path(self.out_dir) / f"round-{round_}" / "intruder"))


# ------------------------------------------------------------------------------------------------ the vehicles
def _vehicle_settings(config: SelfPlayConfig) -> jax_ppo.PPOSettings:
    return jax_ppo.PPOSettings(n_envs=config.vehicle_n_envs, n_steps=config.vehicle_n_steps,
                               batch_size=config.vehicle_batch_size, n_epochs=10, learning_rate=3e-4, gamma=0.99,
                               gae_lambda=0.95, ent_coef=0.0, clip_range=0.2)


def train_vehicles(config: SelfPlayConfig, round_: int, intruder_path: Path, *, initial_policy=None,
                   show: bool = False):
    """Round ``round_``'s vehicle training against the intruder in ``intruder_path``: ``(policy, history)``, and
    ``round-R/vehicle/vehicle.npz``."""
    from stp_env.policies.learned import write_mlp
    from stp_env.rl.ego import ego_params
    from stp_env.rl.gymnax_env import VehicleGymnaxEnv

    out = Path(config.out_dir) / f"round-{round_}" / "vehicle"
    params, intruder = ego_params(config.scenario, config.kbar, f"learned:{intruder_path}", progress=show)
    env = VehicleGymnaxEnv(params, intruder, energy=config.energy, late_limit=config.late_limit)
    settings = _vehicle_settings(config)
    evaluator = make_evaluator(env, EGO_STATS)
    # an ego episode starts when the intruder appears and ends by the episode's end: at most this many steps
    ego_steps = int(np.ceil(float((params.episode.t_end - params.intruder.appear_window[0]) / params.episode.dt)))
    eval_keys = held_out_keys(1_000_000_000, 128, ego_steps + 1)

    def evaluate(policy):
        r = {k: np.asarray(v) for k, v in evaluator(policy, params, *eval_keys).items()}
        flown = ~r["empty"].astype(bool)
        count = max(int(flown.sum()), 1)
        return {"episodes": int(flown.sum()), "arrived_rate": float(r["arrived"][flown].sum() / count),
                "on_time_rate": float(r["on_time"][flown].sum() / count),
                "ego_collisions": int(r["ego_collided"][flown].sum()),
                "collisions": int(r["collisions"].sum()), "guarantee_violations": int(r["guarantee_violations"].sum()),
                "mean_return": float(r["returns"][flown].mean()) if flown.any() else float("nan")}

    def progress_fields(m, per_episode):
        return {"on_time_rate": per_episode("on_time_sum"), "arrived_rate": per_episode("arrived_sum"),
                "ego_collisions": int(m["ego_collided_sum"]), "collisions": int(m["collisions_sum"]),
                "guarantee_violations": int(m["guarantee_violations_sum"])}

    def export(policy, path, extra):
        layers = [(np.asarray(w), np.asarray(b)) for w, b in jax.device_get(policy["actor"])]
        return write_mlp(layers, path, "tanh", {"role": "vehicle", "scenario": config.scenario, "kbar": config.kbar,
                                                "intruder": str(intruder_path), "energy": config.energy,
                                                "late_limit": config.late_limit, "trainer": "jax",
                                                "observation": "core", "self_play_round": round_, **extra})

    fp = json.dumps({"vehicle": dataclasses.asdict(config), "round": round_, "intruder": str(intruder_path)},
                    sort_keys=True)
    run = PPORun(env=env, env_params=params, settings=settings, net_arch=(64, 64),
                 log_std_init=config.vehicle_log_std_init, seed=config.seed + 1000 + round_, out=out,
                 requested_timesteps=config.vehicle_steps, eval_every=0,
                 checkpoint_every=config.vehicle_steps // 4,
                 fingerprint=fingerprint_of(fp, initial_policy), stat_names=EGO_STATS, evaluate=evaluate,
                 export=export, progress_fields=progress_fields,
                 postfix=lambda row: {"on_time": row["on_time_rate"]}, label=f"self-play round {round_} vehicles",
                 stem="vehicle", initial_policy=initial_policy)
    return run_ppo(run, resume=True, show=show)


def fingerprint_of(text: str, initial_policy) -> str:
    import hashlib

    h = hashlib.sha256(text.encode())
    if initial_policy is not None:
        for a in jax.tree.leaves(jax.device_get(initial_policy)):
            h.update(np.ascontiguousarray(a).tobytes())
    return h.hexdigest()[:20]


# ------------------------------------------------------------------------------------------------ evaluation
def evaluate_pair(config: SelfPlayConfig, intruder: str, vehicles: str, label: str, *, show: bool = False) -> dict:
    """``stp-env evaluate``'s numbers for one pair on the configuration's episodes."""
    from stp_env.evaluation.config import Configuration
    from stp_env.evaluation.runner import evaluate

    cfg = Configuration(scenario=config.scenario, kbar=config.kbar, intruder=intruder, vehicle_policy=vehicles,
                        spawn_mode="boundary")
    [result] = evaluate([cfg], episodes=config.eval_episodes, seed=config.eval_seed, progress=show, showcase=False)
    s = result.summary
    keep = ("episodes", "forced_mean", "kbar_reached", "exceed", "collisions", "guarantee_violations",
            "violation_episodes", "assumption_failures", "tracking_violations", "on_time_rate", "arrived_rate", "due",
            "min_separation_m")
    return {"pair": label, "intruder": intruder, "vehicles": vehicles, **{k: s.get(k) for k in keep}}


FORCED_EPISODES = 256
FORCED_SEED = 2_000_000_000
"""The forced vehicle's held-out episodes (:func:`evaluate_forced`): keys of seeds from here, disjoint from the
vehicle runs' own (their keys come from ``jax.random.PRNGKey(seed + 1000 + round)``)."""


def evaluate_forced(config: SelfPlayConfig, intruder_path: Path, vehicle_path: str, *, show: bool = False) -> dict:
    """The vehicle forced first, after its avoidance (:func:`stp_env.rl.ego.evaluate_ego`), on the same
    :data:`FORCED_EPISODES` episodes against the round's intruder: flying the learned policy and flying ``u*``."""
    from stp_env.policies.learned_vehicles import load_vehicle_mlp
    from stp_env.progress import phase
    from stp_env.rl.ego import ego_params, evaluate_ego

    params, intruder = ego_params(config.scenario, config.kbar, f"learned:{intruder_path}", progress=show)
    out = {}
    with phase(f"the forced vehicle's flight on {FORCED_EPISODES} episodes, learned and u*", show):
        for name, kind, mlp in (("ego", "learned", load_vehicle_mlp(vehicle_path)), ("ego_u_star", "u*", None)):
            r = evaluate_ego(params, intruder, kind, mlp=mlp, episodes=FORCED_EPISODES, seed=FORCED_SEED,
                             energy=config.energy, late_limit=config.late_limit)
            flown = ~np.asarray(r["empty"], bool)
            n = max(int(flown.sum()), 1)
            out.update({f"{name}_episodes": int(flown.sum()),
                        f"{name}_on_time_rate": float(r["on_time"][flown].sum() / n),
                        f"{name}_collisions": int(r["ego_collided"][flown].sum()),
                        f"{name}_guarantee_violations": int(np.sum(r["guarantee_violations"]))})
    return out


def _intruder_start_policy(config: SelfPlayConfig, params):
    """Round 1's intruder: ``intruder_start``'s actor with a fresh critic, or ``None`` (a fresh network)."""
    if config.intruder_start is None:
        return None
    from stp_env.policies.learned import load_mlp
    from stp_env.rl.jax_train import make_env

    mlp = load_mlp(config.intruder_start)
    env = make_env(config.intruder_config(1, "switching"), params)
    obs_size = env.observation_space(params).shape[0]
    fresh = jax_ppo.init_policy(jax.random.PRNGKey(config.seed), obs_size, 2, (64, 64), -1.0)
    actor = [(jax.numpy.asarray(w), jax.numpy.asarray(b)) for w, b in (*mlp.hidden, mlp.action)]
    if [w.shape for w, _ in actor] != [w.shape for w, _ in fresh["actor"]]:
        raise ValueError(f"{config.intruder_start}: its layers are not a 64 x 64 actor on the game observation.")
    return {**fresh, "actor": actor}


def self_play(config: SelfPlayConfig, *, progress: bool | None = None) -> list[dict]:
    """Run the rounds (module docstring); returns the evaluated pairs, also written to ``rounds.jsonl`` and
    ``self_play.md``."""
    from stp_env import progress as progress_lib
    from stp_env.rl.jax_train import train_jax
    from stp_env.rl.train import build_params

    show = progress_lib.enabled(progress)
    out = Path(config.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text(json.dumps(dataclasses.asdict(config), indent=2), out / "config.json")
    rows = [evaluate_pair(config, "optimal-max-k", "switching", "scripted: optimal-max-k vs u*", show=show)]
    intruder_policy = vehicle_policy = None
    vehicles = "switching"
    for r in range(1, config.rounds + 1):
        icfg = config.intruder_config(r, vehicles)
        params = build_params(icfg, progress=show)
        start = intruder_policy if r > 1 else _intruder_start_policy(config, params)
        progress_lib.note(f"self-play round {r}: the intruder against {vehicles}", show)
        intruder_policy, _ = train_jax(icfg, params=params, resume=True, progress=show, initial_policy=start)
        intruder_path = Path(icfg.out_dir) / "intruder.npz"
        progress_lib.note(f"self-play round {r}: the vehicles against {intruder_path}", show)
        vehicle_policy, _ = train_vehicles(config, r, intruder_path, initial_policy=vehicle_policy, show=show)
        vehicles = f"learned:{Path(config.out_dir) / f'round-{r}' / 'vehicle' / 'vehicle.npz'}"
        intruder = f"learned:{intruder_path}"
        rows.append({**evaluate_pair(config, intruder, vehicles, f"round {r}: learned vs learned", show=show),
                     **evaluate_forced(config, intruder_path, vehicles[len("learned:"):], show=show)})
        rows.append(evaluate_pair(config, intruder, "switching", f"round {r}: learned intruder vs u*", show=show))
        rows.append(evaluate_pair(config, "optimal-max-k", vehicles, f"round {r}: optimal-max-k vs learned",
                                  show=show))
        _write(out, rows)
    return rows


def _write(out: Path, rows: list[dict]) -> None:
    with atomic_open(out / "rounds.jsonl", "w") as fh:
        fh.write("".join(json.dumps(r, default=float) + "\n" for r in rows))
    lines = ["| pair | mean \\|N^RP\\| | episodes reaching k̄ | above k̄ | collisions | guarantee violations | "
             "on-time arrivals (due vehicles) | the forced vehicle after avoiding: on time, collided |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        on_time = "n/a" if r["on_time_rate"] is None else f"{100 * r['on_time_rate']:.1f} % of {r['due']}"
        ego = (f"learned {100 * r['ego_on_time_rate']:.1f} %, {r['ego_collisions']}; u* "
               f"{100 * r['ego_u_star_on_time_rate']:.1f} %, {r['ego_u_star_collisions']} (of {r['ego_episodes']})"
               if "ego_on_time_rate" in r else "")
        lines.append(f"| {r['pair']} | {r['forced_mean']:.3f} | {r['kbar_reached']} / {r['episodes']} | "
                     f"{r['exceed']} | {r['collisions']} | {r['guarantee_violations']} | {on_time} | {ego} |")
    write_text("\n".join(lines) + "\n", out / "self_play.md")


def main(argv=None) -> int:
    import argparse

    defaults = SelfPlayConfig()
    parser = argparse.ArgumentParser(prog="python -m stp_env.rl.self_play", description=__doc__.split("\n")[0])
    for field in dataclasses.fields(SelfPlayConfig):
        flag = "--" + field.name.replace("_", "-")
        kind = {int: int, float: float}.get(type(getattr(defaults, field.name)), str)
        parser.add_argument(flag, type=kind, default=getattr(defaults, field.name))
    parser.add_argument("--cpu-devices", type=int, default=None, help="JAX CPU devices (default: one per core)")
    args = vars(parser.parse_args(argv))
    from stp_env.cpu_threads import available_cores, set_cpu_devices

    set_cpu_devices(args.pop("cpu_devices") or available_cores())
    rows = self_play(SelfPlayConfig(**args))
    print(json.dumps({"pairs": len(rows), "table": str(Path(args["out_dir"]) / "self_play.md")}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""Air3D backward reachable tube: ``stp_env.hj`` vs ``hj_reachability`` 0.7.0 side by side.

Same problem, grid, scheme, CFL number and tube formulation for both solvers:

* Air3D (``hj_reachability.systems.Air3d()``: both speeds 5, turn rates 1) = ``stp_env.dynamics.RelativeDubins``
  with fixed speeds and no wind; capture cylinder of radius 5; horizon T (default 2.8);
* grid ``(-6, -10, 0) .. (20, 10, 2 pi)``, ``n^3`` points, heading periodic;
* ``--accuracy``: ``low`` (upwind1 + Euler), ``medium`` (ENO2 + RK2) or ``very_high`` (WENO5 + RK3), the same pairs
  in both packages (their ``high`` presets differ, so ``high`` is not offered);
* tube: ``tube_mode="freeze"`` vs ``hamiltonian_postprocessor=backwards_reachable_tube`` (the same formulation:
  ``dV/ds <- min(dV/ds, 0)`` at every stage);
* Lax-Friedrichs dissipation from the state-dependent partial bounds (``dissipation="local"`` = hj_reachability's
  default ``global_lax_friedrichs`` for control-affine dynamics) and ``dt = cfl / max_x sum_i alpha_i(x) / dx_i``;
* float32.

Each solver runs in its own subprocess (so that its peak RSS is its own), compiles with a two-step warm-up solve
(same jitted executables: the step count and the times are traced values in both packages), then runs the full
horizon once, timed. The parent prints one JSON line per grid size.

``hj_reachability``'s step count is not observable without instrumenting its loop, so it is reproduced exactly:
its while loop in float32 (``dt_k = min(cfl * bound, |t_target - t_k|)``) with its own CFL bound.

Usage::

    python benchmarks/hj_air3d.py --sizes 51 101 --accuracy very_high --horizon 2.8
"""

from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import tempfile
import time

import numpy as np

LO = (-6.0, -10.0, 0.0)
HI = (20.0, 10.0, 2 * math.pi)
RADIUS = 5.0
ACCURACIES = ("low", "medium", "very_high")


def _target(n: int) -> np.ndarray:
    """Signed distance to the capture cylinder on the grid (float64, rounded once to float32), identical for
    both solvers."""
    x = np.linspace(LO[0], HI[0], n)
    y = np.linspace(LO[1], HI[1], n)
    d = np.sqrt(x[:, None] ** 2 + y[None, :] ** 2) - RADIUS
    return np.broadcast_to(d[:, :, None], (n, n, n)).astype(np.float32)


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB


def _cpu_s() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def _current_rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def _worker_stp(n: int, accuracy: str, horizon: float, cfl: float, out: str) -> dict:
    import jax.numpy as jnp

    from stp_env import hj
    from stp_env.dynamics import RelativeDubins

    rss_import = _current_rss_mb()
    dyn = RelativeDubins(v_min=5, v_max=5, omega_max=1, other_v_min=5, other_v_max=5, other_omega_max=1, wind=0.0)
    grid = hj.Grid.from_bounds(LO, HI, (n,) * 3, periodic=2)
    target = jnp.asarray(_target(n))
    settings = hj.SolverSettings.with_accuracy(accuracy, tube_mode="freeze", cfl=cfl)
    dt, _ = hj.cfl_time_step(settings, dyn, grid, jnp.float32)

    t0 = time.perf_counter()
    hj.solve(settings, dyn, grid, [0.0, -2 * dt], target, tube=True, progress=False).values.block_until_ready()
    warm = time.perf_counter() - t0

    t0, c0 = time.perf_counter(), _cpu_s()
    res = hj.solve(settings, dyn, grid, [0.0, -horizon], target, tube=True, progress=False)
    res.values.block_until_ready()
    wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    np.save(out, np.asarray(res.values[-1]))
    return {"wall_s": wall, "cpu_s": cpu, "warmup_s": warm, "steps": res.n_steps, "dt": res.dt,
            "rss_after_import_mb": rss_import, "peak_rss_mb": _rss_mb()}


def _hj_reachability_steps(horizon: float, cfl: float, bound: np.float32) -> int:
    """Steps of hj_reachability's ``while |t_target - t| > 0: t += -min(cfl * bound, |t_target - t|)`` in
    float32 (its ``solver.step`` and ``time_integration.euler_step``)."""
    t, target = np.float32(0.0), np.float32(-horizon)
    dt_cfl = np.float32(cfl) * np.float32(bound)
    steps = 0
    while abs(target - t) > 0:
        t = np.float32(t - min(dt_cfl, abs(target - t)))
        steps += 1
    return steps


def _worker_hj(n: int, accuracy: str, horizon: float, cfl: float, out: str) -> dict:
    import hj_reachability as hjr
    import jax
    import jax.numpy as jnp

    rss_import = _current_rss_mb()
    dyn = hjr.systems.Air3d()
    grid = hjr.Grid.from_lattice_parameters_and_boundary_conditions(
        hjr.sets.Box(np.array(LO), np.array(HI)), (n,) * 3, periodic_dims=2)
    target = jnp.asarray(_target(n))
    settings = hjr.SolverSettings.with_accuracy(
        accuracy, hamiltonian_postprocessor=hjr.solver.backwards_reachable_tube, CFL_number=cfl)

    # hj_reachability's own CFL bound: 1 / max_x sum_i alpha_i(x) / dx_i (euler_step, global_lax_friedrichs).
    @jax.jit
    def bound_fn(states):
        alpha = jax.vmap(lambda s: dyn.partial_max_magnitudes(s, 0.0, 0.0, None))(states.reshape(-1, 3))
        return 1 / jnp.max(jnp.sum(alpha / jnp.asarray(grid.spacings), -1))

    bound = np.float32(bound_fn(grid.states))
    dt = float(np.float32(cfl) * bound)

    t0 = time.perf_counter()
    hjr.solve(settings, dyn, grid, jnp.array([0.0, -2 * dt]), target, progress_bar=False).block_until_ready()
    warm = time.perf_counter() - t0

    t0, c0 = time.perf_counter(), _cpu_s()
    values = hjr.solve(settings, dyn, grid, jnp.array([0.0, -horizon]), target, progress_bar=False)
    values.block_until_ready()
    wall, cpu = time.perf_counter() - t0, _cpu_s() - c0
    np.save(out, np.asarray(values[-1]))
    steps = _hj_reachability_steps(horizon, cfl, bound)
    return {"wall_s": wall, "cpu_s": cpu, "warmup_s": warm, "steps": steps, "dt": dt,
            "rss_after_import_mb": rss_import, "peak_rss_mb": _rss_mb()}


def _run_worker(solver: str, n: int, accuracy: str, horizon: float, cfl: float, out: str) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--worker", solver, "--sizes", str(n),
           "--accuracy", accuracy, "--horizon", repr(horizon), "--cfl", repr(cfl), "--out", out]
    proc = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{solver} worker failed:\n{proc.stderr[-4000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def run_case(n: int, accuracy: str, horizon: float, cfl: float, save_dir: str | None = None) -> dict:
    load = os.getloadavg()[0]
    with tempfile.TemporaryDirectory() as tmp:
        out_dir = save_dir or tmp
        paths = {s: os.path.join(out_dir, f"air3d_{n}_{accuracy}_{s}.npy") for s in ("stp_env", "hj_reachability")}
        stp = _run_worker("stp", n, accuracy, horizon, cfl, paths["stp_env"])
        ref = _run_worker("hj", n, accuracy, horizon, cfl, paths["hj_reachability"])
        v_stp = np.load(paths["stp_env"]).astype(np.float64)
        v_hj = np.load(paths["hj_reachability"]).astype(np.float64)
    spacing = [(h - lo) / (n if i == 2 else n - 1) for i, (lo, h) in enumerate(zip(LO, HI))]
    dx = min(spacing)
    diff = np.abs(v_stp - v_hj)
    band = np.abs(v_hj) <= 1.0
    return {
        "case": "air3d", "n": n, "accuracy": accuracy, "horizon": horizon, "cfl": cfl, "dtype": "float32",
        "tube": "freeze / backwards_reachable_tube",
        "stp_env_s": round(stp["wall_s"], 3),
        "hj_reachability_s": round(ref["wall_s"], 3),
        "ratio": round(ref["wall_s"] / stp["wall_s"], 2),
        "cpu_s": [round(stp["cpu_s"], 2), round(ref["cpu_s"], 2)],  # user + sys of the timed solve
        "stp_env_steps": stp["steps"],
        "hj_reachability_steps": ref["steps"],
        "stp_env_per_step_ms": round(1e3 * stp["wall_s"] / stp["steps"], 3),
        "hj_reachability_per_step_ms": round(1e3 * ref["wall_s"] / ref["steps"], 3),
        "stp_env_ns_per_node_step": round(1e9 * stp["wall_s"] / stp["steps"] / n**3, 2),
        "dt": [stp["dt"], ref["dt"]],
        "max_abs_diff": float(diff.max()),
        "max_abs_diff_over_dx": float(diff.max() / dx),
        "max_abs_diff_near_zero_over_dx": float(diff[band].max() / dx),  # nodes with |V| <= 1
        "sign_disagreements": int(np.sum((v_stp <= 0) != (v_hj <= 0))),
        "stp_env_warmup_s": round(stp["warmup_s"], 2),
        "hj_reachability_warmup_s": round(ref["warmup_s"], 2),
        "stp_env_peak_rss_mb": round(stp["peak_rss_mb"]),
        "hj_reachability_peak_rss_mb": round(ref["peak_rss_mb"]),
        "rss_after_import_mb": [round(stp["rss_after_import_mb"]), round(ref["rss_after_import_mb"])],
        "loadavg_1min_before": round(load, 2),
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[51, 101])
    parser.add_argument("--accuracy", choices=ACCURACIES, default="very_high")
    parser.add_argument("--horizon", type=float, default=2.8)
    parser.add_argument("--cfl", type=float, default=0.75)
    parser.add_argument("--save-dir", help="keep both final value functions here (.npy)")
    parser.add_argument("--worker", choices=("stp", "hj"), help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        fn = _worker_stp if args.worker == "stp" else _worker_hj
        print(json.dumps(fn(args.sizes[0], args.accuracy, args.horizon, args.cfl, args.out)), flush=True)
        return
    for n in args.sizes:
        print(json.dumps(run_case(n, args.accuracy, args.horizon, args.cfl, args.save_dir)), flush=True)


if __name__ == "__main__":
    main()

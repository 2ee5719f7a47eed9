"""How much of the planner's buffer disk is slack: the disk adds the avoid region's reach ``d^A`` and the reach
``r_VB`` of ``V^B(0, t_BRD)`` as if the intruder could be at both extremes at once, but one intruder heading serves
both sets. This measures the exact rotation-invariant radius with that heading shared.

    python examples/buffer_coupling.py [--kbars 1 2 3 4] [--scenario pinwheel]

With the intruder's heading fixed at 0 (the radius is rotation invariant), a vehicle ``j`` of heading ``theta_j``
has the intruder at ``p_I - p_j = R(theta_j) s`` with ``(s, -theta_j)`` in ``V^A(0, t_IAT)``, and a vehicle ``i``
has it at ``p_I - p_i = R(theta_i) b`` with ``(b, -theta_i)`` in ``V^B`` (both tables hold the intruder relative to
the vehicle, in the vehicle's frame, with relative heading ``theta_I - theta``). The vehicles' headings are free, so
``p_i - p_j`` ranges over ``A - B`` with ``A = {R(-theta) s : V^A(s, theta) <= 0}`` and ``B`` likewise, and the radius
is ``max_u h_A(u) + h_B(-u)`` over directions ``u`` (support functions). Each heading slice's boundary is found along
720 rays with bilinear interpolation (0.1 cell steps), at the tables' heading nodes. Prints one JSON line per k̄ with
``d^A``, ``r_VB``, the disk's ``d^A + r_VB`` and the coupled radius, and both with the tracking bubbles ``2 r_e``.
"""

from __future__ import annotations

import argparse
import json
import math

import numpy as np


def footprint(grid, values, n_rays: int = 720) -> np.ndarray:
    """Points of ``{V <= 0}`` (relative-position x heading tables) rotated into the frame of the intruder's heading:
    per heading slice ``theta``, the farthest inside point along each ray, rotated by ``-theta``."""
    import jax
    import jax.numpy as jnp

    from stp_env import hj

    plane = hj.Grid.from_bounds(grid.lo[:2], grid.hi[:2], grid.shape[:2])
    radii = np.arange(0.0, min(abs(grid.lo[0]), grid.hi[0], abs(grid.lo[1]), grid.hi[1]), 0.1 * min(plane.spacing))
    angles = np.linspace(-np.pi, np.pi, n_rays, endpoint=False)
    rays = jnp.asarray(np.stack([np.outer(np.cos(angles), radii), np.outer(np.sin(angles), radii)], -1), jnp.float32)
    sample = jax.jit(jax.vmap(jax.vmap(lambda sl, p: hj.interpolation.interpolate(plane, sl, p), (None, 0)), (None, 0)))
    points = []
    for k, theta in enumerate(np.asarray(grid.coordinate_vectors()[2])):
        inside = np.asarray(sample(jnp.asarray(np.asarray(values)[:, :, k], jnp.float32), rays)) <= 0
        if not inside.any():
            continue
        r = np.max(np.where(inside, radii[None, :], -1.0), axis=1)
        keep = r >= 0
        p = np.stack([r[keep] * np.cos(angles[keep]), r[keep] * np.sin(angles[keep])], 1)
        c, s = math.cos(theta), math.sin(theta)
        points.append(p @ np.asarray([[c, -s], [s, c]]))  # row vectors: R(-theta) p
    return np.concatenate(points)


def coupled_radius(a: np.ndarray, b: np.ndarray, n_dirs: int = 2880) -> float:
    """``max |x - y|`` over ``x`` in ``a``, ``y`` in ``b`` (point sets), by support functions."""
    t = np.linspace(0.0, 2 * np.pi, n_dirs, endpoint=False)
    u = np.stack([np.cos(t), np.sin(t)], 1)
    return float(((a @ u.T).max(0) + (-(b @ u.T)).max(0)).max())


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--kbars", nargs="+", type=int, default=[1, 2, 3, 4])
    parser.add_argument("--scenario", default="pinwheel", help="a scenario with the town's vehicle (any k̄)")
    args = parser.parse_args()

    from stp_env import assembly
    from stp_env.assembly import load_buffer
    from stp_env.scenarios import make

    for kbar in args.kbars:
        scenario = make(args.scenario, kbar=kbar)
        avoid, tracking = assembly.load_artifacts(scenario, progress=False)
        buffer = load_buffer(scenario, progress=False)
        k0 = int(np.argmin(np.abs(np.asarray(avoid.taus))))
        a = footprint(avoid.grid, np.asarray(avoid.values)[k0])
        b = footprint(buffer.config.grid, buffer.values)
        d_a, r_vb = float(np.hypot(*a.T).max()), float(np.hypot(*b.T).max())
        coupled = coupled_radius(a, b)
        print(json.dumps({"kbar": kbar, "d_A_m": round(d_a, 2), "r_VB_m": round(r_vb, 2),
                          "disk_m": round(d_a + r_vb, 2), "coupled_m": round(coupled, 2),
                          "disk_with_bubbles_m": round(2 * tracking.bound + d_a + r_vb, 2),
                          "coupled_with_bubbles_m": round(2 * tracking.bound + coupled, 2)}), flush=True)


if __name__ == "__main__":
    main()

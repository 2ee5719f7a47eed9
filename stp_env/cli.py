"""The ``stp-env`` command line.

Subcommands:

* ``avoid-region``: compute the intruder avoid region ``V^A(0, t_IAT)`` of two Dubins vehicles in wind
  (intruder paper eqs. 13-16) and write a PNG.

Exit codes: 0 on success, 2 on bad options (with a message saying what is allowed).
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def _positive(kind):
    def parse(text: str):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected a {kind.__name__}, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value
    return parse


def _nonnegative(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value >= 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {text}")
    return value


def _build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="stp-env", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)

    av = sub.add_parser("avoid-region", help="compute and plot the intruder avoid region V^A (eqs. 13-16)",
                        formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    av.add_argument("--out", default="avoid_region.png", help="PNG file to write")
    av.add_argument("--wind", type=_nonnegative, default=6.0,
                    help="wind bound of each vehicle and of the intruder [m/s]")
    av.add_argument("--v-max", type=_positive(float), default=25.0, help="maximum speed of both [m/s]")
    av.add_argument("--omega-max", type=_positive(float), default=2.0, help="maximum turn rate of both [rad/s]")
    av.add_argument("--collision-radius", type=_positive(float), default=100.0, help="R_c [m]")
    av.add_argument("--t-iat", type=_positive(float), default=10.0,
                    help="t_IAT, the longest time the intruder stays [s]")
    av.add_argument("--half-width", type=_positive(float), default=320.0,
                    help="half-width of the relative-position grid box [m]")
    av.add_argument("--grid", type=_positive(int), default=51,
                    help="grid points per position dimension (heading gets the next even count, so that "
                         "relative heading 0 is a node)")
    av.add_argument("--accuracy", choices=["low", "medium", "high", "very_high"], default="very_high",
                    help="solver preset (scheme + time integrator)")
    av.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    return parser


def _avoid_region(args) -> int:
    from stp_env.dynamics import DubinsWind
    from stp_env.reach.avoid import AvoidRegionConfig, compute_avoid_region, plot_avoid_region

    vehicle = DubinsWind(v_min=0.0, v_max=args.v_max, omega_max=args.omega_max, wind=args.wind)
    config = AvoidRegionConfig(vehicle=vehicle, intruder=vehicle, collision_radius=args.collision_radius,
                               t_iat=args.t_iat, half_width=args.half_width,
                               grid_points=(args.grid, args.grid, args.grid + args.grid % 2), accuracy=args.accuracy)
    start = time.perf_counter()
    region = compute_avoid_region(config, progress=not args.no_progress)
    seconds = time.perf_counter() - start
    margin = region.boundary_margin
    if margin <= 0:
        print(f"warning: the avoid region touches the grid boundary (min boundary value {margin:.1f}); "
              "increase --half-width", file=sys.stderr)
    path = plot_avoid_region(region, args.out)
    summary = {
        "png": path,
        "detection_range_m": round(region.detection_range(), 1),
        "behind_extent_exact_m": config.behind_extent(),
        "boundary_margin_m": round(margin, 1),
        "grid": list(config.grid.shape),
        "time_steps": region.n_steps,
        "seconds": round(seconds, 1),
    }
    print(json.dumps(summary))
    return 0


def main(argv=None) -> int:
    parser = _build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "avoid-region":
            return _avoid_region(args)
    except ValueError as err:
        print(f"stp-env {args.command}: error: {err}", file=sys.stderr)
        return 2
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":
    sys.exit(main())

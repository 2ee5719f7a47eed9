"""``stp-env data convert-checkpoint``: rewrites a planning checkpoint in another file format, with the same key and
the same bits.

    stp-env data convert-checkpoint DIR/bay-area.ckpt.npz bay-area.ckpt2.npz              # to format 2
    stp-env data convert-checkpoint bay-area.ckpt2.npz DIR/bay-area.ckpt.npz --format 1   # and back

Format 2 (the current planner's) packs and compresses the trajectories: about 14x smaller for a long run, small
enough to carry a run's progress to another machine. Format 1 is what planners before it read and write, so a run
that an older, frozen checkout started resumes from a converted file (:func:`stp_env.planning.checkpoint.convert`).
Prints one JSON line.
"""

from __future__ import annotations

import json
from pathlib import Path

from stp_env import cli_kit as kit
from stp_env.data_tools import description


def add_parser(sub) -> None:
    """Add ``convert-checkpoint`` to the ``stp-env data`` subcommands (building it imports no JAX:
    :mod:`stp_env.planning.checkpoint` is NumPy only)."""
    from stp_env.planning import checkpoint

    p = sub.add_parser("convert-checkpoint", help="rewrite a planning checkpoint in another file format (same key, "
                                                  "same bits)",
                       formatter_class=kit.HelpFormatter, description=description(__doc__))
    p.add_argument("src", type=Path, help="a planning checkpoint (either format)")
    p.add_argument("dst", type=Path, help="where to write it (may be src)")
    p.add_argument("--format", type=int, choices=checkpoint.FORMATS, default=checkpoint.FORMAT,
                   help="file format to write")
    p.set_defaults(run=run, command="data convert-checkpoint")


def run(args) -> int:
    """Run ``stp-env data convert-checkpoint``."""
    from stp_env.planning import checkpoint

    if not args.src.is_file():
        raise ValueError(f"{args.src}: no such file.")
    n = checkpoint.convert(args.src, args.dst, args.format)
    print(json.dumps({"src": str(args.src), "dst": str(args.dst), "format": args.format, "vehicles": n,
                      "bytes": args.dst.stat().st_size}))
    return 0

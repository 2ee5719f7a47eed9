"""Rewrites a planning checkpoint in another file format, with the same key and the same bits.

Format 2 (the current planner's) packs and compresses the trajectories: about 14x smaller for a long run, small
enough to carry a run's progress to another machine. Format 1 is what planners before it read and write, so a run
that an older, frozen checkout started resumes from a converted file (``stp_env.planning.checkpoint.convert``).

    python scripts/convert_checkpoint.py DIR/bay-area.ckpt.npz bay-area.ckpt2.npz              # to format 2
    python scripts/convert_checkpoint.py bay-area.ckpt2.npz DIR/bay-area.ckpt.npz --format 1   # and back
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from stp_env.planning import checkpoint


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("src", type=Path, help="a planning checkpoint (either format)")
    parser.add_argument("dst", type=Path, help="where to write it (may be src)")
    parser.add_argument("--format", type=int, choices=checkpoint.FORMATS, default=checkpoint.FORMAT,
                        help=f"file format to write (default {checkpoint.FORMAT})")
    args = parser.parse_args(argv)
    if not args.src.is_file():
        raise SystemExit(f"{args.src}: no such file.")
    try:
        n = checkpoint.convert(args.src, args.dst, args.format)
    except ValueError as err:
        raise SystemExit(str(err)) from err
    print(json.dumps({"src": str(args.src), "dst": str(args.dst), "format": args.format, "vehicles": n,
                      "bytes": args.dst.stat().st_size}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

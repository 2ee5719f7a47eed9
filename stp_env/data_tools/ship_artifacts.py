"""``stp-env data artifacts``: regenerate the reachability artifacts that ship with the package
(``stp_env/data/artifacts/``), or check them.

    stp-env data artifacts              # compute (or take from the cache) and copy; drop stale copies (a checkout)
    stp-env data artifacts --check      # exit 1 if a shipped copy is stale or one is missing
    stp-env data artifacts --recompute  # compute every shipped artifact from scratch (an empty cache)
                                        # and exit 1 unless the shipped copies hold the same arrays

What ships: every artifact the default scenario's parameters read (:func:`stp_env.assembly.params_for` of ``town``,
the default ``stp-env evaluate`` run), and the tracking-error bound and avoid region of every scenario a shipped plan
is for (the 11 m/s ones of the city Cases 1, 3, 4 and the bay area: solves of several minutes, certified in closed
loop), whose array file is at most ``--max-mb``: the tracking bounds and the avoid regions' closed-loop
certificates; the 55 MB avoid tables (a 1-minute solve each) do not ship. A shipped copy is keyed like a cache
entry (parameters, format and code version, content hash), so any edit to the code that computes it (the solver,
the dynamics, the reachability sets: :func:`stp_env.artifacts.code_version`; not the planner or the scenarios)
makes it stale: ``tests/test_artifacts.py`` then fails until this command is run again. The cache
(``STP_ENV_CACHE_DIR``) is used for the computation, so a second run is a copy. Copying writes the package's own
data, which only a source checkout does (:func:`stp_env.data_tools.shipping.checkout_data`); ``--check`` and
``--recompute`` write nothing there.

``--check`` compares keys only (cheap). ``--recompute`` is the full check that a shipped copy is what this code
computes on this machine (the tracking bound's solve is most of its time): the test suite solves the bound on a
coarser grid only (``tests/test_reach_tracking.py``). Each prints one JSON line.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path

from stp_env import cli_kit as kit
from stp_env.data_tools import description, shipping


def _recording_store(root=None):
    """The cache without the shipped layer, remembering which artifacts were asked for (``store.used``)."""
    from stp_env.artifacts import ArtifactStore

    class Recording(ArtifactStore):
        def __init__(self, root=None):
            super().__init__(root, shipped=None)
            self.used = []

        def load_or_compute(self, kind, params, compute, extra_metadata=None):
            art = super().load_or_compute(kind, params, compute, extra_metadata)
            self.used.append(art)
            return art

    return Recording(root)


def wanted(max_mb: float, root=None) -> list:
    """The cache files (npz paths) of the artifacts to ship, computed if not cached (in ``root``, or the default
    cache)."""
    from stp_env import assembly, sim
    from stp_env.assembly import SHIPPED_PLANS, load_artifacts
    from stp_env.scenarios import make

    store = _recording_store(root)
    finals = [load_artifacts(make("town"), store=store, progress=True)[1]]
    assembly.params_for("town", sim.EnvConfig(), store=store, progress=True)
    for file, (name, overrides) in sorted(SHIPPED_PLANS.items()):
        if (shipping.PLANS / f"{file}.npz").is_file():
            finals.append(load_artifacts(make(name, **overrides), store=store, progress=True)[1])
    # the tracking bounds of the boxes default_tracking_bound grew out of (the cost cap bound) do not ship: a first
    # use recomputes them (seconds: the cap binds before any certification) and then reads the final box's copy
    final = {store.paths("tracking_bound", t.config)[0] for t in finals}
    return sorted({a.path for a in store.used if a.path.stat().st_size <= max_mb * 2**20
                   and (a.path in final or not a.path.name.startswith("tracking_bound-"))})


def _same_key(shipped: Path, cached: Path) -> bool:
    from stp_env.loaders import read_json

    if not shipped.is_file():
        return False
    a, b = read_json(shipped, "artifact-metadata"), read_json(cached, "artifact-metadata")
    return (a.get("key"), a.get("code_version")) == (b.get("key"), b.get("code_version"))


def _copy_atomic(src: Path, dst: Path) -> None:
    fd, tmp = tempfile.mkstemp(dir=dst.parent, prefix=".ship-", suffix=dst.suffix)
    os.close(fd)
    try:
        shutil.copyfile(src, tmp)
        os.chmod(tmp, 0o644)                                # package data: readable by every user
        os.replace(tmp, dst)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def compare(computed: Path, shipped: Path, atol: float) -> dict:
    """Largest absolute difference per array between a freshly computed artifact and its shipped copy (``None`` for
    an array missing from one of them or of another shape)."""
    import numpy as np

    from stp_env.loaders import read_npz

    a, b = read_npz(computed, "artifact-arrays"), read_npz(shipped, "artifact-arrays")
    diffs = {}
    for name in sorted(set(a) | set(b)):
        if name not in a or name not in b or a[name].shape != b[name].shape:
            diffs[name] = None
            continue
        x, y = a[name].astype(np.float64), b[name].astype(np.float64)
        same_nan = bool(np.array_equal(np.isnan(x), np.isnan(y)))
        diff = np.abs(np.where(np.isnan(x), 0.0, x) - np.where(np.isnan(y), 0.0, y))
        diffs[name] = float(np.max(diff, initial=0.0)) if same_nan else float("inf")
    ok = all(d is not None and d <= atol for d in diffs.values())
    return {"file": shipped.name, "same": ok, "max_abs_diff": diffs}


def recompute(max_mb: float, atol: float) -> int:
    """``--recompute``: 0 if every shipped copy holds what a computation from an empty cache gives, else 1."""
    from stp_env.artifacts import SHIPPED_DIR

    with tempfile.TemporaryDirectory(prefix="stp-env-recompute-") as root:
        paths = wanted(max_mb, root)
        reports = []
        for p in paths:
            shipped = SHIPPED_DIR / p.name
            reports.append(compare(p, shipped, atol) if shipped.is_file() else
                           {"file": p.name, "same": False, "max_abs_diff": "not shipped"})
    ok = bool(reports) and all(r["same"] for r in reports)
    print(json.dumps({"recomputed_like_shipped": ok, "atol": atol, "artifacts": reports}))
    return 0 if ok else 1


def add_parser(sub) -> None:
    """Add ``artifacts`` to the ``stp-env data`` subcommands (building it imports no JAX)."""
    p = sub.add_parser("artifacts", help="regenerate the shipped reachability artifacts (a checkout), or check them "
                                         "(--check, --recompute: exit 1 if stale)",
                       formatter_class=kit.HelpFormatter, description=description(__doc__))
    p.add_argument("--max-mb", type=kit.positive, default=2.0, help="largest array file that ships [MiB]")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--check", action="store_true", help="only report whether the shipped copies are current")
    mode.add_argument("--recompute", action="store_true",
                      help="compute the shipped artifacts from scratch and compare them with the shipped copies")
    p.add_argument("--atol", type=kit.nonnegative, default=1e-3,
                   help="--recompute: largest accepted difference per value")
    p.set_defaults(run=run, command="data artifacts")


def run(args) -> int:
    """Run ``stp-env data artifacts``: copy (0), or with ``--check`` / ``--recompute`` 0 if current, else 1."""
    if args.recompute:
        return recompute(args.max_mb, args.atol)
    from stp_env.artifacts import SHIPPED_DIR as shipped_dir

    if not args.check:
        shipping.checkout_data(shipped_dir, "stp-env data artifacts", "--check and --recompute only compare")
    paths = wanted(args.max_mb)
    names = {p.name for p in paths} | {p.with_suffix(".json").name for p in paths}
    present = {p.name for p in shipped_dir.glob("*")} if shipped_dir.is_dir() else set()
    if args.check:
        # current: every wanted artifact ships, keyed as this code keys it (the time or machine it was computed on
        # may differ from the cache's copy)
        current = all(_same_key(shipped_dir / p.with_suffix(".json").name, p.with_suffix(".json")) for p in paths)
        print(json.dumps({"current": current and present == names, "wanted": sorted(names),
                          "shipped": sorted(present)}))
        return 0 if current and present == names else 1
    shipped_dir.mkdir(parents=True, exist_ok=True)
    for p in paths:
        _copy_atomic(p, shipped_dir / p.name)              # arrays first: a copy without its metadata is ignored
        _copy_atomic(p.with_suffix(".json"), shipped_dir / p.with_suffix(".json").name)
    for stale in sorted(present - names):
        (shipped_dir / stale).unlink()
    print(json.dumps({"shipped": sorted(names), "removed": sorted(present - names),
                      "bytes": sum((shipped_dir / n).stat().st_size for n in names)}))
    return 0

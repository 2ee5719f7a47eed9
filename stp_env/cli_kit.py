"""The command line's shared option types and options: one definition (type, range, help text with units) of the
seed, batch sizes, output and cache directories, progress, wind model and scenario that every ``stp-env``
subcommand uses, and the help formatter that prints each default once.

The types are the library's checks (:mod:`stp_env.arguments`, :func:`stp_env.seeds.check_seed`) turned into
argparse types: a bad value exits with code 2 and one line naming the option. Building the parser, and
``--help``, import no JAX: the names the help texts list (wind models, scenarios, intruders, vehicle policies,
spawn modes, and the installed plug-ins of each) come from :mod:`stp_env.catalog`, plain tables that the
registries check themselves against.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from stp_env import catalog
from stp_env.arguments import INT32_MAX, MAX_KBAR, check_int, check_kbar, check_real, parse_spec
from stp_env.resources import EPISODE_BYTES, check_count, check_memory, cpu_limit_reason, max_cpu_devices
from stp_env.seeds import MAX_SEED, MAX_SEED_32, check_seed

PACKAGE = Path(__file__).resolve().parent


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Appends ``(default: X)`` to an option's help once: not when the help already says what the default is
    (``default:``), and not for a default of ``None`` or ``False`` (an option that is off unless given)."""

    def _get_help_string(self, action):
        text = action.help or ""
        default = action.default
        if ("default:" in text or default is None or default is False or default is argparse.SUPPRESS
                or isinstance(action, argparse._HelpAction)):
            return text
        return super()._get_help_string(action)


# ------------------------------------------------------------------------------------------------ types
def _typed(check, kind: str):
    """An argparse type: the text as ``kind`` (int or float), then ``check(value)``; argparse reports a
    ``ArgumentTypeError`` as ``argument --option: message``."""
    def parse(text: str):
        try:
            value = int(text) if kind == "int" else float(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind == 'int' else 'a number'}, got "
                                             f"{text[:40]!r}") from None
        try:
            return check(value)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err).split("; got")[0].strip() + f", got {text[:40]}") from None

    parse.__name__ = kind
    return parse


def integer(lo: int | None = None, hi: int | None = INT32_MAX):
    """An integer in ``[lo, hi]`` (``hi`` defaults to :data:`stp_env.arguments.INT32_MAX`)."""
    return _typed(lambda v: check_int(v, "", lo, hi), "int")


def real(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False, hi_open: bool = False):
    """A finite number in the range (``nan`` and ``inf`` are refused)."""
    return _typed(lambda v: check_real(v, "", lo, hi, lo_open=lo_open, hi_open=hi_open), "float")


def in_memory(unit_bytes: int, unit: str, hi: int = INT32_MAX):
    """A count in ``[1, hi]`` of things (``unit``) of at least ``unit_bytes`` each that fit in the memory available now
    (:func:`stp_env.resources.check_memory`): a batch that could never be allocated is refused while parsing."""
    bounded = integer(1, hi)

    def parse(text: str) -> int:
        n = bounded(text)
        try:
            return check_memory("", n, unit_bytes=unit_bytes, unit=unit)
        except ValueError as err:
            raise argparse.ArgumentTypeError(str(err).rstrip(".")) from None

    parse.__name__ = "int"
    return parse


positive_int = integer(1)
count = integer(0)
positive = real(0.0, lo_open=True)
nonnegative = real(0.0)
probability = real(0.0, 1.0, lo_open=True, hi_open=True)
unit_interval = real(0.0, 1.0)
kbar = _typed(lambda v: check_kbar(v, ""), "int")


def seed(maximum: int = MAX_SEED):
    """A seed in ``[0, maximum]`` (:func:`stp_env.seeds.check_seed`)."""
    return _typed(lambda v: check_seed(v, "", maximum), "int")


def wind_model(text: str) -> str:
    """A wind model spec ``name`` or ``name:param=value,...`` of a registered model (checked against the models'
    source, :func:`wind_model_catalog`; the model checks its parameters' ranges before anything is computed)."""
    catalog = wind_model_catalog()
    try:
        parse_spec(text, "wind model", catalog, lambda name: catalog[name]["params"])
    except ValueError as e:
        raise argparse.ArgumentTypeError(str(e).rstrip(".")) from None
    return text


def scenario(text: str) -> str:
    """A registered scenario name (:func:`scenario_names`)."""
    names = scenario_names()
    if text not in names:
        raise argparse.ArgumentTypeError(f"unknown scenario {text!r}; registered: {', '.join(names)}")
    return text


# ------------------------------------------------------------------------------------------------ options
SEED_HELP = ("an integer in [0, {bound}]; every seed its own random stream (no wrap-around, no negative "
             "seeds)")


def add_seed(parser, what: str, *, default: int = 0, maximum: int = MAX_SEED) -> None:
    """``--seed``: ``what`` it seeds."""
    bound = "2**63 - 1" if maximum == MAX_SEED else "2**32 - 1" if maximum == MAX_SEED_32 else str(maximum)
    parser.add_argument("--seed", type=seed(maximum), default=default,
                        help=f"seed of {what}: " + SEED_HELP.format(bound=bound))


def add_batch_size(parser, what: str, *, default: int, maximum: int = INT32_MAX, unit_bytes: int = EPISODE_BYTES,
                   unit: str = "episode") -> None:
    """``--batch-size``: ``what`` one batch holds, with its unit; at most ``maximum`` and as many things (``unit``)
    of ``unit_bytes`` as the memory available holds (:func:`in_memory`)."""
    parser.add_argument("--batch-size", dest="batch_size", type=in_memory(unit_bytes, unit, maximum),
                        default=default, metavar="N", help=what)


def add_out(parser, default: str, what: str = "output directory") -> None:
    """``--out``: checked to be writable before anything is computed."""
    parser.add_argument("--out", default=default, help=f"{what} (checked to be writable before anything is "
                                                       "computed)")


def add_ray(parser, what: str) -> None:
    """``--ray`` / ``--ray-address ADDRESS``: run the job's pieces on Ray (:mod:`stp_env.execution`)."""
    parser.add_argument("--ray", action="store_true",
                        help=f"run {what} as Ray tasks: on the cluster at $RAY_ADDRESS if set, else on a new local "
                             "cluster (the same results as in-process; needs pip install 'stp-env[ray]'; "
                             "docs/ray.md)")
    parser.add_argument("--ray-address", default=None, metavar="ADDRESS",
                        help="run on the Ray cluster at ADDRESS (what `ray start --head` prints; 'auto': the one on "
                             "this machine); implies --ray")


def cpu_device_count(value: str) -> int | str:
    """``--cpu-devices``'s value: ``auto`` or a positive integer of at most
    :func:`stp_env.resources.max_cpu_devices` (refused while parsing, before JAX starts)."""
    if value.strip() == "auto":
        return "auto"
    try:
        n = positive_int(value)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a positive integer or 'auto', got {value[:40]!r}") from None
    try:
        return check_count("", n, limit=max_cpu_devices(), why=cpu_limit_reason())
    except ValueError as err:
        raise argparse.ArgumentTypeError(str(err).rstrip(".")) from None


def add_cpu_devices(parser, unset: int | str = "auto", note: str = "") -> None:
    """``--cpu-devices N|auto``: JAX's CPU split into ``N`` devices, each batch shared among them (default: the
    ``STP_ENV_CPU_DEVICES`` environment variable, else ``unset``; ``auto``: one device per core)."""
    default = "'auto', one per core" if unset == "auto" else str(unset)
    parser.add_argument("--cpu-devices", type=cpu_device_count, default=None, metavar="N",
                        help=f"split the CPU into N devices and share every batch among them ('auto': one per core); "
                             f"default: the STP_ENV_CPU_DEVICES environment variable, else {default}{note}; each "
                             "count is another compiled program, so episodes agree in their outcomes, not always in "
                             "their last bits (an evaluation's events record N and replay with it); with --ray, "
                             "Ray's workers run the batches on one device each")
    parser.set_defaults(cpu_devices_unset=unset)


def apply_cpu_devices(args) -> None:
    """Set ``--cpu-devices`` before JAX starts (:func:`stp_env.set_cpu_devices`). ``auto``: one device per core
    (:func:`stp_env.cpu_threads.available_cores`), or nothing when JAX has already started (it keeps its count) or
    with --ray (the batches run in Ray's workers, one device each). ``ValueError`` for a count other than 1 with
    --ray, a bad ``STP_ENV_CPU_DEVICES``, or a count other than the one JAX has started with."""
    from stp_env.cpu_threads import (
        DEVICES_ENV_VAR,
        _backend_started,
        available_cores,
        default_cpu_devices,
        set_cpu_devices,
    )

    unset = getattr(args, "cpu_devices_unset", "auto")
    requested = args.cpu_devices if args.cpu_devices is not None else default_cpu_devices(unset)
    on_ray = bool(getattr(args, "ray", False) or getattr(args, "ray_address", None))
    if requested == "auto":
        if not on_ray and not _backend_started():
            set_cpu_devices(available_cores())
        return
    if requested != 1 and on_ray:
        source = "--cpu-devices" if args.cpu_devices is not None else DEVICES_ENV_VAR
        raise ValueError(f"{source} shares the batches of this process among its devices; with --ray the batches "
                         "run in Ray's workers: leave it out (or give 1).")
    try:
        set_cpu_devices(requested)
    except RuntimeError as err:
        raise ValueError(str(err)) from None


def follow_cpu_devices(n: int) -> None:
    """Use ``n`` CPU devices (a saved event's count) when JAX has not started; otherwise leave the count as it is
    (the replay then says that it runs another program)."""
    from stp_env.cpu_threads import _backend_started, set_cpu_devices

    if not _backend_started():
        set_cpu_devices(int(n))


def executor(args):
    """The executor that ``--ray`` / ``--ray-address`` ask for (in-process without them)."""
    from stp_env.execution import executor_for

    return executor_for(args.ray, args.ray_address)


def add_cache_dir(parser) -> None:
    """``--cache-dir``: the artifact cache."""
    parser.add_argument("--cache-dir", default=None,
                        help="artifact cache directory (default: $STP_ENV_CACHE_DIR, else the user cache directory)")


def add_progress(parser) -> None:
    """``--no-progress``."""
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bars")


def add_wind_model(parser, default: str, what: str = "how the winds are drawn") -> None:
    """``--wind-model NAME[:param=value,...]`` of the registered models (:mod:`stp_env.sim.winds`)."""
    parser.add_argument("--wind-model", type=wind_model, default=default, metavar="NAME[:PARAM=VALUE,...]",
                        help=f"{what}: a registered wind model, with parameters as name:param=value,... "
                             f"({describe_wind_models()})")


def add_scenario(parser, default: str | None, what: str = "registered scenario") -> None:
    """``--scenario``: a registered scenario (:mod:`stp_env.scenarios`)."""
    parser.add_argument("--scenario", type=scenario, default=default, metavar="NAME",
                        help=f"{what}: one of {', '.join(scenario_names())}")


# ------------------------------------------------------------------------------------------------ catalogs
def wind_model_catalog() -> dict[str, dict]:
    """The wind models as ``--help`` lists them: ``{name: {"params": {field: default}, "help": text}}``, the
    built-ins' (:data:`stp_env.catalog.WIND_MODELS`), then the installed plug-ins' (named only: their modules are
    not imported for ``--help``)."""
    out = {name: {"params": dict(entry.params), "help": entry.help} for name, entry in catalog.WIND_MODELS.items()}
    for name in catalog.names("wind_models", catalog.WIND_MODELS)[len(catalog.WIND_MODELS):]:
        out[name] = {"params": {}, "help": "a plug-in"}
    return out


def describe_wind_models() -> str:
    """:func:`stp_env.sim.winds.describe`, from the catalog."""
    out = []
    for name, entry in wind_model_catalog().items():
        params = ", ".join(f"{k}={v}" for k, v in entry["params"].items())
        out.append(f"{name}{f' ({params})' if params else ''}: {entry['help']}")
    return "; ".join(out)


def scenario_names() -> tuple[str, ...]:
    """The registered scenarios (:data:`stp_env.catalog.SCENARIOS`) and the installed plug-ins', sorted."""
    return tuple(sorted(catalog.names("scenarios", catalog.SCENARIOS)))


def intruder_names() -> tuple[str, ...]:
    """The scripted intruders (:data:`stp_env.catalog.INTRUDERS`), then the installed plug-ins'."""
    return catalog.names("intruders", catalog.INTRUDERS)


def vehicle_policy_names() -> tuple[str, ...]:
    """The vehicle policies (:data:`stp_env.catalog.VEHICLE_POLICIES`), then the installed plug-ins'."""
    return catalog.names("vehicle_policies", catalog.VEHICLE_POLICIES)


def vehicle_policy_spec(text: str) -> str:
    """A vehicle policy: a scripted name (:func:`vehicle_policy_names`) or ``learned:NAME_OR_PATH`` (the file is
    checked when the configuration is, before anything is computed)."""
    if text.startswith("learned:"):
        if not text[len("learned:"):].strip():
            raise argparse.ArgumentTypeError("learned: needs a shipped name or the path of an .npz")
        return text
    names = vehicle_policy_names()
    if text not in names:
        raise argparse.ArgumentTypeError(f"unknown vehicle policy {text!r}; allowed: {', '.join(names)}, or "
                                         "learned:NAME_OR_PATH")
    return text


def spawn_modes() -> tuple[str, ...]:
    """:data:`stp_env.catalog.SPAWN_MODES`."""
    return catalog.SPAWN_MODES


__all__ = [
    "MAX_KBAR",
    "HelpFormatter",
    "add_batch_size",
    "add_cache_dir",
    "add_out",
    "add_progress",
    "add_scenario",
    "add_seed",
    "add_wind_model",
    "count",
    "describe_wind_models",
    "in_memory",
    "integer",
    "intruder_names",
    "kbar",
    "nonnegative",
    "positive",
    "positive_int",
    "probability",
    "real",
    "scenario",
    "scenario_names",
    "seed",
    "spawn_modes",
    "unit_interval",
    "vehicle_policy_names",
    "vehicle_policy_spec",
    "wind_model",
    "wind_model_catalog",
]

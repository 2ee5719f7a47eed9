"""The ``stp-env data`` command: its subcommands, one module each (:mod:`stp_env.data_tools`), under one parser.
Registered by :mod:`stp_env.cli` through :func:`add_parser`; building it, and ``--help``, import no JAX."""

from __future__ import annotations

from stp_env import cli_kit as kit
from stp_env.data_tools import check_plan, convert_checkpoint, plans, reconcile_controls, ship_artifacts, ship_intruder

COMMANDS = (plans, check_plan, reconcile_controls, convert_checkpoint, ship_artifacts, ship_intruder)
"""The modules of the subcommands, in the order ``stp-env data --help`` lists them."""


def add_parser(sub) -> None:
    """Add ``data`` and its subcommands to an argparse subparsers object."""
    data = sub.add_parser("data", help="maintain data: make, check and repair plans, convert planning checkpoints, "
                                       "ship reachability artifacts and learned intruders",
                          formatter_class=kit.HelpFormatter,
                          description="Make, check and repair the data the package ships (plans, reachability "
                                      "artifacts, learned intruders) and plan files of your own. What writes into "
                                      "the package (stp_env/data) does so only in a source checkout.")
    commands = data.add_subparsers(dest="data_command", required=True, metavar="COMMAND")
    for module in COMMANDS:
        module.add_parser(commands)

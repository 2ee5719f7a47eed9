"""``stp-env data``: maintenance of the data the package ships and of the plan files a user makes.

One module per subcommand, each with ``add_parser(sub)`` and ``run(args)`` (:mod:`stp_env.data_tools.cli` adds
them under ``data``): ``plans`` (:mod:`~stp_env.data_tools.plans`), ``check-plan``
(:mod:`~stp_env.data_tools.check_plan`), ``reconcile-controls`` (:mod:`~stp_env.data_tools.reconcile_controls`),
``convert-checkpoint`` (:mod:`~stp_env.data_tools.convert_checkpoint`), ``artifacts``
(:mod:`~stp_env.data_tools.ship_artifacts`) and ``ship-intruder`` (:mod:`~stp_env.data_tools.ship_intruder`).
Building their parsers, and ``--help``, import no JAX. What writes the package's own data (``stp_env/data/``:
``plans --ship``, ``artifacts``, ``ship-intruder`` without ``--out``, ``reconcile-controls`` of a shipped plan) does
so only in a source checkout (:func:`stp_env.data_tools.shipping.checkout_data`); an installed package is never
rewritten.
"""


def description(doc: str) -> str:
    """A subcommand's ``--help`` description: the first paragraph of its module docstring, without the leading
    command name and the reStructuredText quotes."""
    first = " ".join(doc.split("\n\n")[0].split())
    if first.startswith("``stp-env data"):
        first = first.split(": ", 1)[1]
    first = first.replace("``", "")
    return first[:1].upper() + first[1:]

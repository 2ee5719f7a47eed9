"""Where the package's own data lies (``stp_env/data/``; the artifacts' folder is
:data:`stp_env.artifacts.SHIPPED_DIR`), and the one check before a data tool writes there: the package must run from
a source checkout (a ``pyproject.toml`` beside it), never from an installation, whose files belong to the
installer."""

from __future__ import annotations

from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1]
DATA = PACKAGE / "data"
PLANS = DATA / "plans"
INTRUDERS = DATA / "intruders"


def is_checkout(package: Path = PACKAGE) -> bool:
    """Whether ``package`` is the ``stp_env`` folder of a source checkout (an editable install included)."""
    return (package.parent / "pyproject.toml").is_file()


def checkout_data(folder: Path, what: str, instead: str = "") -> Path:
    """``folder`` (a folder of ``stp_env/data``) when the package runs from a source checkout, else a one-line
    ``ValueError`` saying that ``what`` writes the package's own data (and, with ``instead``, what to do)."""
    if not is_checkout():
        raise ValueError(f"{what} writes the package's own data ({folder}), which only a source checkout of stp-env "
                         f"may change; this one is installed in {PACKAGE.parent}" + (f" ({instead})" if instead else "")
                         + ".")
    return folder

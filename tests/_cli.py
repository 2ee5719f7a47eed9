"""Running the ``stp-env`` command in-process, as the CLI tests do."""

from __future__ import annotations

import contextlib
import io

from stp_env import cli


def run_cli(argv):
    """``(exit code, stdout, stderr)`` of ``stp-env argv`` (argparse's ``SystemExit`` becomes the code)."""
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            code = cli.main(argv)
        except SystemExit as exc:  # argparse errors
            code = exc.code
    return code, out.getvalue(), err.getvalue()

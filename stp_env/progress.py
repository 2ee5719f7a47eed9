"""Progress on the terminal: no silent wait longer than a couple of seconds.

Long steps (computing a reachability artifact, compiling a simulator program, drawing figures, rendering frames)
either show a ``tqdm`` bar or print one line to standard error before they start (``stp-env: compiling ...``).

Whether they do: ``progress=True`` / ``False`` where a function takes it; ``None`` (the default of the library's
entry points, e.g. :func:`stp_env.parallel_env`) follows ``$STP_ENV_PROGRESS`` (``1`` / ``0``) if set, else shows
progress only when standard error is a terminal (so logs and pipes stay clean).
"""

from __future__ import annotations

import contextlib
import os
import sys
import time

ENV_VAR = "STP_ENV_PROGRESS"
_OFF = {"0", "off", "false", "no"}


def enabled(progress: bool | None = None) -> bool:
    """Whether to show progress: ``progress`` itself when given, else ``$STP_ENV_PROGRESS``, else whether standard
    error is a terminal."""
    if progress is not None:
        return bool(progress)
    value = os.environ.get(ENV_VAR, "").strip().lower()
    if value:
        return value not in _OFF
    try:
        return sys.stderr.isatty()
    except (AttributeError, ValueError):  # replaced or closed stream
        return False


def note(message: str, progress: bool | None = None) -> None:
    """``stp-env: <message>`` on standard error when :func:`enabled`."""
    if enabled(progress):
        print(f"stp-env: {message}", file=sys.stderr, flush=True)


@contextlib.contextmanager
def phase(message: str, progress: bool | None = None, *, report_after_s: float = 2.0):
    """A step announced before it starts (``stp-env: <message>...``) and, when it took longer than
    ``report_after_s``, timed when it ends."""
    on = enabled(progress)
    if on:
        print(f"stp-env: {message}...", file=sys.stderr, flush=True)
    start = time.perf_counter()
    yield
    seconds = time.perf_counter() - start
    if on and seconds > report_after_s:
        print(f"stp-env: {message}: done in {seconds:.1f} s", file=sys.stderr, flush=True)


_COMPILED: set = set()


def compile_note(what: str, *args, progress: bool | None = None) -> None:
    """Announce the compilation of the program ``what`` for arguments of the shapes of ``args`` (pytrees), the
    first time this process meets those shapes: the call that follows compiles it, or loads it from the persistent
    compilation cache (:mod:`stp_env.compilation_cache`)."""
    if not enabled(progress):
        return
    import jax

    leaves, treedef = jax.tree.flatten(args)
    key = (what, treedef, tuple((getattr(x, "shape", None), str(getattr(x, "dtype", type(x)))) for x in leaves))
    if key not in _COMPILED:
        _COMPILED.add(key)
        note(f"compiling {what} (once per machine: later processes load it from the compilation cache)...", True)


def compiling_until_first_update(bar, label: str = "compiling (once per machine)...") -> None:
    """Show ``label`` on a ``tqdm`` ``bar`` until its first ``update``: the first batch of a jitted loop compiles
    its program, so the bar says why it stands at 0."""
    if bar is None or getattr(bar, "disable", False):
        return
    bar.set_postfix_str(label, refresh=True)
    update = bar.update

    def first_update(n=1):
        bar.update = update
        bar.set_postfix_str("", refresh=False)
        return update(n)

    bar.update = first_update


def command_started(command: str, enabled_: bool | None = None) -> None:
    """The first line of a long-running ``stp-env`` command, before it loads anything: what may take long (with
    ``enabled_=None``: in a terminal, or with ``$STP_ENV_PROGRESS=1``; a log or a pipe gets the bars and the
    command's own output only)."""
    note(f"{command}: started (reachability artifacts are computed on first use and cached; programs compile once "
         "per machine)", enabled_)

"""The ``pgd`` console script: the lean ``pgd query`` first, else the click command line.

A plain ``pgd query`` runs in :mod:`pgdcli.cli.query` (numpy and h5py only, no click); everything
else, and any query that fails or asks for help, runs through click (:mod:`pgdcli.cli.main`), which
is imported only then.
"""

from __future__ import annotations

import sys
import warnings

from . import guard
from .main import cli
from .query import one_line_error, run

__all__ = ["main"]


def _one_line_warning(message, category, filename, lineno, file=None, line=None) -> None:
    text = guard.one_line(message)
    try:
        sys.stderr.write(f"Warning: {text}\n")
    except OSError:
        pass


def main(argv=None) -> None:
    """Console-script entry point: the lean ``pgd query``, else the click command line."""
    # a warning (an inaccurate codebook loaded) is one 'Warning:' line, not Python's file:line format
    warnings.showwarning = _one_line_warning
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        code = run(args)
    except KeyboardInterrupt:
        sys.stderr.write("Error: interrupted\n")
        sys.exit(guard.EXIT_INTERRUPTED)
    except MemoryError:
        one_line_error("out of memory while evaluating the codebook; see the limits in the documentation")
        sys.exit(guard.EXIT_USAGE)
    except Exception as exc:  # noqa: BLE001 - the guard of the lean path (output had begun)
        if guard.debug_enabled():
            raise
        one_line_error(guard.internal_error_message(exc))
        sys.exit(guard.EXIT_INTERNAL)
    if code is not None:
        sys.exit(code)
    cli.main(args=argv, prog_name="pgd")

"""The ``pgd`` command group: a thin layer over the library.

Each command parses its options, calls one library function and formats the
result. stdout carries data only; progress, tables and messages go to stderr.
Exit status: 0 success, 1 a numerical outcome the user asked to be told
about (solver not converged, verification gate failed), 2 invalid input
(one ``Error:`` line, no traceback), 70 an internal error (a bug: one line,
the traceback with ``--debug``); see :mod:`pgdcli.cli.guard`.

This module holds the click group and the guard every command runs in; the commands are
in one module each (``*_command.py``), registered by :mod:`pgdcli.cli.main`. Only the
``cli`` package imports click and rich; rich is imported only by the commands that draw
with it, and a plain ``pgd query`` never imports this module (:mod:`pgdcli.cli.entry`).
"""

from __future__ import annotations

import sys
import traceback

import click

from .. import __version__
from ..errors import PgdError
from . import guard
from .guard import EXIT_FAILED, EXIT_INTERNAL, EXIT_INTERRUPTED, EXIT_OK, EXIT_USAGE


# ----------------------------------------------------------------------------------------------
# one-line errors for every usage problem
# ----------------------------------------------------------------------------------------------
class PgdGroup(click.Group):
    """A click group that runs every command inside the guard of :mod:`pgdcli.cli.guard`.

    Usage errors and :class:`PgdError` are one ``Error:`` line on stderr (exit 2);
    anything unexpected is one ``Error: internal error: ...`` line (exit 70, the
    traceback with ``--debug`` or ``PGD_DEBUG=1``); a reader gone away ends the
    command quietly (exit 0) and a full disk is one line (exit 2). Never a traceback.
    """

    def resolve_command(self, ctx, args):
        name, command, rest = super().resolve_command(ctx, args)
        guard.set_activity(f"running 'pgd {name}'")
        return name, command, rest

    def invoke(self, ctx):
        try:
            return super().invoke(ctx)
        except KeyboardInterrupt:
            raise Interrupted() from None

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        try:
            code = super().main(args=args, prog_name=prog_name or "pgd", complete_var=complete_var,
                                standalone_mode=False, **extra)
            code = _flushed(code)
        except click.exceptions.NoArgsIsHelpError as exc:  # bare `pgd`: show the help
            click.echo(exc.ctx.get_help() if exc.ctx else "")
            code = EXIT_OK
        except click.UsageError as exc:
            hint = f" (see '{exc.ctx.command_path} --help')" if exc.ctx is not None else ""
            error(exc.format_message() + hint)
            code = EXIT_USAGE
        except PgdError as exc:
            error(str(exc))
            code = EXIT_USAGE
        except click.ClickException as exc:
            error(exc.format_message())
            code = exc.exit_code
        except (Interrupted, KeyboardInterrupt):
            error("interrupted")
            code = EXIT_INTERRUPTED
        except click.Abort as exc:
            interrupted = isinstance(exc.__context__, KeyboardInterrupt)
            error("interrupted" if interrupted else "aborted")
            code = EXIT_INTERRUPTED if interrupted else EXIT_FAILED
        except MemoryError:
            guard.silence_stdout()
            error(f"out of memory while {guard.activity()}; see the limits in the documentation "
                  f"(PGD_MAX_WORK_BYTES and others) or use a machine with more memory")
            code = EXIT_USAGE
        except Failed as exc:
            code = _flushed(EXIT_FAILED)
            if code != EXIT_USAGE:  # a full disk was reported instead; a reader gone away is no excuse
                (warn if exc.warning else error)(str(exc))
                code = EXIT_FAILED
        except BrokenPipeError:
            code = _flushed(EXIT_OK, broken=True)
        except Exception as exc:  # noqa: BLE001 - the guard: nothing escapes as a traceback
            code = _unexpected(exc)
        if not isinstance(code, int):
            code = EXIT_OK
        if guard.flush_stdout() is not None:  # after an error: no second report, no failing flush at exit
            guard.silence_stdout()
        if standalone_mode:
            sys.exit(code)
        return code


class Interrupted(Exception):
    """Ctrl-C inside a command: carried past click, which would make it ``Abort`` (exit 1)."""


def _flushed(code, broken: bool = False):
    """Flush stdout inside the guard: a reader gone away ends quietly (exit 0), a full disk is one line."""
    exc = None if broken else guard.flush_stdout()
    if broken or isinstance(exc, BrokenPipeError):
        # a pipeline reader went away (e.g. `pgd query ... | head`): not an error
        guard.silence_stdout()
        return EXIT_OK
    if exc is not None:
        guard.silence_stdout()
        error(guard.output_error_message(exc, "to stdout"))
        return EXIT_USAGE
    return code


def _unexpected(exc: Exception) -> int:
    """An exception nobody meant to raise: a full disk (exit 2) or a bug (exit 70)."""
    if guard.is_output_error(exc):
        guard.silence_stdout()
        error(guard.output_error_message(exc, getattr(exc, "filename", None) or "to stdout"))
        return EXIT_USAGE
    if guard.debug_enabled():
        traceback.print_exception(type(exc), exc, exc.__traceback__, file=sys.stderr)
    error(guard.internal_error_message(exc))
    return EXIT_INTERNAL


def warn(message: str) -> None:
    click.echo(f"Warning: {guard.one_line(message)}", err=True)


def error(message: str) -> None:
    click.echo(f"Error: {guard.one_line(message)}", err=True)


class Failed(Exception):
    """A numerical outcome that ends a command with exit status 1 and a one-line reason.

    ``Failed(reason)`` prints ``Error: reason``; ``Failed(reason, warning=True)`` prints
    ``Warning: reason`` (the command's output stands, but it is not to be trusted as such).
    """

    def __init__(self, message: str, *, warning: bool = False):
        super().__init__(message)
        self.warning = warning


def format_option(formats):
    """The ``--format`` option of a command: its choices, default and help from its registry
    (:mod:`pgdcli.cli.formats`)."""
    return click.option("--format", "fmt", type=click.Choice(formats.names), default=formats.default,
                        show_default=True, help=formats.help())


def run_command(func, *args, **kwargs):
    """``func(*args, **kwargs)``; a :class:`Failed` it raises ends the command with exit 1 (in the group)."""
    return func(*args, **kwargs)


@click.group(cls=PgdGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(__version__, "-V", "--version", prog_name="pgd", message="%(prog)s %(version)s")
@click.option("--debug", is_flag=True, expose_value=False, is_eager=True,
              callback=lambda ctx, param, value: guard.set_debug(True) if value else None,
              help="Show the traceback of an internal error (also PGD_DEBUG=1).")
def cli():
    """PGD codebooks for parametric dynamical systems.

    Solve a YAML problem spec once, offline, into a codebook (HDF5) holding the
    separated solution u(t, p1, ..., pd) = sum_i alpha_i T_i(t) P_i1(p1)...P_id(pd);
    then query it anywhere in its domain in microseconds.

    \b
      pgd solve problems/parametric.yaml
      pgd query codebooks/parametric.h5 --t 5 --k 2
      pgd info codebooks/parametric.h5

    Exit status: 0 success, 1 solver not converged or a check failed,
    2 invalid input or usage (or a full disk), 70 internal error (a bug;
    --debug shows the traceback). stdout carries data only; progress and
    messages go to stderr.
    """


def stderr_console():
    from rich.console import Console

    return Console(stderr=True, highlight=False)

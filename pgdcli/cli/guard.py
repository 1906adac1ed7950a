"""Exit statuses and the one guard every ``pgd`` command runs inside.

No traceback ever reaches a user by accident: an exception nobody meant to
raise becomes one ``Error: internal error: ...`` line and its own exit status,
so a script can tell a crash from a failed check (1) or bad input (2). A reader
that goes away (``pgd query ... | head``) and a full disk are reported as such.

Imports only the standard library: the lean ``pgd query`` path uses it.
"""

from __future__ import annotations

import errno
import os
import sys

from ..names import printable

__all__ = ["one_line", "EXIT_OK", "EXIT_FAILED", "EXIT_USAGE", "EXIT_INTERNAL", "EXIT_INTERRUPTED", "debug_enabled",
           "set_debug", "set_activity", "activity", "internal_error_message", "output_error_message", "is_output_error", "silence_stdout",
           "flush_stdout"]

EXIT_OK = 0
EXIT_FAILED = 1  # a numerical outcome the user asked about: not converged, a verification gate failed
EXIT_USAGE = 2  # invalid input or usage; also an output that cannot be written (full disk)
EXIT_INTERNAL = 70  # a bug in pgdcli (BSD's EX_SOFTWARE): an exception nobody meant to raise
EXIT_INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)

# errors of writing data that are the disk's or the device's, not ours
_OUTPUT_ERRNOS = frozenset(getattr(errno, name) for name in ("ENOSPC", "EDQUOT", "EFBIG", "EIO", "EROFS")
                           if hasattr(errno, name))

_debug = False


_activity = ["running pgd"]


def set_activity(text: str) -> None:
    """Say what the command is doing, for a one-line report of running out of memory."""
    _activity[0] = text


def activity() -> str:
    """What the command said it is doing (``solving problems/x.yaml``)."""
    return _activity[0]


def set_debug(on: bool = True) -> None:
    """Show tracebacks of internal errors (``pgd --debug``)."""
    global _debug
    _debug = bool(on)


def debug_enabled() -> bool:
    """``pgd --debug`` was given or ``PGD_DEBUG`` is set to something other than ``""``/``0``."""
    return _debug or os.environ.get("PGD_DEBUG", "") not in ("", "0")


def one_line(message) -> str:
    """A message on one line, safe for a terminal: whitespace runs joined, control characters escaped."""
    return printable(" ".join(str(message).split()), 2000)


def _first_line(text: str, limit: int = 300) -> str:
    """``text`` on one line, at most ``limit`` characters (never more is built)."""
    text = " ".join(str(text)[: limit + 1].split())
    return text if len(text) <= limit else text[: limit - 3] + "..."


def internal_error_message(exc: BaseException) -> str:
    """The one line for an unexpected exception (without the ``Error:`` prefix)."""
    return (f"internal error: {type(exc).__name__}: {_first_line(exc)}; please report it with the spec "
            f"(run with --debug or PGD_DEBUG=1 for the traceback)")


def is_output_error(exc: BaseException) -> bool:
    """An OSError of the disk or device (full, read-only, quota, I/O error)."""
    return isinstance(exc, OSError) and exc.errno in _OUTPUT_ERRNOS


def output_error_message(exc: OSError, what: str = "the output") -> str:
    """``cannot write <what>: No space left on device`` (one line)."""
    reason = exc.strerror or _first_line(exc)
    return f"cannot write {what}: {reason}"


def silence_stdout() -> None:
    """Point the stdout file descriptor at /dev/null.

    After a broken pipe or a full disk the interpreter's last flush of
    ``sys.stdout`` would raise again (``Exception ignored ...`` on stderr and
    exit status 120); writing to /dev/null instead always succeeds.
    """
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real stdout (tests): nothing to silence
        pass


def flush_stdout() -> BaseException | None:
    """Flush ``sys.stdout`` now (not at exit, where an error is no longer ours to report).

    Returns the ``BrokenPipeError`` or disk ``OSError`` raised, else None.
    """
    try:
        sys.stdout.flush()
    except BrokenPipeError as exc:
        return exc
    except OSError as exc:
        if is_output_error(exc):
            return exc
        raise
    except ValueError:  # stdout already closed
        return None
    return None

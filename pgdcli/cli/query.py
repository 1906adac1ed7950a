"""``pgd query`` without click: argument parsing and the lean command.

``pgd query`` is called in loops, so its start-up time is part of its cost.
This module does what the click command :func:`pgdcli.cli.query_command.query` does, with
the same helpers (defined here and in :mod:`pgdcli.cli.stream`, used by both), but
imports only numpy and :mod:`pgdcli.codebook.codebook` (h5py when the codebook is read);
csv and json only when needed. No click, no rich, no scipy.

:func:`run` handles the plain invocations. Anything else -- ``--help``, a
malformed option, any error found before the first chunk of output -- makes it
return ``None`` having printed nothing, so that the click command runs instead
and does the reporting (stdin read so far is handed to click unchanged). What
is printed, for success and for failure, is byte for byte what the click
command prints (checked by ``tests/cli/test_query_fastpath.py``); an error after
output has begun is reported here with the same bytes.
"""

from __future__ import annotations

import io
import os
import sys

from ..errors import PgdError, QueryError
from . import guard
from . import stream  # registers the query's output formats
from .formats import QUERY
from .guard import one_line
from .stream import check_grid_size

__all__ = ["run", "UsageProblem", "one_line_error", "EventView"]

_VALUE_OPTIONS = ("--format", "--field", "--points")
_CLICK_ONLY = ("--output", "--scheduler", "--workers", "--event")  # into a file, on a cluster, events: click


class UsageProblem(Exception):
    """A usage error of ``pgd query``; the click command raises it as ``click.BadParameter``
    (with ``param_hint``) or ``click.UsageError``."""

    def __init__(self, message: str, param_hint: str | None = None):
        super().__init__(message)
        self.message = message
        self.param_hint = param_hint


class EventView:
    """A codebook's events seen as a codebook: its coordinates but time, the event times as its unknowns.

    ``pgd query --event NAME`` prints through the query's own parsing and writers with it.
    """

    def __init__(self, cb, events: list[str]):
        if not cb.events:
            raise QueryError("this codebook records no events (add an 'events:' section to the spec)")
        for e in events:
            if e not in cb.events:
                raise UsageProblem(f"unknown event {e!r}; this codebook has {', '.join(cb.events)}",
                                   param_hint="'--event'")
        self.cb = cb
        self.coordinates = [c for c in cb.coordinates if c.role != "time"]
        self.coordinate_names = [c.name for c in self.coordinates]
        self.unknown_names = list(cb.events)

    def evaluate(self, coordinates, fields=None):
        return self.cb.event_times(coordinates, fields)


# ----------------------------------------------------------------------------------------------
# helpers shared with the click command
# ----------------------------------------------------------------------------------------------
def describe(c) -> str:
    return f"{c.name} in [{c.domain[0]:g}, {c.domain[1]:g}]"


def parse_coordinate_args(args: list[str], cb) -> dict[str, str]:
    """``--NAME VALUE`` / ``--NAME=VALUE`` pairs -> {name: text}, every coordinate exactly once."""
    given: dict[str, str] = {}
    i = 0
    names = cb.coordinate_names
    while i < len(args):
        arg = args[i]
        if not arg.startswith("--") or len(arg) == 2:
            raise UsageProblem(f"unexpected argument {arg!r}; coordinates are given as --NAME VALUE "
                               f"({' '.join('--' + n for n in names)})")
        name, eq, value = arg[2:].partition("=")
        if not eq:
            if i + 1 >= len(args):
                raise UsageProblem(f"option '--{name}' needs a value")
            value = args[i + 1]
            i += 1
        i += 1
        if name not in names:
            raise QueryError(f"unknown coordinate '--{name}'; this codebook has "
                             f"{', '.join(describe(c) for c in cb.coordinates)}")
        if name in given:
            raise UsageProblem(f"coordinate '--{name}' given twice")
        given[name] = value
    missing = [c for c in cb.coordinates if c.name not in given]
    if missing:
        raise QueryError("missing coordinate " + ", ".join(f"'--{c.name}' ({describe(c)})" for c in missing))
    return given


def parse_values(name: str, text: str):
    """A number, a comma list or ``start:stop:count`` -> 1-D float array.

    A count is checked against :func:`pgdcli.cli.stream.max_points` before
    anything is allocated (``0:1:1000000000000`` is refused, not attempted).
    """
    import numpy as np

    text = text.strip()
    try:
        if ":" in text:
            parts = text.split(":")
            if len(parts) != 3:
                raise ValueError
            start, stop, count = float(parts[0]), float(parts[1]), int(parts[2])
            if count < 1:
                raise ValueError
            check_grid_size([(name, count)])
            return np.linspace(start, stop, count)
        return np.array([float(v) for v in text.split(",")], dtype=float)
    except ValueError:
        shown = text if len(text) <= 60 else text[:57] + "..."
        raise UsageProblem(f"{shown!r} is not a number, a comma list or start:stop:count",
                           param_hint=f"'--{name}'") from None


def grid_axes(args: list[str], cb) -> list:
    """The coordinates' values (1-D arrays, codebook order), checked: domain, and the grid's size."""
    given = parse_coordinate_args(args, cb)
    lists = [parse_values(c.name, given[c.name]) for c in cb.coordinates]
    for c, v in zip(cb.coordinates, lists):
        check_domain(c, v)
    check_grid_size([(c.name, v.size) for c, v in zip(cb.coordinates, lists)])
    return lists


def check_domain(c, values) -> None:
    import numpy as np

    finite = np.isfinite(values)
    if not finite.all():  # as a points file's cell: not a number, not a value outside the domain
        raise QueryError(f"coordinate '--{c.name}': {float(values[~finite][0])!r} is not a finite number")
    bad = (values < c.domain[0]) | (values > c.domain[1])
    if bad.any():
        raise QueryError(f"coordinate '--{c.name}': value {float(values[bad][0])!r} is outside the domain "
                         f"[{c.domain[0]:g}, {c.domain[1]:g}]")


def open_points(path: str):
    """``--points`` FILE -> (binary handle, name for messages); ``-`` is stdin."""
    if path == "-":
        return getattr(sys.stdin, "buffer", sys.stdin), "stdin"
    try:
        return open(path, "rb"), path
    except FileNotFoundError:
        raise QueryError(f"--points {path}: no such file") from None
    except IsADirectoryError:
        raise QueryError(f"--points {path}: is a directory, expected a CSV file") from None
    except OSError as exc:
        raise QueryError(f"--points {path}: cannot read ({exc.strerror or exc})") from None


# ----------------------------------------------------------------------------------------------
# the lean command
# ----------------------------------------------------------------------------------------------
class _Recorder:
    """stdin (binary) that keeps what it hands out, until :meth:`stop`: if the lean path gives up
    before printing anything, click gets the same input again (:meth:`replayed`)."""

    def __init__(self, raw, owner=None):
        # owner: the text stdin around ``raw``, kept alive (its finalizer would close ``raw``)
        self.raw, self.owner, self.kept, self.recording = raw, owner, [], True

    def readline(self, size: int = -1) -> bytes:
        line = self.raw.readline(size)
        if self.recording:
            self.kept.append(line)
        return line

    def stop(self) -> None:
        self.recording, self.kept = False, []

    def replayed(self):
        """A text stdin that reads the kept bytes, then the rest of the real stdin."""
        kept, raw, owner = b"".join(self.kept), self.raw, self.owner

        class Raw(io.RawIOBase):
            stdin = owner
            def readable(self):
                return True

            def readinto(self, buffer):
                nonlocal kept
                if kept:
                    n = min(len(buffer), len(kept))
                    buffer[:n], kept = kept[:n], kept[n:]
                    return n
                data = raw.read1(len(buffer)) if hasattr(raw, "read1") else raw.read(len(buffer))
                buffer[:len(data)] = data
                return len(data)

        return io.TextIOWrapper(io.BufferedReader(Raw()), encoding="utf-8")


def point_chunks(cb, points: str | None, rest: list[str], stdin=None):
    """The points of a query, in chunks (:mod:`pgdcli.cli.stream`), and a file handle to close (or None).

    Grid arguments are parsed and checked (domain, size) here, before any output.
    """
    if points is None:
        return stream.grid_points(grid_axes(rest, cb)), None
    if points == "-" and stdin is not None:
        return stream.read_points(stdin, "stdin", cb), None
    handle, source = open_points(points)
    return stream.read_points(handle, source, cb), (handle if points != "-" else None)


def one_line_error(message: str) -> None:
    sys.stderr.write(f"Error: {one_line(message)}\n")


def _stream_rest(writer, chunks, text: str) -> int:
    """Print the evaluated first chunk and every other one; errors from here on are reported here,
    with the bytes the click command would print (the output has begun: no falling back)."""
    try:
        writer.write(text)
        for chunk in chunks:
            writer.write(writer.text(chunk))
        writer.finish()
    except PgdError as exc:
        error = guard.flush_stdout()
        if error is None:
            one_line_error(str(exc))
            return guard.EXIT_USAGE
        exc = error
    except BrokenPipeError as exc_:
        exc = exc_
    except OSError as exc_:
        if not guard.is_output_error(exc_):
            raise
        exc = exc_
    else:
        exc = guard.flush_stdout()
        if exc is None:
            return guard.EXIT_OK
    guard.silence_stdout()
    if isinstance(exc, BrokenPipeError):
        # a pipeline reader went away (e.g. `pgd query ... | head`): not an error
        return guard.EXIT_OK
    one_line_error(guard.output_error_message(exc, "to stdout"))
    return guard.EXIT_USAGE


def _split(args: list[str]):
    """Tokens after ``query`` -> (codebook, format, fields, points, coordinate args), as click splits
    them for the query command (its options anywhere, every other token left in order, the first of
    which is CODEBOOK); None for what only click should handle (help, ``--``, a bad option)."""
    fmt, fields, points, rest = "plain", [], None, []
    i = 0
    while i < len(args):
        arg = args[i]
        i += 1
        if arg in ("--help", "--") or arg.partition("=")[0] in _CLICK_ONLY:
            return None
        if arg.startswith("--"):
            name, eq, value = arg.partition("=")
            if name in _VALUE_OPTIONS:
                if not eq:
                    if i >= len(args):
                        return None
                    value = args[i]
                    i += 1
                if name == "--format":
                    if value not in QUERY.names:
                        return None
                    fmt = value
                elif name == "--field":
                    fields.append(value)
                else:
                    points = value
                continue
        elif arg.startswith("-") and len(arg) > 1 and "h" in arg:
            return None  # click reads -h (help) in a cluster of short options
        rest.append(arg)
    if not rest or rest[0].startswith("-"):
        return None
    return rest[0], fmt, fields, points, rest[1:]


def run(argv: list[str]) -> int | None:
    """Run ``pgd ARGV`` if it is a plain ``query`` invocation; return its exit status.

    Returns None, having printed nothing, when click should run the command
    instead: anything but ``query``, help, an unusual option, any error found
    before the first chunk of output (click then reports it).
    """
    if len(argv) < 2 or argv[0] != "query" or "_PGD_COMPLETE" in os.environ:
        return None
    split = _split(argv[1:])
    if split is None:
        return None
    codebook, fmt, fields, points, rest = split
    recorder = handle = None
    try:
        from ..codebook.codebook import Codebook

        if os.path.isdir(codebook):
            return None
        cb = Codebook.load(codebook, evaluation_only=True)
        selected = list(fields) if fields else cb.unknown_names
        if any(f not in cb.fields for f in selected) or (points is not None and rest):
            return None
        if getattr(cb, "action", None) == "terminal":  # points after its event: click's path tells
            return None
        if points == "-":
            recorder = _Recorder(getattr(sys.stdin, "buffer", None) or sys.stdin, sys.stdin)
        chunks, handle = point_chunks(cb, points, rest, stdin=recorder)
        writer = stream.Writer(sys.stdout, fmt, cb, selected)
        first = next(chunks, None)
        text = "" if first is None else writer.text(first)
    except KeyboardInterrupt:
        raise
    except Exception:
        if handle is not None:
            handle.close()
        if recorder is not None:  # click reads the same input again
            sys.stdin = recorder.replayed()
        return None
    if recorder is not None:
        recorder.stop()
    try:
        return _stream_rest(writer, chunks, text)
    finally:
        if handle is not None:
            handle.close()

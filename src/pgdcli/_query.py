"""``pgd query`` without click: argument parsing, evaluation and output.

``pgd query`` is called in loops, so its start-up time is part of its cost.
This module does what the click command :func:`pgdcli.cli.query` does, with
the same helpers (defined here, used by both), but imports only numpy and
:mod:`pgdcli.codebook` (h5py when the codebook is read); json and csv only for
``--format json`` and ``--points``. No click, no rich, no scipy.

:func:`run` handles the plain invocations and returns ``None`` for anything
else -- ``--help``, a malformed option, any error at all -- so that the click
command runs instead and does the reporting: what is printed, for success and
for failure, is byte for byte what the click command prints (checked by
``tests/test_query_fastpath.py``).
"""

from __future__ import annotations

import io
import os
import sys

from .errors import QueryError

__all__ = ["run", "main", "UsageProblem"]

FORMATS = ("plain", "csv", "json")
_VALUE_OPTIONS = ("--format", "--field", "--points")


class UsageProblem(Exception):
    """A usage error of ``pgd query``; the click command raises it as ``click.BadParameter``
    (with ``param_hint``) or ``click.UsageError``."""

    def __init__(self, message: str, param_hint: str | None = None):
        super().__init__(message)
        self.message = message
        self.param_hint = param_hint


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
    """A number, a comma list or ``start:stop:count`` -> 1-D float array."""
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
            return np.linspace(start, stop, count)
        return np.array([float(v) for v in text.split(",")], dtype=float)
    except ValueError:
        raise UsageProblem(f"{text!r} is not a number, a comma list or start:stop:count",
                           param_hint=f"'--{name}'") from None


def grid_from_args(args: list[str], cb) -> dict:
    """The cartesian product of the coordinates' values, flat (first coordinate slowest)."""
    import numpy as np

    given = parse_coordinate_args(args, cb)
    lists = [parse_values(c.name, given[c.name]) for c in cb.coordinates]
    for c, v in zip(cb.coordinates, lists):
        check_domain(c, v)
    grids = np.meshgrid(*lists, indexing="ij")
    return {c.name: g.reshape(-1) for c, g in zip(cb.coordinates, grids)}


def check_domain(c, values) -> None:
    import numpy as np

    bad = ~np.isfinite(values) | (values < c.domain[0]) | (values > c.domain[1])
    if bad.any():
        raise QueryError(f"coordinate '--{c.name}': value {float(values[bad][0])!r} is outside the domain "
                         f"[{c.domain[0]:g}, {c.domain[1]:g}]")


def read_points(handle, cb) -> dict:
    """A CSV whose header names the coordinates -> {name: 1-D array}, one entry per data row."""
    import csv

    import numpy as np

    source = getattr(handle, "name", "points")
    source = "stdin" if source == "<stdin>" else source
    reader = csv.reader(handle)
    header = next(reader, None)
    if header is None:
        raise QueryError(f"{source}: empty points file; expected a CSV header naming the coordinates")
    header = [h.strip() for h in header]
    names = cb.coordinate_names
    for h in header:
        if h not in names:
            raise QueryError(f"{source}: unknown column {h!r}; expected the coordinates {', '.join(names)}")
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise QueryError(f"{source}: column(s) {', '.join(repeated)} appear more than once in the header")
    missing = [n for n in names if n not in header]
    if missing:
        raise QueryError(f"{source}: missing column(s) {', '.join(missing)}")
    rows = []
    for line, row in enumerate(reader, start=2):
        if not row or all(not cell.strip() for cell in row):
            continue
        if len(row) != len(header):
            raise QueryError(f"{source}: line {line}: expected {len(header)} values, got {len(row)}")
        try:
            rows.append([float(cell) for cell in row])
        except ValueError:
            raise QueryError(f"{source}: line {line}: not a number in {','.join(row)!r}") from None
    data = np.array(rows, dtype=float).reshape(-1, len(header))
    coords = {h: data[:, i] for i, h in enumerate(header)}
    for c in cb.coordinates:
        check_domain(c, coords[c.name])
    return {n: coords[n] for n in names}


def format_rows(fmt, coord_names, coords, selected, values) -> str:
    """The output text: one line per point (plain, csv) or a JSON list of objects."""
    import numpy as np

    cols = [np.asarray(values[f]).reshape(-1).tolist() for f in selected]
    buf = io.StringIO()
    if fmt == "plain":
        for row in zip(*cols):
            buf.write(" ".join(map(repr, row)))
            buf.write("\n")
        return buf.getvalue()
    ccols = [np.asarray(coords[c]).reshape(-1).tolist() for c in coord_names]
    if fmt == "csv":
        buf.write(",".join(coord_names + selected) + "\n")
        for row in zip(*ccols, *cols):
            buf.write(",".join(map(repr, row)))
            buf.write("\n")
    else:
        import json

        keys = coord_names + selected
        records = [dict(zip(keys, row)) for row in zip(*ccols, *cols)]
        buf.write(json.dumps(records))
        buf.write("\n")
    return buf.getvalue()


def write_rows(out, fmt, coord_names, coords, selected, values) -> None:
    out.write(format_rows(fmt, coord_names, coords, selected, values))
    out.flush()


# ----------------------------------------------------------------------------------------------
# the lean command
# ----------------------------------------------------------------------------------------------
class _Replay(io.StringIO):
    """stdin already read by :func:`run`, handed to click unchanged when it takes over."""

    name = "<stdin>"


def _split(args: list[str]):
    """Tokens after ``query`` -> (codebook, format, fields, points, coordinate args), as click splits
    them for the query command (its options anywhere, every other token left in order, the first of
    which is CODEBOOK); None for what only click should handle (help, ``--``, a bad option)."""
    fmt, fields, points, rest = "plain", [], None, []
    i = 0
    while i < len(args):
        arg = args[i]
        i += 1
        if arg in ("--help", "--"):
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
                    if value not in FORMATS:
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
    """Run ``pgd ARGV`` if it is a plain ``query`` invocation and succeeds; return its exit status.

    Returns None, having printed nothing, when click should run the command
    instead: anything but ``query``, help, an unusual option, any error.
    """
    if len(argv) < 2 or argv[0] != "query" or "_PGD_COMPLETE" in os.environ:
        return None
    split = _split(argv[1:])
    if split is None:
        return None
    codebook, fmt, fields, points, rest = split
    replay = None
    try:
        from .codebook import Codebook

        if os.path.isdir(codebook):
            return None
        cb = Codebook.load(codebook)
        selected = list(fields) if fields else cb.unknown_names
        if any(f not in cb.fields for f in selected):
            return None
        if points is not None:
            if rest:
                return None
            if points == "-":
                if (getattr(sys.stdin, "encoding", None) or "").lower().replace("-", "") != "utf8":
                    return None
                replay = _Replay(sys.stdin.read())
                coords = read_points(replay, cb)
            else:
                with open(points) as handle:
                    coords = read_points(handle, cb)
        else:
            coords = grid_from_args(rest, cb)
        values = cb.evaluate(coords, fields=selected)
        text = format_rows(fmt, cb.coordinate_names, coords, selected, values)
    except KeyboardInterrupt:
        raise
    except Exception:
        if replay is not None:  # click reads the same input again
            replay.seek(0)
            sys.stdin = replay
        return None
    try:
        sys.stdout.write(text)
        sys.stdout.flush()
    except BrokenPipeError:
        # a pipeline reader went away (e.g. `pgd query ... | head`): not an error (as the click group)
        sys.stderr.close()
    return 0


def main(argv=None) -> None:
    """Console-script entry point: the lean ``pgd query``, else the click command line."""
    args = sys.argv[1:] if argv is None else list(argv)
    try:
        code = run(args)
    except KeyboardInterrupt:
        sys.stderr.write("Error: interrupted\n")
        sys.exit(130)
    if code is not None:
        sys.exit(code)
    from .cli import cli

    cli.main(args=argv, prog_name="pgd")

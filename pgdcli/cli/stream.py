"""``pgd query`` output, point by point and chunk by chunk.

Two rules shape this module:

- **One point, one output.** Every point is evaluated by the same path, the
  one-point path of :meth:`Codebook.evaluate` (Python floats in), whether it
  was asked alone, in a list, in a range, from ``--points`` or with
  ``--field``. The batch path rounds differently (a BLAS matrix product's
  summation order depends on the batch's shape), so it is never used here.
- **Bounded memory.** Points are generated (grids) or read (``--points``) in
  chunks of :data:`CHUNK` and printed as they are evaluated; a grid larger
  than :func:`max_points` is refused with its size before anything is
  allocated, and a points file is never held in memory.

Imports numpy and the codebook's error types only (the lean query path).
"""

from __future__ import annotations

import csv
import json
import os

from ..errors import QueryError
from .formats import QUERY

__all__ = ["CHUNK", "DEFAULT_MAX_POINTS", "MAX_LINE_BYTES", "max_points", "check_grid_size", "grid_points",
           "read_points", "format_chunk", "closing", "Writer", "PlainRows", "CsvRows", "JsonRows"]

CHUNK = 4096  # points evaluated and printed at a time
DEFAULT_MAX_POINTS = 10_000_000  # a grid query's largest product of axes (PGD_QUERY_MAX_POINTS)
MAX_LINE_BYTES = 65536  # a points file's longest line


def max_points() -> int:
    """The largest grid ``pgd query`` evaluates: ``PGD_QUERY_MAX_POINTS`` or :data:`DEFAULT_MAX_POINTS`."""
    text = os.environ.get("PGD_QUERY_MAX_POINTS", "")
    try:
        value = int(text)
    except ValueError:
        return DEFAULT_MAX_POINTS
    return value if value >= 1 else DEFAULT_MAX_POINTS


def check_grid_size(counts: list[tuple[str, int]]) -> int:
    """The number of points of a grid with these axis lengths; QueryError above :func:`max_points`.

    Python integers: ``1e12 x 1e5`` is computed exactly, nothing is allocated.
    """
    limit = max_points()
    total = 1
    for _, n in counts:
        total *= n
    if total > limit:
        sizes = " x ".join(f"{n} ({name})" for name, n in counts)
        raise QueryError(f"the query asks for {total} points ({sizes}), more than the limit of {limit}; "
                         f"narrow the ranges, use --points FILE, or raise PGD_QUERY_MAX_POINTS")
    return total


def grid_points(axes: list):
    """Chunks of the cartesian product of ``axes`` (1-D arrays, first varying slowest).

    Yields lists of tuples of Python floats, :data:`CHUNK` points at a time.
    """
    import numpy as np

    shape = tuple(a.size for a in axes)
    total = int(np.prod(shape, dtype=np.int64)) if shape else 0
    for lo in range(0, total, CHUNK):
        index = np.unravel_index(np.arange(lo, min(lo + CHUNK, total)), shape)
        cols = [a[i].tolist() for a, i in zip(axes, index)]
        yield list(zip(*cols))


def _lines(handle, source: str):
    """``(line number, text)`` of a binary handle, each line checked for length and UTF-8."""
    number = 0
    while True:
        raw = handle.readline(MAX_LINE_BYTES + 1)
        if not raw:
            return
        number += 1
        if len(raw) > MAX_LINE_BYTES:
            raise QueryError(f"{source}: line {number}: longer than {MAX_LINE_BYTES} bytes")
        try:
            text = raw.decode("utf-8-sig" if number == 1 else "utf-8")
        except UnicodeDecodeError:
            raise QueryError(f"{source}: line {number}: not UTF-8 text (a CSV file of numbers is expected)") from None
        yield number, text


def _cells(text: str, source: str, number: int) -> list[str]:
    try:
        return next(csv.reader([text]), [])
    except csv.Error as exc:
        raise QueryError(f"{source}: line {number}: not a CSV row ({exc})") from None


def _header(lines, source: str, cb) -> tuple[list[int], int]:
    """The header -> (for each codebook coordinate its column index, the number of columns)."""
    for number, text in lines:
        header = [h.strip() for h in _cells(text, source, number)]
        break
    else:
        raise QueryError(f"{source}: empty points file; expected a CSV header naming the coordinates")
    names = cb.coordinate_names
    for h in header:
        if h not in names:
            shown = h if len(h) <= 40 else h[:37] + "..."
            raise QueryError(f"{source}: line 1: unknown column {shown!r}; expected the coordinates {', '.join(names)}")
    repeated = sorted({h for h in header if header.count(h) > 1})
    if repeated:
        raise QueryError(f"{source}: column(s) {', '.join(repeated)} appear more than once in the header")
    missing = [n for n in names if n not in header]
    if missing:
        raise QueryError(f"{source}: missing column(s) {', '.join(missing)}")
    return [header.index(n) for n in names], len(header)


def read_points(handle, source: str, cb):
    """Chunks of the points of a CSV file (binary ``handle``), checked row by row.

    The header names the coordinates (any order); each data row gives one
    point, in codebook coordinate order. Blank lines are skipped (and counted
    in line numbers). Every error names ``source`` and the line: a row of the
    wrong length, a cell that is not a number, a NaN or infinity, a value
    outside the coordinate's domain, bytes that are not UTF-8.

    Yields lists of tuples of Python floats, :data:`CHUNK` points at a time.
    """
    lines = _lines(handle, source)
    columns, width = _header(lines, source, cb)
    coords = cb.coordinates
    chunk = []
    for number, text in lines:
        if not text.strip():
            continue
        row = _cells(text, source, number)
        if len(row) != width:
            raise QueryError(f"{source}: line {number}: expected {width} values, got {len(row)}")
        point = []
        for c, j in zip(coords, columns):
            try:
                x = float(row[j])
            except ValueError:
                cell = row[j] if len(row[j]) <= 40 else row[j][:37] + "..."
                raise QueryError(f"{source}: line {number}: column {c.name!r}: not a number: {cell!r}") from None
            if x != x or x in (float("inf"), float("-inf")):
                raise QueryError(f"{source}: line {number}: column {c.name!r}: {row[j].strip()!r} is not "
                                 f"a finite number")
            if not (c.domain[0] <= x <= c.domain[1]):
                raise QueryError(f"{source}: line {number}: column {c.name!r}: value {x!r} is outside "
                                 f"the domain [{c.domain[0]:g}, {c.domain[1]:g}]")
            point.append(x)
        chunk.append(tuple(point))
        if len(chunk) == CHUNK:
            yield chunk
            chunk = []
    if chunk:
        yield chunk


def _values(cb, names: list[str], selected: list[str], points: list[tuple]) -> list[list[float]]:
    """Each point through the one-point path of :meth:`Codebook.evaluate` (see the module docstring)."""
    evaluate = cb.evaluate
    # all unknowns in order: fields=None lets a tensor-train codebook take its shortest one-point path
    fields = None if list(selected) == cb.unknown_names else selected
    rows = []
    for point in points:
        values = evaluate(dict(zip(names, point)), fields=fields)
        rows.append([float(values[u]) for u in selected])
    return rows


@QUERY.register("plain", "values separated by spaces, one line per point")
class PlainRows:
    """Each point's values, full precision, separated by spaces."""

    @staticmethod
    def chunk(names: list[str], selected: list[str], points: list[tuple], rows: list[list[float]],
              first: bool) -> str:
        return "".join(" ".join(map(repr, r)) + "\n" for r in rows)

    @staticmethod
    def closing(names: list[str], selected: list[str], wrote: bool) -> str:
        return ""


@QUERY.register("csv", "header + coordinates and values")
class CsvRows:
    """A header (coordinates, then unknowns), then each point's coordinates and values."""

    @staticmethod
    def chunk(names: list[str], selected: list[str], points: list[tuple], rows: list[list[float]],
              first: bool) -> str:
        head = ",".join(names + selected) + "\n" if first else ""
        return head + "".join(",".join(map(repr, p + tuple(r))) + "\n" for p, r in zip(points, rows))

    @staticmethod
    def closing(names: list[str], selected: list[str], wrote: bool) -> str:
        return "" if wrote else ",".join(names + selected) + "\n"  # an empty output still has its header


@QUERY.register("json", "a list of objects")
class JsonRows:
    """One list of ``{coordinate: value, ..., unknown: value, ...}`` objects, written chunk by chunk."""

    @staticmethod
    def chunk(names: list[str], selected: list[str], points: list[tuple], rows: list[list[float]],
              first: bool) -> str:
        keys = names + selected
        text = ", ".join(json.dumps(dict(zip(keys, p + tuple(r)))) for p, r in zip(points, rows))
        return ("[" if first else ", ") + text

    @staticmethod
    def closing(names: list[str], selected: list[str], wrote: bool) -> str:
        return "]\n" if wrote else "[]\n"


def format_chunk(fmt: str, cb, selected: list[str], points: list[tuple], first: bool) -> str:
    """The text of one chunk of points (``first``: the csv header / the json list's opening)."""
    names = cb.coordinate_names
    return QUERY.writer(fmt).chunk(names, selected, points, _values(cb, names, selected, points), first)


def closing(fmt: str, cb, selected: list[str], wrote: bool) -> str:
    """What ends the output: the csv header of an empty output, the json list's end."""
    return QUERY.writer(fmt).closing(cb.coordinate_names, selected, wrote)


class Writer:
    """Evaluate and print chunks of points; ``started`` once anything was written."""

    def __init__(self, out, fmt: str, cb, selected: list[str]):
        self.out, self.fmt, self.cb, self.selected = out, fmt, cb, selected
        self.started = False

    def text(self, chunk: list[tuple]) -> str:
        return format_chunk(self.fmt, self.cb, self.selected, chunk, first=not self.started)

    def write(self, text: str) -> None:
        if text:
            self.out.write(text)
            self.started = True

    def finish(self) -> None:
        self.out.write(closing(self.fmt, self.cb, self.selected, self.started))
        self.out.flush()

    def run(self, chunks) -> None:
        """Print every chunk of ``chunks`` (an iterator), then the closing text."""
        for chunk in chunks:
            self.write(self.text(chunk))
        self.finish()

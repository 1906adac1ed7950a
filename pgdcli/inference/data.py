"""Data for ``pgd fit``: reading the CSV and checking its columns, fixed coordinates (one-line errors)."""

from __future__ import annotations

import csv
import math
from array import array
from typing import Mapping

import numpy as np

from ..errors import PgdError
from ..limits import MAX_LINE_BYTES, limit

__all__ = ["FitError", "read_data", "check_finite", "split_columns", "fixed_values"]


class FitError(PgdError):
    """Invalid fit request: data, fixed coordinates or bounds (one-line message)."""


def read_data(source, label: str | None = None) -> dict[str, np.ndarray]:
    """Read a CSV with a header row into column name -> float array, streaming.

    The input is read line by line with the query path's limits: a line of at most
    :data:`~pgdcli.limits.MAX_LINE_BYTES` bytes, at most ``PGD_QUERY_MAX_POINTS`` lines (blank ones
    included), so a gigabyte on stdin is refused after its first bounded chunk, not read whole.

    Parameters
    ----------
    source : str, path or file-like
        ``'-'`` is not interpreted here (the CLI passes stdin as a file).
    label : str, optional
        Name used in error messages (default: the path).

    Raises
    ------
    FitError
        Empty file, no data rows, a duplicate or empty column name, a row of the wrong
        length, a value that is not a number, or a NaN; a line or a file over the limits.
    """
    if hasattr(source, "read"):
        return _read_rows(source, label or getattr(source, "name", "DATA"))
    label = label or str(source)
    try:
        with open(source, "rb") as handle:
            return _read_rows(handle, label)
    except OSError as exc:
        raise FitError(f"{label}: cannot read ({exc.strerror or exc})") from None


def _lines(handle, label: str):
    """``(line number, text)`` of every line, each bounded, their count bounded."""
    most = limit("query_points") + 1
    number = 0
    while True:
        try:
            raw = handle.readline(MAX_LINE_BYTES + 1)
        except UnicodeDecodeError:
            raise FitError(f"{label}: line {number + 1}: not UTF-8 text (a CSV file of numbers is expected)") from None
        if not raw:
            return
        number += 1
        if len(raw) > MAX_LINE_BYTES:
            raise FitError(f"{label}: line {number}: longer than {MAX_LINE_BYTES} bytes")
        if number > most:
            raise FitError(f"{label}: more than {most - 1} lines (PGD_QUERY_MAX_POINTS)")
        if isinstance(raw, bytes):
            try:
                raw = raw.decode("utf-8-sig" if number == 1 else "utf-8")
            except UnicodeDecodeError:
                raise FitError(f"{label}: line {number}: not UTF-8 text (a CSV file of numbers is expected)") from None
        yield number, raw


def _row(text: str, label: str, number: int) -> list[str]:
    try:
        return next(csv.reader([text]), [])
    except csv.Error as exc:
        raise FitError(f"{label}: line {number}: not a CSV row ({exc})") from None


def _rows(handle, label: str):
    """``(line number, cells)`` of the rows that hold something (blank lines and lone commas skipped)."""
    for number, text in _lines(handle, label):
        cells = _row(text, label, number)
        if any(x.strip() for x in cells):
            yield number, cells


def _read_rows(handle, label: str) -> dict[str, np.ndarray]:
    rows = _rows(handle, label)
    first = next(rows, None)
    if first is None:
        raise FitError(f"{label}: empty file (expected a CSV header naming the columns)")
    header = [h.strip() for h in first[1]]
    if any(not h for h in header) or len(set(header)) != len(header):
        shown = ",".join(header)
        raise FitError(f"{label}: the header must name every column once, got "
                       f"{shown if len(shown) <= 200 else shown[:197] + '...'}")
    columns = [array("d") for _ in header]
    for number, row in rows:
        if len(row) != len(header):
            raise FitError(f"{label}: line {number} has {len(row)} values for {len(header)} columns")
        for j, x in enumerate(row):
            try:
                value = float(x)
            except ValueError:
                shown = x.strip()[:40]
                raise FitError(f"{label}: line {number}, column {header[j]!r}: {shown!r} is not a number") from None
            if not math.isfinite(value):
                raise FitError(f"{label}: line {number}, column {header[j]!r} is {value!r} (NaN or infinite values "
                               f"are not data; drop the row)")
            columns[j].append(value)
    if not columns[0]:
        raise FitError(f"{label}: no data rows after the header")
    return {h: np.frombuffer(col, dtype=float).copy() for h, col in zip(header, columns)}


def check_finite(data: Mapping[str, np.ndarray], label: str, first_line: int = 1) -> None:
    for name, col in data.items():
        bad = ~np.isfinite(col)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            where = f"line {i + first_line}" if first_line == 2 else f"row {i + 1}"
            raise FitError(f"{label}: {where}, column {name!r} is {float(col[i])!r} (NaN or infinite values "
                           f"are not data; drop the row)")


def split_columns(cb, data: Mapping[str, np.ndarray], label: str) -> tuple[dict, list, dict]:
    """Split data into known coordinates, observed unknowns and sigma columns (checked)."""
    coords, observed, sigma = {}, [], {}
    lengths = {len(np.atleast_1d(v)) for v in data.values()}
    if len(lengths) > 1:
        raise FitError(f"{label}: columns of different lengths {sorted(lengths)}")
    for name, col in data.items():
        col = np.atleast_1d(np.asarray(col, dtype=float))
        if name in cb.coordinate_names:
            coords[name] = col
        elif name in cb.unknown_names:
            observed.append(name)
        elif name.startswith("sigma_") and name[6:] in cb.unknown_names:
            sigma[name[6:]] = col
        else:
            raise FitError(f"{label}: column {name!r} is neither a coordinate ({', '.join(cb.coordinate_names)}), "
                           f"an unknown ({', '.join(cb.unknown_names)}) nor sigma_<unknown>")
    time = next((c.name for c in cb.coordinates if c.role == "time"), None)
    if time is not None and time not in coords:
        raise FitError(f"{label}: no column for the time coordinate {time!r}")
    if not observed:
        raise FitError(f"{label}: no observed unknown; add a column named one of {', '.join(cb.unknown_names)}")
    for u in sigma:
        if u not in observed:
            raise FitError(f"{label}: sigma_{u} given but {u!r} is not observed")
        if np.any(sigma[u] <= 0):
            raise FitError(f"{label}: sigma_{u} must be positive")
    for name, col in coords.items():
        c = cb.coordinate(name)
        lo, hi = c.domain
        out = (col < lo) | (col > hi)
        if out.any():
            raise FitError(f"{label}: column {name!r}: value {float(col[out][0])!r} is outside the domain [{lo:g}, {hi:g}]")
    return coords, observed, sigma


def fixed_values(cb, fix: Mapping[str, float] | None, coords: Mapping) -> dict[str, float]:
    fixed = {}
    for name, value in (fix or {}).items():
        if name not in cb.coordinate_names:
            raise FitError(f"--fix {name}: unknown coordinate; this codebook has {', '.join(cb.coordinate_names)}")
        if name in coords:
            raise FitError(f"--fix {name}: {name!r} is already a data column")
        lo, hi = cb.coordinate(name).domain
        value = float(value)
        if not lo <= value <= hi:
            raise FitError(f"--fix {name}={value:g}: outside the domain [{lo:g}, {hi:g}]")
        fixed[name] = value
    return fixed

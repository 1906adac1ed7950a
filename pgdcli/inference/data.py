"""Data for ``pgd fit``: reading the CSV and checking its columns, fixed coordinates (one-line errors)."""

from __future__ import annotations

import csv
import io
from pathlib import Path
from typing import Mapping

import numpy as np

from ..errors import PgdError

__all__ = ["FitError", "read_data", "check_finite", "split_columns", "fixed_values"]


class FitError(PgdError):
    """Invalid fit request: data, fixed coordinates or bounds (one-line message)."""


def read_data(source, label: str | None = None) -> dict[str, np.ndarray]:
    """Read a CSV with a header row into column name -> float array.

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
        length, a value that is not a number, or a NaN.
    """
    if hasattr(source, "read"):
        label = label or getattr(source, "name", "DATA")
        text = source.read()
    else:
        label = label or str(source)
        try:
            text = Path(source).read_text()
        except OSError as exc:
            raise FitError(f"{label}: cannot read ({exc.strerror or exc})") from None
    rows = [r for r in csv.reader(io.StringIO(text)) if r and any(x.strip() for x in r)]
    if not rows:
        raise FitError(f"{label}: empty file (expected a CSV header naming the columns)")
    header = [h.strip() for h in rows[0]]
    if any(not h for h in header) or len(set(header)) != len(header):
        raise FitError(f"{label}: the header must name every column once, got {','.join(header)}")
    if len(rows) == 1:
        raise FitError(f"{label}: no data rows after the header")
    values = np.empty((len(rows) - 1, len(header)))
    for i, row in enumerate(rows[1:], start=2):
        if len(row) != len(header):
            raise FitError(f"{label}: line {i} has {len(row)} values for {len(header)} columns")
        for j, x in enumerate(row):
            try:
                values[i - 2, j] = float(x)
            except ValueError:
                raise FitError(f"{label}: line {i}, column {header[j]!r}: {x.strip()!r} is not a number") from None
    data = {h: values[:, j] for j, h in enumerate(header)}
    check_finite(data, label, first_line=2)
    return data


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

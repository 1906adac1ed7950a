"""Arguments of ``pgd plot`` and of the plot API, checked against a codebook (errors name the option)."""

from __future__ import annotations

from typing import Mapping, Sequence
import math

from ..errors import PgdError, QueryError

__all__ = ["KINDS", "DEFAULT_KIND", "FORMATS", "DEFAULT_DPI", "parse_point", "parse_over", "parse_size",
           "require_matplotlib"]


KINDS = ("solution", "modes", "convergence", "error", "phase", "sensitivity")
DEFAULT_KIND = "solution"
FORMATS = ("png", "svg")
DEFAULT_DPI = 150
DEFAULT_COUNT = 6
LINE_POINTS = 201          # samples along a curve
MAP_POINTS = 81            # samples per axis of a map
REFERENCE_MARKERS = 21     # reference markers per curve (solution --reference)
DEFAULT_AT_CURVES = 5      # curves along the first parameter when no --at is given


def require_matplotlib(what: str = "drawing a figure") -> None:
    """Raise a one-line :class:`~pgdcli.errors.PgdError` when matplotlib is not installed.

    matplotlib is an optional dependency (the ``plot`` extra): solving, querying, verifying,
    fitting and exporting do not need it.

    Parameters
    ----------
    what : str
        What needs it, for the message (e.g. ``"pgd plot"``).

    Raises
    ------
    PgdError
        matplotlib cannot be imported; the message gives the command that installs it.
    """
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        raise PgdError(f"{what} needs matplotlib, which is not installed: pip install 'pgdcli[plot]' "
                       f"(or pip install matplotlib)") from None


# ----------------------------------------------------------------------------------------------
# argument parsing shared by the CLI and the Python API (errors name the option)
# ----------------------------------------------------------------------------------------------
def _describe(c) -> str:
    return f"{c.name} in [{c.domain[0]:g}, {c.domain[1]:g}]"


def _coordinate(codebook, name: str, option: str):
    for c in codebook.coordinates:
        if c.name == name:
            return c
    raise QueryError(f"{option}: unknown coordinate {name!r}; this codebook has "
                     f"{', '.join(_describe(c) for c in codebook.coordinates)}")


def _check_value(c, value: float, option: str) -> float:
    low, high = c.domain
    if not (math.isfinite(value) and low <= value <= high):
        raise QueryError(f"{option} {c.name}={value:g}: outside the domain [{low:g}, {high:g}] of {c.name!r}")
    return float(value)


def parse_point(text: str | Mapping[str, float], codebook, option: str = "--at") -> dict[str, float]:
    """``'k=3.2,c=0.1'`` (or a mapping) -> ``{'k': 3.2, 'c': 0.1}``, checked against the codebook.

    Raises
    ------
    QueryError
        Malformed text, a missing value, an unknown coordinate, a coordinate
        given twice or a value outside its domain; the message names ``option``.
    """
    if isinstance(text, Mapping):
        items = [(str(k), v) for k, v in text.items()]
    else:
        items = []
        for part in str(text).split(","):
            name, eq, value = part.partition("=")
            name, value = name.strip(), value.strip()
            if not eq or not name:
                raise QueryError(f"{option}: expected NAME=VALUE[,NAME=VALUE...], got {str(text)!r}")
            if not value:
                raise QueryError(f"{option}: missing value for coordinate {name!r} (expected {name}=NUMBER)")
            items.append((name, value))
    out: dict[str, float] = {}
    for name, value in items:
        c = _coordinate(codebook, name, option)
        if name in out:
            raise QueryError(f"{option}: coordinate {name!r} given twice")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise QueryError(f"{option} {name}={value}: not a number") from None
        out[name] = _check_value(c, number, option)
    return out


def parse_over(text: str | Sequence[str], codebook) -> tuple[str, str]:
    """``'k,t'`` -> ``('k', 't')``: the x and y axes of a map (two different coordinates)."""
    names = [n.strip() for n in text.split(",")] if isinstance(text, str) else [str(n) for n in text]
    if len(names) != 2 or not all(names) or names[0] == names[1]:
        names_ = codebook.coordinate_names
        example = f" (e.g. {names_[1]},{names_[0]})" if len(names_) >= 2 else ""
        raise QueryError(f"--over: expected two different coordinate names X,Y{example}, got {text!r}")
    for n in names:
        _coordinate(codebook, n, "--over")
    return names[0], names[1]


def parse_size(text: str) -> tuple[float, float]:
    """``'8x5'`` (inches) -> ``(8.0, 5.0)``."""
    parts = str(text).lower().replace(",", "x").split("x")
    try:
        w, h = (float(p) for p in parts)
    except ValueError:
        raise QueryError(f"--size: expected WIDTHxHEIGHT in inches (e.g. 8x5), got {text!r}") from None
    if not (0.5 <= w <= 100 and 0.5 <= h <= 100):
        raise QueryError(f"--size: width and height must be between 0.5 and 100 inches, got {text!r}")
    return w, h


def field_name(codebook, field: str | None) -> str:
    if field is None:
        return codebook.unknown_names[0]
    if field not in codebook.fields:
        raise QueryError(f"--field: unknown {field!r}; this codebook has {', '.join(codebook.unknown_names)}")
    return field


def time_coordinate_of(codebook, what: str):
    for c in codebook.coordinates:
        if c.role == "time":
            return c
    raise QueryError(f"{what} needs a time coordinate; this codebook has none "
                     f"({', '.join(codebook.coordinate_names)})")


def line_axis(codebook, what: str):
    """The coordinate curves run along: time, or for a steady codebook its first space coordinate."""
    for c in codebook.coordinates:
        if c.role == "time":
            return c
    for c in codebook.coordinates:
        if c.role == "space":
            return c
    return time_coordinate_of(codebook, what)


def is_steady(codebook) -> bool:
    return not any(c.role == "time" for c in codebook.coordinates)


def domain_midpoint(c) -> float:
    return 0.5 * (c.domain[0] + c.domain[1])


def count_points(points: int | None, default: int, high: int = 100_000, option: str = "--points") -> int:
    if points is None:
        return default
    if int(points) != points or not 2 <= points <= high:
        raise QueryError(f"{option}: expected an integer from 2 to {high}, got {points}")
    return int(points)


def point_label(point: Mapping[str, float]) -> str:
    return ", ".join(f"{k}={v:g}" for k, v in point.items()) or "(no parameters)"

"""Checks of what a query asks for: coordinate names, unknowns, values inside the domain.

The one definition of the rules every evaluation path of :class:`~pgdcli.codebook.Codebook`
applies before any number is computed. numpy only (the query path).
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import QueryError

__all__ = ["domain_slack", "clip_to_domain", "check_names", "select_fields"]


def domain_slack(low: float, high: float) -> float:
    """How far outside ``[low, high]`` a value is still taken as on the boundary: the rounding of
    user-side arithmetic (``np.linspace(low, high)`` may step past ``high`` by an ulp)."""
    return 1e-12 * max(1.0, abs(low), abs(high))


def clip_to_domain(c: CoordinateInfo, x: np.ndarray) -> np.ndarray:
    """``x`` clipped into the domain of ``c``; QueryError naming the first value outside it.

    Parameters
    ----------
    c : CoordinateInfo
    x : ndarray, shape (n,)

    Returns
    -------
    ndarray, shape (n,)
    """
    low, high = c.domain
    slack = domain_slack(low, high)
    bad = ~((x >= low - slack) & (x <= high + slack))
    if bad.any():
        v = float(x[bad][0])
        raise QueryError(f"coordinate {c.name!r}: value {v!r} is outside the domain [{low:g}, {high:g}]")
    return np.clip(x, low, high)


def check_names(coordinates: Sequence[CoordinateInfo], given: Mapping[str, object]) -> None:
    """QueryError for the first name of ``given`` that is no coordinate, then the first coordinate missing."""
    names = [c.name for c in coordinates]
    for key in given:
        if key not in names:
            raise QueryError(f"unknown coordinate {key!r}; this codebook has {', '.join(names)}")
    for c in coordinates:
        if c.name not in given:
            raise QueryError(f"missing coordinate {c.name!r} (domain [{c.domain[0]:g}, {c.domain[1]:g}])")


def select_fields(unknowns: Sequence[str], fields: Sequence[str] | None) -> list[str]:
    """The unknowns asked for (all of ``unknowns`` for None); QueryError naming one that is not there."""
    if fields is None:
        return list(unknowns)
    out = []
    for f in fields:
        if f not in unknowns:
            raise QueryError(f"unknown field {f!r}; this codebook has {', '.join(unknowns)}")
        out.append(f)
    return out

"""A codebook file's events: the ``events/<name>`` groups of docs/codebook-format.md (format 1.2).

Each event's group holds its condition (``when``), ``direction``, the node count of each of its
coordinates (``coordinate-nodes``: the codebook's coordinates, time with 2) and its tensor train, stored
as an unknown's is; the root's ``event-order`` lists the events. numpy only (the query path).
"""

from __future__ import annotations

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError
from ..limits import limit
from ..names import printable
from .events import DIRECTIONS, EventTime

__all__ = ["write_events", "read_events", "MAX_EVENTS"]

#: Most events a codebook may declare (a spec allows 16).
MAX_EVENTS = 64


def write_events(f, events: dict, write_train) -> None:
    """Write ``events`` (name -> EventTime) into an open file; ``write_train(group, coordinates, train)``."""
    if not events:
        return
    f.attrs["event-order"] = np.array(list(events), dtype=object)
    ge = f.create_group("events")
    for e, event in events.items():
        g = ge.create_group(e)
        g.attrs["when"] = event.when
        g.attrs["direction"] = event.direction
        g.attrs["coordinate-nodes"] = np.array([c.nodes for c in event.coordinates], dtype=np.int64)
        write_train(g, event.coordinates, event.field)


def _text(value) -> str:
    """An attribute's text ('' for anything else: an event's texts are never numbers)."""
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    return value if isinstance(value, str) else ""


def read_events(found, coords: list, read_names, read_train) -> dict:
    """Event name -> (EventTime, bytes its arrays declare) of a surveyed file (``{}`` without events).

    ``read_names(value, what, most)`` checks a list of names read from an attribute (the reader of the
    coordinates' and unknowns'); ``read_train(name, coordinates, where)`` reads the train at ``where``
    against ``coordinates``.
    """
    p = found.source
    value = found.attr("", "event-order")
    if value is None:
        return {}
    events = {}
    for e in read_names(value, "event", MAX_EVENTS):
        where = f"events/{e}"
        if where not in found.attrs:
            raise CodebookError(f"{p}: corrupt codebook: no event {e!r}")
        when, direction = _text(found.attr(where, "when", "")), _text(found.attr(where, "direction", ""))
        if not when or direction not in DIRECTIONS:
            raise CodebookError(f"{p}: corrupt codebook: event {e!r} has no condition or direction "
                                f"{printable(direction)!r}")
        if _text(found.attr(where, "representation", "")) != "tensor-train":
            raise CodebookError(f"{p}: event {e!r} is not stored as a tensor train, which this pgdcli does not "
                                f"know; upgrade pgdcli (pip install -U pgdcli)")
        mine = _coordinates(found, e, coords)
        field, size = read_train(e, mine, where)
        events[e] = (EventTime(when, direction, tuple(mine), field), size)
    return events


def _coordinates(found, e: str, coords: list) -> list:
    """An event's coordinates: the codebook's with the event's node counts (time: 2 Chebyshev nodes)."""
    p = found.source
    try:
        counts = np.asarray(found.attr(f"events/{e}", "coordinate-nodes"), dtype=np.int64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        counts = np.zeros(0, dtype=np.int64)
    if counts.size != len(coords):
        raise CodebookError(f"{p}: corrupt codebook: event {e!r}: no node count for each of the {len(coords)} "
                            f"coordinates")
    out = []
    most = limit("time_nodes") + 1
    for c, n in zip(coords, counts):
        n = int(n)
        if c.role == "time":
            info, ok = CoordinateInfo(c.name, c.domain, n, "chebyshev", c.role), n == 2
        else:
            info = CoordinateInfo(c.name, c.domain, n, c.discretization, c.role, c.breakpoints)
            ok = 2 <= n <= most
            if ok:
                try:
                    info.basis()
                except (ValueError, ZeroDivisionError):
                    ok = False
        if not ok:
            raise CodebookError(f"{p}: corrupt codebook: event {e!r}: {n} nodes for coordinate {c.name!r} do not fit "
                                f"its discretization")
        out.append(info)
    return out

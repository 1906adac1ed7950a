"""A codebook's events: the time of each named event as a field of the parameters.

An event (``events:`` in a spec) is stored as a tensor train over coordinates of its own: the
codebook's, with their own node counts (an event time may need more nodes than the solution), and
time with two nodes and a constant core: evaluated at any time it gives the same number, the first
time after the start at which the event's condition ``when`` crosses zero in its ``direction``.
numpy only (the query path).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np

from ..discretization.coordinates import CoordinateInfo
from ..errors import CodebookError, QueryError
from ..names import identifier_problem, printable
from .fields import TT, validate_field

__all__ = ["EventTime", "DIRECTIONS", "validate_event", "event_times", "event_without_time"]

DIRECTIONS = ("any", "rising", "falling")
#: Longest condition text kept with a codebook (a spec's expressions are shorter).
MAX_WHEN_LENGTH = 10_000


@dataclass(frozen=True)
class EventTime:
    """One event of a codebook.

    Attributes
    ----------
    when : str
        The condition as written in the spec (``"y = 0"``).
    direction : str
        ``any``, ``rising`` (from - to +) or ``falling``.
    coordinates : tuple of CoordinateInfo
        The codebook's coordinates with the event's own node counts (time: 2 nodes).
    field : TT
        The event's time, one core per coordinate, constant along time.
    """

    when: str
    direction: str
    coordinates: tuple
    field: TT


def validate_event(name: str, coordinates: Sequence[CoordinateInfo], event) -> EventTime:
    """The event, checked against the codebook's coordinates (CodebookError naming the event)."""
    why = identifier_problem(name)
    if why:
        raise CodebookError(f"event name {printable(name)!r}: {why}")
    if not isinstance(event, EventTime):
        raise CodebookError(f"event {name!r}: expected an EventTime, got {type(event).__name__}")
    if event.direction not in DIRECTIONS:
        raise CodebookError(f"event {name!r}: direction {event.direction!r} is not one of {', '.join(DIRECTIONS)}")
    if not isinstance(event.when, str) or len(event.when) > MAX_WHEN_LENGTH:
        raise CodebookError(f"event {name!r}: its condition is not a text of at most {MAX_WHEN_LENGTH} characters")
    if not any(c.role == "time" for c in coordinates):
        raise CodebookError(f"event {name!r}: a codebook without a time coordinate records no events")
    if not isinstance(event.field, TT):
        raise CodebookError(f"event {name!r}: expected a tensor train, got {type(event.field).__name__}")
    mine = tuple(event.coordinates)
    if [(c.name, tuple(c.domain), c.role) for c in mine] != [(c.name, tuple(c.domain), c.role) for c in coordinates]:
        raise CodebookError(f"event {name!r}: its coordinates are not the codebook's (names, domains, roles)")
    validate_field(f"event {name}", mine, event.field)
    return event


def event_times(cb, books: Mapping, coordinates: Mapping[str, object], events: Sequence[str] | None = None
                ) -> dict[str, np.ndarray]:
    """The time of events at parameter points (:meth:`pgdcli.Codebook.event_times`).

    Parameters
    ----------
    cb : pgdcli.Codebook
    books : mapping
        Event name -> a codebook of the event's field alone, on its coordinates.
    coordinates : mapping
        Every coordinate but time -> scalar or array_like (broadcast together).
    events : sequence of str, optional
        Event names (default: all, in spec order).

    Returns
    -------
    dict of str to ndarray
        Event name -> its time, of the broadcast shape: the first time after the start at which
        the event's condition crosses zero in its direction.

    Raises
    ------
    QueryError
        A codebook without events, an unknown event, the time coordinate given, missing,
        unknown or out-of-domain coordinates.
    """
    if not cb.events:
        raise QueryError("this codebook records no events (add an 'events:' section to the spec)")
    selected = list(cb.events) if events is None else list(events)
    for e in selected:
        if e not in cb.events:
            raise QueryError(f"unknown event {e!r}; this codebook's events: {', '.join(cb.events)}")
    time = next(c for c in cb.coordinates if c.role == "time")  # a codebook with events has one
    if time.name in coordinates:
        raise QueryError(f"an event's time does not depend on {time.name!r}: give the other coordinates only")
    given = dict(coordinates)
    given[time.name] = float(time.domain[0])  # the fields are constant in time
    return {e: books[e].evaluate(given)[e] for e in selected}


def event_without_time(event: EventTime) -> tuple[list, TT]:
    """An event's coordinates and train without the time core (contracted at the start of time), or as
    they are when time is the only coordinate."""
    coords = list(event.coordinates)
    j = next(k for k, c in enumerate(coords) if c.role == "time")
    if len(coords) == 1:
        return coords, event.field
    cores, order = [np.asarray(c) for c in event.field.cores], list(event.field.mode_order)
    k = order.index(j)
    weights = coords[j].basis().interpolation_matrix(np.array([coords[j].domain[0]]))[0]
    matrix = np.einsum("anb,n->ab", cores[k], weights)
    if k + 1 < len(cores):
        cores[k + 1] = np.einsum("ab,bnc->anc", matrix, cores[k + 1])
    else:
        cores[k - 1] = np.einsum("anb,bc->anc", cores[k - 1], matrix)
    del cores[k], order[k]
    return coords[:j] + coords[j + 1:], TT(cores, [m - (m > j) for m in order])

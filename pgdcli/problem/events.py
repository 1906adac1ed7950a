"""Events: named conditions ``lhs = rhs`` whose first crossing in time the codebook records.

A spec may name events::

    events:
      landing: "y = 0"                              # the first time y - 0 changes sign
      apex: {when: "vy = 0", direction: falling}    # only where vy goes from + to -

The condition ``g = lhs - rhs`` may use the unknowns' values (no ``der()``), the time, the other
coordinates and constants, and every function of the equations. The event time is the first
``t > t0`` where ``g`` changes sign in the given direction (``rising``: from - to +, ``falling``:
from + to -, ``any``); a condition that holds exactly at the start time is not an event there.
It is a function of the parameters alone, stored in the codebook as one more separated field.

This module parses the section and evaluates ``g``; numpy only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .checker import Checker, NameRegistry, show_value
from .expressions import ParseOptions, Polynomial, parse_equation
from .general import evaluate as general_tree_values
from .general import is_general, tree_of

__all__ = ["Event", "DIRECTIONS", "EVENT_KEYS", "parse_events", "condition_values", "state_gradient_norm"]

#: ``rising``: g goes from negative to non-negative; ``falling``: positive to non-positive.
DIRECTIONS = ("any", "rising", "falling")
EVENT_KEYS = ("when", "direction")
#: Keys of what other tools do at an event, refused with a reason (the motion is not stopped or reset).
ACTION_KEYS = ("then", "action", "terminal", "stop", "reset")
#: At most this many events per spec (each is one more field to build and check).
MAX_EVENTS = 16


@dataclass(frozen=True)
class Event:
    """A named event: the first crossing of ``condition = lhs - rhs`` through zero after the start time.

    Attributes
    ----------
    name : str
    text : str
        The condition as written (``"y = 0"``).
    direction : str
        One of :data:`DIRECTIONS`.
    condition : Polynomial
        ``lhs - rhs``, a polynomial in the unknowns' values with separated coefficients.
    """

    name: str
    text: str
    direction: str
    condition: Polynomial


def parse_events(check: Checker, names: NameRegistry, value: Any, options: ParseOptions,
                 has_space: bool) -> tuple[Event, ...]:
    """The ``events`` section: name -> ``"lhs = rhs"`` or ``{when: "lhs = rhs", direction: ...}``.

    Raises
    ------
    SpecError
        Naming ``events.<name>`` and what was expected.
    """
    if value is None:
        return ()
    section = check.mapping(value, "events", empty_ok=False)
    if options.time is None or has_space:
        raise check.error("events", "events need an initial-value problem of ODEs (a time coordinate and no space "
                                    "coordinate)")
    if len(section) > MAX_EVENTS:
        raise check.error("events", f"{len(section)} events; at most {MAX_EVENTS}")
    events = []
    for key, body in section.items():
        name = names.add(key, "events")
        path = f"events.{name}"
        direction = "any"
        if isinstance(body, dict):
            acting = [k for k in ACTION_KEYS if k in body]
            if acting:
                raise check.error(f"{path}.{acting[0]}", "acting on an event (stopping the motion, or a reset such "
                                                         "as a bounce) is not supported: the codebook records the "
                                                         "event's time only (keys: when, direction)")
            body = check.mapping(body, path, EVENT_KEYS)
            direction = check.choice(body.get("direction", "any"), f"{path}.direction", DIRECTIONS)
            body = check.require(body, "when", path)
            path = f"{path}.when"
        if not isinstance(body, str):
            raise check.error(path, f"expected a condition like 'y = 0' (or {{when: 'y = 0', direction: falling}}), "
                                    f"got {show_value(body)}")
        if re.search(r"\bder\s*\(", body):
            raise check.error(path, f"the condition '{body}' uses der(); an event's condition takes the unknowns' "
                                    f"values (write the derivative's equation right-hand side instead)")
        condition = parse_equation(body, options, where=f"{check.source}: {path}", allow_der=False)
        if not condition.unknowns:
            raise check.error(path, f"the condition '{body}' does not involve an unknown; an event is where the "
                                    f"solution meets it")
        events.append(Event(name, body, direction, condition))
    return tuple(events)


def condition_values(event: Event, unknowns: Mapping[str, np.ndarray], coordinates: Mapping[str, np.ndarray]
                     ) -> np.ndarray:
    """``g = lhs - rhs`` of an event at points (numpy broadcasting of every value given).

    Parameters
    ----------
    event : Event
    unknowns : mapping of str to ndarray
        Every unknown's value at the points.
    coordinates : mapping of str to ndarray
        Every coordinate the condition's coefficients use (time included).

    Returns
    -------
    ndarray
        The broadcast shape of the values.
    """
    values = {**coordinates, **unknowns}
    total = 0.0
    with np.errstate(all="ignore"):
        for monomial, coefficient in event.condition.items():
            term = coefficient.evaluate(**coordinates)
            for atom in monomial:
                term = term * (general_tree_values(tree_of(atom), values) if is_general(atom) else unknowns[atom.unknown])
            total = total + term
    shape = np.broadcast_shapes(*(np.shape(v) for v in values.values()))
    return np.broadcast_to(np.asarray(total, dtype=float), shape)


def state_gradient_norm(event: Event, unknowns: Mapping[str, np.ndarray], coordinates: Mapping[str, np.ndarray]
                        ) -> np.ndarray:
    """``sum_i |dg/du_i|`` at points, by central differences: ``|g| / norm`` is the smallest change of the
    state (in the max norm) that puts it on the event's surface, to first order.

    A scale, not a claimed value: the step is ``1e-6 (1 + |u_i|)``.
    """
    total = 0.0
    for name in unknowns:  # every unknown: a general term's (sin(th)) are inside its tree
        u = np.asarray(unknowns[name], dtype=float)
        h = 1e-6 * (1.0 + np.abs(u))
        up = condition_values(event, {**unknowns, name: u + h}, coordinates)
        down = condition_values(event, {**unknowns, name: u - h}, coordinates)
        total = total + np.abs(up - down) / (2 * h)
    return np.asarray(total, dtype=float)

"""Events: named conditions ``lhs = rhs`` whose first crossing in time the codebook records.

A spec may name events::

    events:
      landing: "y = 0"                              # the first time y - 0 changes sign
      apex: {when: "vy = 0", direction: falling}    # only where vy goes from + to -
      impact: {when: "y = 0", direction: falling, then: {v: "-e*v"}}   # a reset: the motion goes on
      landing: {when: "y = 0", direction: falling, terminal: true}     # the motion ends there

The condition ``g = lhs - rhs`` may use the unknowns' values (no ``der()``), the time, the other
coordinates and constants, and every function of the equations. The event time is the first
``t > t0`` where ``g`` changes sign in the given direction (``rising``: from - to +, ``falling``:
from + to -, ``any``); a condition that holds exactly at the start time is not an event there.
It is a function of the parameters alone, stored in the codebook as one more separated field.

An event may act on the motion: ``then`` maps unknowns to expressions of the unknowns' values just
before the event, the coordinates (time: the event's) and constants, their values just after it (a
bounce); ``terminal: true`` ends the motion there. One event of a spec may act; an event with
``then`` is the spec's only event.

This module parses the section and evaluates ``g``; numpy only.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from .checker import Checker, NameRegistry, show_value
from .expressions import ParseOptions, Polynomial, parse_equation, parse_expression
from .general import evaluate as general_tree_values
from .general import is_general, tree_of

__all__ = ["Event", "DIRECTIONS", "EVENT_KEYS", "parse_events", "condition_values", "state_gradient_norm",
           "reset_values", "acting_event"]

#: ``rising``: g goes from negative to non-negative; ``falling``: positive to non-positive.
DIRECTIONS = ("any", "rising", "falling")
EVENT_KEYS = ("when", "direction", "then", "terminal")
#: Keys other tools use for acting on an event, refused with the ones this spec takes.
OTHER_ACTION_KEYS = ("action", "stop", "reset")
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
    reset : tuple of (str, str, Polynomial)
        ``then``: (unknown, expression as written, the expression parsed) per unknown reset.
    terminal : bool
        The motion ends at the event.
    """

    name: str
    text: str
    direction: str
    condition: Polynomial
    reset: tuple = ()
    terminal: bool = False

    @property
    def acts(self) -> bool:
        """Whether the event resets or ends the motion."""
        return bool(self.reset) or self.terminal


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
        events.append(_parse_event(check, name, body, options))
    acting = [e for e in events if e.acts]
    if len(acting) > 1:
        raise check.error(f"events.{acting[1].name}", f"only one event may act on the motion (then, terminal); "
                                                      f"{acting[0].name!r} does already")
    if acting and acting[0].reset and len(events) > 1:
        raise check.error(f"events.{acting[0].name}.then", "an event with a reset must be the spec's only event "
                                                           "(the others' times would be of the first phase only)")
    return tuple(events)


def _parse_event(check: Checker, name: str, body: Any, options: ParseOptions) -> Event:
    path = f"events.{name}"
    direction, reset, terminal = "any", (), False
    if isinstance(body, dict):
        other = [k for k in OTHER_ACTION_KEYS if k in body]
        if other:
            raise check.error(f"{path}.{other[0]}", "to act on an event write then: {unknown: expression} (a reset "
                                                    "such as a bounce) or terminal: true (the motion ends there)")
        body = check.mapping(body, path, EVENT_KEYS)
        direction = check.choice(body.get("direction", "any"), f"{path}.direction", DIRECTIONS)
        if "then" in body and "terminal" in body:
            raise check.error(f"{path}.terminal", "give then (a reset: the motion goes on) or terminal (the motion "
                                                  "ends), not both")
        if "terminal" in body:
            terminal = body["terminal"]
            if not isinstance(terminal, bool):
                raise check.error(f"{path}.terminal", f"expected true or false, got {show_value(terminal)}")
        if "then" in body:
            reset = _parse_reset(check, body["then"], f"{path}.then", options)
            if direction == "any":
                raise check.error(f"{path}.direction", "a reset needs direction: falling or rising (just after it "
                                                       "the state is on the event's surface, where any direction "
                                                       "would meet the event again)")
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
    return Event(name, body, direction, condition, reset, terminal)


def _parse_reset(check: Checker, value: Any, path: str, options: ParseOptions) -> tuple:
    """``then: {unknown: expression}`` -> ((unknown, text, Polynomial), ...)."""
    section = check.mapping(value, path, empty_ok=False)
    out = []
    for unknown, text in section.items():
        where = f"{path}.{unknown}"
        if unknown not in options.unknowns:
            raise check.error(where, f"{show_value(unknown)} is not an unknown; a reset gives unknowns "
                                     f"({', '.join(options.unknowns)}) their values after the event")
        if isinstance(text, bool) or not isinstance(text, (str, int, float)):
            raise check.error(where, f"expected an expression of the unknowns, coordinates and constants, "
                                     f"got {show_value(text)}")
        text = str(text)
        if re.search(r"\bder\s*\(", text):
            raise check.error(where, f"the reset '{text}' uses der(); a reset takes the unknowns' values just "
                                     f"before the event")
        out.append((unknown, text, parse_expression(text, options, where=f"{check.source}: {where}",
                                                    allow_der=False)))
    return tuple(out)


def acting_event(events) -> Event | None:
    """The event that resets or ends the motion (at most one), or None."""
    return next((e for e in events if e.acts), None)


def reset_values(event: Event, unknowns: Mapping[str, np.ndarray], coordinates: Mapping[str, np.ndarray]
                 ) -> dict[str, np.ndarray]:
    """The unknowns just after the event from their values just before it (unknowns not reset keep theirs)."""
    out = dict(unknowns)
    for name, _, expression in event.reset:
        out[name] = _polynomial_values(expression, unknowns, coordinates)
    return out


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
    return _polynomial_values(event.condition, unknowns, coordinates)


def _polynomial_values(polynomial: Polynomial, unknowns: Mapping[str, np.ndarray],
                       coordinates: Mapping[str, np.ndarray]) -> np.ndarray:
    values = {**coordinates, **unknowns}
    total = 0.0
    with np.errstate(all="ignore"):
        for monomial, coefficient in polynomial.items():
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

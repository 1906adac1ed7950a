"""The ``events:`` section of a spec: parsing, its one-line errors, and the condition's values."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.errors import SpecError
from pgdcli.problem.events import condition_values, reset_values
from pgdcli.problem.spec import parse_spec

BALL = """
coordinates:
  t: {domain: [0, 2]}
  v0: {domain: [1, 5]}
unknowns:
  y: {initial: 0}
  v: {initial: v0}
equations:
  - "der(y) = v"
  - "der(v) = -9.81"
"""


def _parse(events: str):
    return parse_spec(BALL + "events:\n" + events, source="ball.yaml")


def test_short_and_long_forms():
    problem = _parse('  landing: {when: "y = 0", direction: falling}\n  apex: "v = 0"\n')
    landing, apex = problem.events
    assert (landing.name, landing.text, landing.direction) == ("landing", "y = 0", "falling")
    assert (apex.name, apex.direction) == ("apex", "any")


def test_condition_values_are_lhs_minus_rhs_at_points():
    (event,) = _parse('  high: "y*v + sin(t) = 0.5*v0"\n').events
    y, v, t, v0 = np.array([1.0, 2.0]), np.array([3.0, -1.0]), np.array([0.1, 0.7]), np.array([2.0, 4.0])
    got = condition_values(event, {"y": y, "v": v}, {"t": t, "v0": v0})
    np.testing.assert_allclose(got, y * v + np.sin(t) - 0.5 * v0, rtol=1e-15)


@pytest.mark.parametrize("events, message", [
    ('  landing: "t = 1"\n', "events.landing: the condition 't = 1' does not involve an unknown"),
    ("  landing: 3\n", "events.landing: expected a condition like 'y = 0'"),
    ('  landing: {when: "y = 0", direction: up}\n', "events.landing.direction: expected one of any, rising, falling"),
    ('  v: "y = 0"\n', "events.v: name 'v' is already used by unknowns.v"),
    ('  landing: {direction: rising}\n', "events.landing"),
    ('  landing: {when: "y = 0", at: 2}\n', "events.landing"),
    ('  landing: "y == 0"\n', "events.landing"),
    ('  landing: "der(y) = 0"\n', "events.landing: the condition 'der(y) = 0' uses der()"),
    ('  landing: "y = q"\n', "events.landing"),
    ("  []\n", "events"),
    ('  bounce: {when: "y = 0", direction: falling, then: {v: "-0.8*v"}, terminal: true}\n',
     "events.bounce.terminal: give then"),
    ('  bounce: {when: "y = 0", then: {v: "-0.8*v"}}\n', "events.bounce.direction: a reset needs direction"),
    ('  bounce: {when: "y = 0", direction: falling, then: {w: "-0.8*v"}}\n',
     "events.bounce.then.w: 'w' is not an unknown"),
    ('  bounce: {when: "y = 0", direction: falling, then: {v: "-0.8*der(v)"}}\n',
     "events.bounce.then.v: the reset '-0.8*der(v)' uses der()"),
    ('  bounce: {when: "y = 0", direction: falling, then: {v: "-0.8*q"}}\n', "events.bounce.then.v: unknown name 'q'"),
    ('  bounce: {when: "y = 0", direction: falling, then: {v: [1]}}\n', "events.bounce.then.v: expected an expression"),
    ('  bounce: {when: "y = 0", direction: falling, then: {}}\n', "events.bounce.then"),
    ('  bounce: {when: "y = 0", direction: falling, then: {v: "-v"}}\n  apex: "v = 0"\n',
     "events.bounce.then: an event with a reset must be the spec's only event"),
    ('  landing: {when: "y = 0", terminal: true}\n  top: {when: "v = 0", terminal: true}\n',
     "events.top: only one event may act on the motion"),
    ('  landing: {when: "y = 0", terminal: 1}\n', "events.landing.terminal: expected true or false"),
    ('  landing: {when: "y = 0", stop: true}\n', "events.landing.stop: to act on an event write then:"),
])
def test_bad_events_name_the_key(events, message):
    with pytest.raises(SpecError) as info:
        _parse(events)
    text = str(info.value)
    assert text.startswith("ball.yaml: ") and message in text and "\n" not in text


def test_resets_and_terminal_events_parse():
    (bounce,) = _parse('  bounce: {when: "y = 0", direction: falling, then: {v: "-0.5*v + 0*t"}}\n').events
    assert bounce.acts and not bounce.terminal and [(u, text) for u, text, _ in bounce.reset] == [("v", "-0.5*v + 0*t")]
    after = reset_values(bounce, {"y": np.array([0.0]), "v": np.array([-4.0])}, {"t": np.array([1.0]),
                                                                                  "v0": np.array([2.0])})
    assert after["y"][0] == 0.0 and after["v"][0] == 2.0
    landing, apex = _parse('  landing: {when: "y = 0", terminal: true}\n  apex: "v = 0"\n').events
    assert landing.terminal and not landing.reset and not apex.acts


def test_events_need_an_ode_problem():
    text = """
coordinates:
  x: {domain: [0, 1]}
  t: {domain: [0, 1]}
unknowns:
  u: {initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}
equations:
  - "der(u) = der(u, x, 2)"
events:
  cool: "u = 0.1"
"""
    with pytest.raises(SpecError, match="events: events need an initial-value problem of ODEs"):
        parse_spec(text, source="heat.yaml")


def test_no_events_section_means_none():
    assert parse_spec(BALL).events == ()

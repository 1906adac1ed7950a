"""Problems with switching functions (min, max, clamp): codebooks within their tolerance, or refused.

problems/road_ramp.yaml (a switch in time) and problems/two_rates.yaml (a switch in an initial value).

Each shipped problem is checked at 300 random points, on every face and at every corner of its box
against solve_ivp (DOP853, rtol 1e-10, atol 1e-12) integrated here piecewise between the switch
times this file knows, sharing nothing with the solver; the relaxation also against its closed form.
"""

from __future__ import annotations

import itertools
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli
from pgdcli.adapt import INACCURATE

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"


def _points(cb, rng, random=300, per_face=4):
    """Random points of the box, points on each of its faces, and its corners: a list of dicts."""
    coords = cb.coordinates
    points = [{c.name: rng.uniform(*c.domain) for c in coords} for _ in range(random)]
    for face, end in itertools.product(coords, (0, 1)):
        for _ in range(per_face):
            p = {c.name: rng.uniform(*c.domain) for c in coords}
            p[face.name] = face.domain[end]
            points.append(p)
    points += [{c.name: c.domain[e] for c, e in zip(coords, ends)} for ends in itertools.product((0, 1), repeat=len(coords))]
    return points


def _piecewise_ivp(rhs, y0, t, breaks):
    """y(t) of y' = rhs(s, y) from 0, integrated separately between the switch times ``breaks``."""
    y = np.asarray(y0, dtype=float)
    start = 0.0
    for end in [b for b in breaks if b < t] + [t]:
        if end > start:
            y = solve_ivp(rhs, (start, end), y, method="DOP853", rtol=1e-10, atol=1e-12).y[:, -1]
        start = end
    return y


def _road(s, y, k, c):
    ramp = 0.2 * min(max(s - 1.0, 0.0), 0.5)
    return [y[1], -k * (y[0] - ramp) - c * y[1]]


def _road_error(cb, p):
    ref = _piecewise_ivp(lambda s, y: _road(s, y, p["k"], p["c"]), [0.0, 0.0], p["t"], [1.0, 1.5])
    got = cb(**p)
    return max(abs(float(got["y"]) - ref[0]), abs(float(got["v"]) - ref[1]))


@pytest.mark.slow
def test_road_ramp_is_within_its_tolerance_with_slabs_at_the_kinks():
    problem = pgdcli.load_spec(PROBLEMS / "road_ramp.yaml")
    result = pgdcli.solve(problem)
    assert result.accurate, result.message
    cb = result.codebook
    breakpoints = cb.coordinate("t").breakpoints
    assert any(abs(b - 1.0) < 1e-12 for b in breakpoints) and any(abs(b - 1.5) < 1e-12 for b in breakpoints)
    worst = max(_road_error(cb, p) for p in _points(cb, np.random.default_rng(7)))
    assert worst <= problem.solver.tolerance, worst


@pytest.mark.slow
def test_the_gate_refuses_a_codebook_that_interpolates_across_the_kinks():
    text = (PROBLEMS / "road_ramp.yaml").read_text() + "  time_slabs: 1\n  max_nodes: 17\n"
    result = pgdcli.solve(pgdcli.parse_spec(text, source="road_ramp.yaml"))
    assert result.status == INACCURATE and result.message.startswith("tolerance not met"), result.message
    rep = result.codebook.report
    where = {k: float(v) for k, v in (kv.split("=") for kv in rep["check_where"].split(", "))}
    true = _road_error(result.codebook, where)
    assert true == pytest.approx(rep["check_error"], rel=1e-3)  # the error the message names is the true one
    assert true > 1e-6  # the tolerance of road_ramp.yaml


def test_two_rates_matches_its_closed_form_and_solve_ivp():
    problem = pgdcli.load_spec(PROBLEMS / "two_rates.yaml")
    result = pgdcli.solve(problem)
    assert result.accurate, result.message
    cb = result.codebook
    points = _points(cb, np.random.default_rng(8))
    arrays = {name: np.array([p[name] for p in points]) for name in points[0]}
    got = cb(**arrays)["u"]
    u0, t = arrays["u0"], arrays["t"]
    exact = np.where(u0 > 0, u0 * np.exp(-arrays["k"] * t), u0 * np.exp(-arrays["c"] * t))
    assert np.max(np.abs(got - exact)) <= problem.solver.tolerance
    for p, value in zip(points[:40], got[:40]):
        rate = p["k"] if p["u0"] > 0 else p["c"]
        ref = solve_ivp(lambda s, y: [-rate * y[0]], (0, p["t"]), [p["u0"]], method="DOP853", rtol=1e-10,
                        atol=1e-12).y[0, -1]
        assert abs(value - ref) <= problem.solver.tolerance


def test_switch_points_of_parameters_become_element_boundaries():
    text = """
coordinates:
  t: {domain: [0, 1]}
  a: {domain: [0, 1]}
  b: {domain: [-1, 1], elements: 2}
unknowns:
  u: {initial: 0}
equations:
  - "der(u) = -u + min(a, 0.3) + where(b**2 < 0.25, 1, 0) + max(t - a, 0)"
"""
    problem = pgdcli.parse_spec(text, source="switches.yaml")
    assert problem.coordinate("a").breakpoints == pytest.approx((0.0, 0.3, 1.0), abs=1e-12)
    assert problem.coordinate("b").breakpoints == pytest.approx((-1.0, -0.5, 0.0, 0.5, 1.0), abs=1e-12)
    assert problem.coordinate("t").breakpoints == ()  # max(t - a, 0) switches along a line: left to resolution


#: A nonlinear problem (the march) with a jump (where) and a kink (max) in time.
MARCHED = """
coordinates:
  t: {domain: [0, 2]}
  k: {domain: [0.5, 2]}
unknowns:
  u: {initial: 1}
equations:
  - "der(u) = -k*u**2 + where(t < 0.7, 0, 1) + max(t - 1.3, 0)"
solver:
  tolerance: 1e-7
"""


def _marched_reference(t, k, a=1.3):
    f = lambda s, u: [-k * u[0] ** 2 + (0.0 if s < 0.7 else 1.0) + max(s - a, 0.0)]
    return _piecewise_ivp(f, [1.0], t, sorted([0.7, a]))[0]


def test_the_march_ends_steps_at_switches_of_time():
    result = pgdcli.solve(pgdcli.parse_spec(MARCHED, source="marched.yaml"))
    assert result.accurate, result.message
    cb = result.codebook
    breakpoints = np.array(cb.coordinate("t").breakpoints)
    for switch in (0.7, 1.3):  # each ends a time slab, just before the switch
        assert np.min(np.abs(breakpoints - switch)) < 1e-12, switch
    worst = max(abs(float(cb(**p)["u"]) - _marched_reference(p["t"], p["k"]))
                for p in _points(cb, np.random.default_rng(9)))
    assert worst <= 1e-7, worst


@pytest.mark.slow
def test_a_switch_along_a_line_of_time_and_a_parameter_is_located_and_measured():
    """max(t - a, 0) switches at t = a: every node of a gets a time slab there, and the codebook,
    which interpolates across the line in a, is within its tolerance or refused with its true error."""
    text = MARCHED.replace("max(t - 1.3, 0)", "max(t - a, 0)").replace(
        "k: {domain: [0.5, 2]}", "k: {domain: [0.5, 2]}\n  a: {domain: [0.9, 1.6]}")
    result = pgdcli.solve(pgdcli.parse_spec(text, source="line.yaml"))
    cb = result.codebook
    breakpoints = np.array(cb.coordinate("t").breakpoints)
    assert all(np.min(np.abs(breakpoints - a)) < 1e-12 for a in cb.coordinate("a").basis().nodes)
    if result.accurate:
        worst = max(abs(float(cb(**p)["u"]) - _marched_reference(p["t"], p["k"], p["a"]))
                    for p in _points(cb, np.random.default_rng(9)))
        assert worst <= 1e-7, worst
        return
    assert result.status == INACCURATE, result.message
    where = {k: float(v) for k, v in (kv.split("=") for kv in cb.report["check_where"].split(", "))}
    true = abs(float(cb(**where)["u"]) - _marched_reference(where["t"], where["k"], where["a"]))
    assert true == pytest.approx(cb.report["check_error"], rel=1e-3) and true > 1e-7


def test_a_switch_of_the_unknowns_is_not_located_and_the_march_says_why(tmp_path):
    text = """
coordinates:
  t: {domain: [0, 1.5]}
  a: {domain: [0.5, 1]}
unknowns:
  u: {initial: a}
equations:
  - "der(u) = -1 + 0.5*step(0.25 - u)"
"""
    result = pgdcli.solve(pgdcli.parse_spec(text, source="jump.yaml"))
    assert not result.accurate or result.codebook is None or result.status != 0
    assert "step(0.25 - u) has a kink or a jump" in result.message, result.message


#: A stiff relaxation (rates up to 5000) whose forcing jumps at t = 1.7, with a switching function of
#: the unknown in its exact Jacobian (min(u, 3) stays u: no switch along the trajectories).
STIFF_JUMP = """
coordinates:
  t: {domain: [0, 3]}
  k: {domain: [1000, 5000]}
unknowns:
  u: {initial: 2}
equations:
  - "der(u) = -k*(u - cos(t)) - u**3 + cos(t)**3 + 0.5*k*step(t - 1.7) - 0.1*min(u, 3)"
solver:
  tolerance: 1e-5
"""


@pytest.mark.slow
def test_a_stiff_march_with_rodas4_ends_its_steps_at_a_switch_of_time():
    result = pgdcli.solve(pgdcli.parse_spec(STIFF_JUMP, source="stiff_jump.yaml"))
    assert result.accurate, result.message
    cb = result.codebook
    assert cb.report["integrator"] == "rodas4", cb.report["integrator_reason"]
    assert np.min(np.abs(np.array(cb.coordinate("t").breakpoints) - 1.7)) < 1e-12
    rng = np.random.default_rng(11)
    points = [{"t": t, "k": k} for t, k in zip(rng.uniform(0, 3, 40), rng.uniform(1000, 5000, 40))]
    points += [{"t": t, "k": k} for t in (1.7 - 1e-3, 1.7 + 1e-3, 3.0) for k in (1000.0, 5000.0)]
    for p in points:
        k = p["k"]
        f = lambda s, u: [-k * (u[0] - np.cos(s)) - u[0] ** 3 + np.cos(s) ** 3 + (0.5 * k if s >= 1.7 else 0.0)
                          - 0.1 * min(u[0], 3.0)]
        y, start = np.array([2.0]), 0.0
        for end in [e for e in (1.7,) if e < p["t"]] + [p["t"]]:
            y = solve_ivp(f, (start, end), y, method="Radau", rtol=1e-11, atol=1e-13).y[:, -1]
            start = end
        assert abs(float(cb(**p)["u"]) - y[0]) <= 1e-5, p

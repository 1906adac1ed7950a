"""Events: event times stored with the codebook, within the tolerance of independent references.

A ball thrown up from a height without drag has closed-form event times (its landing is the root of a
quadratic: not a polynomial in the height, so the event needs more nodes than the solution); the
shipped ``problems/landing.yaml`` (quadratic drag, a nonlinear march) is checked against solve_ivp's
own event location at tight tolerances, computed here, at random points, faces and corners.
"""

from __future__ import annotations

import dataclasses
import itertools
import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp

import pgdcli
from pgdcli.algorithms.events import first_crossings
from pgdcli.algorithms.outcome import Status
from pgdcli.checks.events import check_events
from pgdcli.cli.main import cli
from pgdcli.codebook.events import EventTime
from pgdcli.problem.spec import load_spec, parse_spec

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"
G = 9.81

DROP = """
name: drop
coordinates:
  t: {domain: [0, 1.5]}
  h: {domain: [0, 2]}
  v0: {domain: [1, 5]}
unknowns:
  y: {initial: h}
  v: {initial: v0}
equations:
  - "der(y) = v"
  - "der(v) = -9.81"
events:
  landing: {when: "y = 0", direction: falling}
  apex: "v = 0"
  low: {when: "y = 0.5*h", direction: rising}
solver:
  tolerance: 1.0e-6
"""


def _landing(h, v0):
    return (v0 + np.sqrt(v0 ** 2 + 2 * G * h)) / G


@pytest.fixture(scope="module")
def drop():
    problem = parse_spec(DROP.replace("  low: {when: \"y = 0.5*h\", direction: rising}\n", ""), source="drop.yaml")
    return problem, pgdcli.solve(problem)


def _box(domains: dict, n: int, seed: int) -> dict:
    rng = np.random.default_rng(seed)
    cols = {k: rng.uniform(lo, hi, n) for k, (lo, hi) in domains.items()}
    corners = np.array(list(itertools.product(*domains.values())))
    return {k: np.concatenate([v, corners[:, j]]) for j, (k, v) in enumerate(cols.items())}


def test_drop_event_times_match_the_closed_form(drop):
    problem, result = drop
    assert result.converged and result.accurate, result.message
    cb = result.codebook
    p = _box({"h": (0, 2), "v0": (1, 5)}, 400, 3)
    times = cb.event_times(p)
    assert np.abs(times["landing"] - _landing(p["h"], p["v0"])).max() <= 1e-6
    assert np.abs(times["apex"] - p["v0"] / G).max() <= 1e-6
    # the landing time's square root needs nodes the polynomial solution does not
    landing = cb.events["landing"]
    assert landing.coordinates[1].nodes > cb.coordinate("h").nodes
    assert cb.report["events"] == "landing,apex" and np.all(cb.report["event_ratios"] <= 1)


def test_a_condition_met_at_the_start_is_not_an_event_there(drop):
    problem, result = drop
    # h = 0: y(0) = 0 exactly; the ball lands at 2 v0 / g, not at t = 0
    t = first_crossings(problem, result.codebook, problem.events[0], {"h": np.zeros(3), "v0": np.array([1.0, 3, 5])})
    np.testing.assert_allclose(t, 2 * np.array([1.0, 3, 5]) / G, atol=1e-7)


def test_direction_selects_the_crossing():
    problem = parse_spec(DROP, source="drop.yaml")
    cb = pgdcli.solve(problem).codebook
    # y = h/2 from below never happens first: y starts at h and rises, then falls through h/2 (falling)
    rising = problem.events[2]
    falling = dataclasses.replace(rising, direction="falling")
    h, v0 = np.array([1.0, 2.0]), np.array([2.0, 4.0])
    assert np.isnan(first_crossings(problem, cb, rising, {"h": h, "v0": v0})).all()
    expected = (v0 + np.sqrt(v0 ** 2 + G * h)) / G  # h + v0 t - g t^2 / 2 = h / 2
    np.testing.assert_allclose(first_crossings(problem, cb, falling, {"h": h, "v0": v0}), expected, atol=1e-7)


def test_an_event_missing_somewhere_is_refused_with_the_point(write_spec):
    text = DROP.replace("[0, 1.5]", "[0, 0.5]")
    result = pgdcli.solve(parse_spec(text, source="short.yaml"))
    assert not result.converged and result.status == Status.FAILED
    assert "event 'landing' (y = 0) does not happen before t=0.5 at h=" in result.message
    path = write_spec(text)
    run = CliRunner().invoke(cli, ["solve", str(path), "-o", str(path.with_suffix(".h5"))], prog_name="pgd")
    assert run.exit_code == 1 and not path.with_suffix(".h5").exists()
    assert "does not happen before t=0.5" in run.output


def test_the_check_catches_a_wrong_event_time(drop):
    problem, result = drop
    cb = result.codebook
    event = cb.events["apex"]
    cores = [c.copy() for c in event.field.cores]
    cores[-1] = cores[-1] * (1 + 1e-4)  # every apex time 1e-4 relative off
    wrong = cb.with_events({**cb.events, "apex": EventTime(event.when, event.direction, event.coordinates,
                                                           type(event.field)(cores, event.field.mode_order))})
    checks = {c.name: c for c in check_events(problem, wrong, tolerance=1e-6)}
    assert checks["landing"].accurate and not checks["apex"].accurate
    assert checks["apex"].ratio > 10


def test_events_survive_save_and_load(drop, tmp_path):
    _, result = drop
    path = tmp_path / "drop.h5"
    result.codebook.save(path)
    back = pgdcli.Codebook.load(path)
    assert back.format_version == "1.3" and list(back.events) == ["landing", "apex"]
    p = {"h": np.array([0.3, 1.7]), "v0": np.array([1.5, 4.5])}
    for name in ("landing", "apex"):
        np.testing.assert_array_equal(back.event_times(p)[name], result.codebook.event_times(p)[name])
    assert back.info()["events"]["landing"]["when"] == "y = 0"


def test_query_event_prints_times_and_refuses_bad_options(drop, tmp_path):
    _, result = drop
    path = tmp_path / "drop.h5"
    result.codebook.save(path)
    runner = CliRunner()
    run = runner.invoke(cli, ["query", str(path), "--event", "landing", "--event", "apex", "--h", "1",
                              "--v0", "2,4", "--format", "json"], prog_name="pgd")
    assert run.exit_code == 0, run.output
    rows = json.loads(run.stdout)
    assert [r["v0"] for r in rows] == [2.0, 4.0]
    for r in rows:
        assert abs(r["landing"] - _landing(1.0, r["v0"])) <= 1e-6 and abs(r["apex"] - r["v0"] / G) <= 1e-6
    for args, message in [
        (["--event", "fall", "--h", "1", "--v0", "2"], "unknown event 'fall'"),
        (["--event", "landing", "--h", "1", "--v0", "2", "--t", "1"], "unknown coordinate '--t'"),
        (["--event", "landing", "--h", "1", "--v0", "9"], "outside the domain"),
        (["--event", "landing", "--field", "y", "--h", "1", "--v0", "2"], "give one of them"),
    ]:
        bad = runner.invoke(cli, ["query", str(path), *args], prog_name="pgd")
        assert bad.exit_code == 2 and message in bad.output, bad.output
        assert "Traceback" not in bad.output


def test_query_event_on_a_codebook_without_events(tmp_path, solved):
    path = tmp_path / "plain.h5"
    solved("parametric").codebook.save(path)
    bad = CliRunner().invoke(cli, ["query", str(path), "--event", "x", "--k", "1"], prog_name="pgd")
    assert bad.exit_code == 2 and "records no events" in bad.output


def _reference_landing(v0: float, c: float) -> tuple[float, float]:
    def rhs(t, s):
        return [s[1], -G - c * s[1] * abs(s[1])]

    def landing(t, s):
        return s[0]

    def apex(t, s):
        return s[1]

    landing.direction = -1
    sol = solve_ivp(rhs, (0, 2.5), [0.0, v0], method="DOP853", rtol=1e-12, atol=1e-14, events=[landing, apex])
    return sol.t_events[0][sol.t_events[0] > 1e-9][0], sol.t_events[1][0]


@pytest.mark.slow
def test_shipped_landing_within_tolerance_against_solve_ivp():
    result = pgdcli.solve(load_spec(PROBLEMS / "landing.yaml"))
    assert result.converged and result.accurate, result.message
    p = _box({"v0": (5, 10), "c": (0.0, 0.2)}, 300, 5)
    rng = np.random.default_rng(6)
    faces = {"v0": np.r_[np.full(8, 5.0), np.full(8, 10.0), rng.uniform(5, 10, 16)],
             "c": np.r_[rng.uniform(0, 0.2, 16), np.zeros(8), np.full(8, 0.2)]}
    p = {k: np.concatenate([p[k], faces[k]]) for k in p}
    got = result.codebook.event_times(p)
    ref = np.array([_reference_landing(a, b) for a, b in zip(p["v0"], p["c"])])
    assert np.abs(got["landing"] - ref[:, 0]).max() <= 1e-6
    assert np.abs(got["apex"] - ref[:, 1]).max() <= 1e-6


def test_a_slow_crossing_is_held_to_the_solutions_tolerance():
    # u = exp(-1e-4 k t) passes 0.5 at ln 2 / (1e-4 k), with |du/dt| = 5e-5 k there: an error of 1e-6 in u
    # moves the crossing by up to 0.02 in time, so the event time is promised to that (the state's tolerance)
    text = """
coordinates:
  t: {domain: [0, 10000]}
  k: {domain: [1, 2]}
unknowns:
  u: {initial: 1}
equations:
  - "der(u) = -1e-4*k*u"
events:
  half: "u = 0.5"
solver:
  tolerance: 1.0e-6
"""
    result = pgdcli.solve(parse_spec(text, source="slow.yaml"))
    assert result.converged and result.accurate, result.message
    k = np.r_[np.linspace(1, 2, 101), np.random.default_rng(2).uniform(1, 2, 300)]
    got = result.codebook.event_times({"k": k})["half"]
    exact = np.log(2) / (1e-4 * k)
    allowed = 1e-6 / (5e-5 * k)  # the time an error of 1e-6 in u moves the crossing
    assert np.all(np.abs(got - exact) <= allowed)
    # and the state of the exact solution at the stored time is within the tolerance of 0.5
    assert np.abs(np.exp(-1e-4 * k * got) - 0.5).max() <= 1e-6


def test_verify_checks_the_event_times_and_fails_a_wrong_one(drop, tmp_path):
    _, result = drop
    cb = result.codebook
    good, bad = tmp_path / "good.h5", tmp_path / "bad.h5"
    cb.save(good)
    event = cb.events["landing"]
    cores = [c.copy() for c in event.field.cores]
    cores[-1] = cores[-1] * (1 + 1e-4)  # every landing 1e-4 of itself late
    cb.with_events({**cb.events, "landing": EventTime(event.when, event.direction, event.coordinates,
                                                      type(event.field)(cores, event.field.mode_order))}).save(bad)
    report = pgdcli.verify(good, samples=16)
    assert report.passed() and set(report.events) == {"landing", "apex"}
    assert report.to_dict()["events"]["landing"]["tolerance_ratio"] <= 1
    run = CliRunner().invoke(cli, ["verify", str(bad), "--samples", "16"], prog_name="pgd")
    assert run.exit_code == 1 and "verification failed: event landing: time error 1." in run.output, run.output

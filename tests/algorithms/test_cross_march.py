"""The cross march (pgdcli.algorithms.cross_march): trajectories at the nodes a tensor-train cross
names, marched with a pilot's steps (pgdcli.algorithms.grid_steps).

The arrays at chosen nodes must equal the whole grid's at those nodes; a replay of the pilot's steps
must reproduce the pilot's states; codebooks built by the cross must be within the tolerance of
scipy's solve_ivp (DOP853, rtol = atol = 1e-12, written here in numpy) at random points off the grid.
"""

from __future__ import annotations

import numpy as np
import pytest
from conftest import PROBLEMS
from scipy.integrate import solve_ivp

import pgdcli
from pgdcli import load_spec, parse_spec
from pgdcli.errors import SpecError
from pgdcli.algorithms import cross_march, grid_steps
from pgdcli.algorithms.outcome import Learned
from pgdcli.algorithms.march import compile_system

# a forced Duffing oscillator with a stiffness, a damping, a forcing frequency and an initial position as
# coordinates: parameter-dependent and time-dependent coefficients, 10 x 8 x 12 x 8 nodes
DUFFING = """
name: duffing4
coordinates:
  t: {domain: [0, 3]}
  k: {domain: [1, 2], nodes: 10}
  c: {domain: [0.1, 0.4], nodes: 8}
  w: {domain: [0.8, 1.4], nodes: 12}
  x0: {domain: [-0.5, 0.5], nodes: 8}
unknowns:
  x: {initial: x0}
  v: {initial: 0}
equations:
  - "der(x) = v"
  - "der(v) = -k*x - c*v - 0.5*x**3 + 0.4*cos(w*t)"
solver:
  tolerance: 1e-5
  march: cross
"""


# an exothermic stirred tank: an Arrhenius rate exp(-E/T) (a function of an unknown), nodes left to the solver
CSTR = """
name: cstr
coordinates:
  t: {domain: [0, 3]}
  k0: {domain: [5, 10]}
  E: {domain: [1.5, 2.5]}
  q: {domain: [0.5, 1.5]}
  c0: {domain: [0.2, 1.0]}
unknowns:
  c: {initial: c0}
  T: {initial: 1}
equations:
  - "der(c) = q*(1 - c) - k0*exp(-E/T)*c"
  - "der(T) = q*(1 - T) + 0.5*k0*exp(-E/T)*c - 0.3*(T - 1)"
solver:
  tolerance: 1e-6
  march: cross
"""


def duffing_rhs(k, c, w):
    return lambda t, y: [y[1], -k * y[0] - c * y[1] - 0.5 * y[0] ** 3 + 0.4 * np.cos(w * t)]


@pytest.mark.parametrize("source", ["coupled", "duffing", "cstr"])
def test_rhs_at_chosen_nodes_equals_the_whole_grids(source):
    specs = {"duffing": DUFFING, "cstr": CSTR.replace("{domain: [", "{nodes: 5, domain: [").replace(
        "t: {nodes: 5, domain: [", "t: {domain: [")}
    problem = parse_spec(specs[source], source="d.yaml") if source in specs else load_spec(PROBLEMS / "coupled.yaml")
    system = compile_system(problem, 1e-8)
    rng = np.random.default_rng(2)
    whole = grid_steps.GridRhs(system)
    y = rng.uniform(-1.0, 1.0, size=(len(system.unknowns), int(np.prod(system.shape))))
    indices = np.stack([rng.integers(0, n, size=50) for n in system.shape], axis=1)
    chosen = grid_steps.GridRhs(system, indices)
    flat = np.ravel_multi_index(tuple(indices.T), system.shape)
    for t in (0.0, 0.7):
        np.testing.assert_allclose(chosen(t, y[:, flat]), whole(t, y)[:, flat], rtol=1e-13, atol=1e-13)

    def whole_rhs_at(t):
        return whole(t, y)[:, flat]

    start = grid_steps.initial_values(system)[:, flat]  # products in another order: equal to rounding
    np.testing.assert_allclose(grid_steps.initial_values(system, indices), start, rtol=1e-14, atol=1e-15)
    functions = grid_steps.NodeFunctions(system)
    np.testing.assert_allclose(grid_steps.initial_values(system, indices, functions), start, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(grid_steps.GridRhs(system, indices, functions)(0.3, y[:, flat]), whole_rhs_at(0.3),
                               rtol=1e-13, atol=1e-13)


def test_replay_reproduces_the_pilot():
    system = compile_system(parse_spec(DUFFING, source="d.yaml"), 1e-6)
    indices = np.stack([np.arange(6), np.arange(6)[::-1], np.zeros(6, int), np.arange(6)], axis=1)
    kept: list = []
    rhs = grid_steps.GridRhs(system, indices)
    schedule = grid_steps.advance(system, rhs, grid_steps.initial_values(system, indices), 1e-6, kept.extend,
                                  slab_nodes=6)
    replayed = grid_steps.replay(grid_steps.GridRhs(system, indices[::-1]),
                                 grid_steps.initial_values(system, indices[::-1]), schedule)
    assert replayed.shape == (len(schedule.times), 2, 6)
    np.testing.assert_allclose(replayed[:, :, ::-1], np.stack(kept), rtol=1e-14, atol=1e-14)


def test_cross_codebook_against_solve_ivp_off_the_grid():
    result = pgdcli.solve(parse_spec(DUFFING, source="duffing4.yaml"))
    assert result.converged, result.message
    report = result.codebook.report
    assert report["march"] == "cross"
    assert report["cross_trajectories"] > 0 and report["pilot_points"] > 0
    rng = np.random.default_rng(8)
    times = np.linspace(0.0, 3.0, 13)
    worst = 0.0
    for _ in range(25):
        k, c, w, x0 = rng.uniform([1, 0.1, 0.8, -0.5], [2, 0.4, 1.4, 0.5])
        ref = solve_ivp(duffing_rhs(k, c, w), (0.0, 3.0), [x0, 0.0], method="DOP853", rtol=1e-12, atol=1e-12,
                        t_eval=times)
        got = result.codebook(t=times, k=k, c=c, w=w, x0=x0)
        worst = max(worst, float(np.max(np.abs(np.asarray(got["x"]).reshape(-1) - ref.y[0]))),
                    float(np.max(np.abs(np.asarray(got["v"]).reshape(-1) - ref.y[1]))))
    assert worst <= 1e-5


@pytest.mark.slow
def test_the_10d_rigid_body_against_solve_ivp_off_the_grid():
    """problems/rigid_body10.yaml: 10^9 grid nodes, built by the cross (~40 s), at random points of its box."""
    result = pgdcli.solve(load_spec(PROBLEMS / "rigid_body10.yaml"))
    assert result.converged, result.message
    assert result.codebook.report["march"] == "cross"
    mass, j, fg3 = 1.0 + np.array([0.2, 0.5, 0.8]), np.array([0.1, 0.2, 0.3]), -0.5

    def kirchhoff(inertia):
        def f(t, y):
            u, w = y[:3], y[3:]
            du = (np.cross(mass * u, w) + [0.0, 0.0, fg3]) / mass
            dw = (np.cross((j + inertia) * w, w) + np.cross((mass - 1.0) * u, u)) / (j + inertia)
            return np.concatenate([du, dw])
        return f

    rng = np.random.default_rng(4)
    times = np.linspace(0.0, 1.0, 11)
    names = ["u1", "u2", "u3", "w1", "w2", "w3"]
    worst = 0.0
    for _ in range(30):
        y0 = rng.uniform(0.5, 1.5, 6)
        inertia = rng.uniform([0.8, 1.3, 1.8], [1.2, 1.7, 2.2])
        ref = solve_ivp(kirchhoff(inertia), (0.0, 1.0), y0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=times)
        point = dict(zip(["u10", "u20", "u30", "w10", "w20", "w30", "I1", "I2", "I3"], [*y0, *inertia]))
        got = result.codebook(t=times, **point)
        for i, name in enumerate(names):
            worst = max(worst, float(np.max(np.abs(np.asarray(got[name]).reshape(-1) - ref.y[i]))))
    assert worst <= 1e-5


def test_a_function_of_the_unknowns_through_the_cross_against_solve_ivp():
    result = pgdcli.solve(parse_spec(CSTR, source="cstr.yaml"))
    assert result.converged, result.message
    assert result.codebook.report["march"] == "cross"
    rng = np.random.default_rng(99)
    times = np.linspace(0.0, 3.0, 13)
    worst = 0.0
    for _ in range(25):
        k0, e, q, c0 = rng.uniform([5, 1.5, 0.5, 0.2], [10, 2.5, 1.5, 1.0])

        def f(t, y):
            rate = k0 * np.exp(-e / y[1]) * y[0]
            return [q * (1 - y[0]) - rate, q * (1 - y[1]) + 0.5 * rate - 0.3 * (y[1] - 1)]

        ref = solve_ivp(f, (0.0, 3.0), [c0, 1.0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=times)
        got = result.codebook(t=times, k0=k0, E=e, q=q, c0=c0)
        worst = max(worst, *(float(np.max(np.abs(np.asarray(got[n]).reshape(-1) - ref.y[i])))
                             for i, n in enumerate(["c", "T"])))
    assert worst <= 1e-6


def test_a_blow_up_in_part_of_the_grid_is_a_clear_failure():
    spec = DUFFING.replace('"der(v) = -k*x - c*v - 0.5*x**3 + 0.4*cos(w*t)"', '"der(v) = k*x**4"').replace(
        "x0: {domain: [-0.5, 0.5]", "x0: {domain: [0.5, 3]")
    result = pgdcli.solve(parse_spec(spec, source="blow.yaml"))
    assert not result.converged
    assert "blows up" in result.message or "underflow" in result.message
    assert "x0=" in result.message  # where: a node of the grid


def test_cross_is_a_march_the_spec_accepts():
    with pytest.raises(SpecError, match="cross"):
        parse_spec(DUFFING.replace("march: cross", "march: crosss"), source="d.yaml")
    assert "cross" in cross_march.__all__[1]


def test_auto_gives_a_grid_the_cross_first_and_the_grid_march_what_it_left(monkeypatch):
    from pgdcli.algorithms import march

    spec = DUFFING.replace("  march: cross\n", "")
    monkeypatch.setattr(march, "CROSS_FIRST_VALUES", 1000)  # the 7680 x 2 values of DUFFING
    result = pgdcli.solve(parse_spec(spec, source="duffing4.yaml"))
    assert result.converged and result.codebook.report["march"] == "cross"
    monkeypatch.setattr(march, "CROSS_BUDGET", 0)  # no trajectory allowed: the first half sweep ends it
    result = pgdcli.solve(parse_spec(spec, source="duffing4.yaml"))
    assert result.converged and result.codebook.report["march"] == "grid"
    assert "more than the budget of 0" in result.codebook.report["cross_abandoned"]


def test_a_cross_abandoned_in_one_solve_is_not_tried_again_in_the_next(monkeypatch):
    """What a solve of the automatic resolution learned (``learned``) sends the next one to the grid march."""
    from pgdcli.algorithms import march

    problem = parse_spec(DUFFING.replace("  march: cross\n", ""), source="duffing4.yaml")
    monkeypatch.setattr(march, "CROSS_FIRST_VALUES", 1000)
    monkeypatch.setattr(march, "CROSS_BUDGET", 0)
    crosses = []
    real = march.march_by_cross
    monkeypatch.setattr(march, "march_by_cross", lambda *a, **k: crosses.append(1) or real(*a, **k))
    first = march.solve_march(problem, 1e-6)
    learned = Learned().after(first)
    assert first.converged and first.codebook.report["march"] == "grid" and len(crosses) == 1
    assert "more than the budget of 0" in learned.cross_abandoned
    second = march.solve_march(problem, 1e-6, learned=learned)
    assert second.converged and second.codebook.report["march"] == "grid" and len(crosses) == 1
    assert second.codebook.report["cross_abandoned"].startswith("in an earlier solve of the automatic resolution")
    for u in ("x", "v"):  # the same grid march, with or without the cross before it
        assert np.array_equal(first.codebook.fields[u].cores[1], second.codebook.fields[u].cores[1])
    march.solve_march(problem, 1e-6)  # nothing learned: the cross is tried
    assert len(crosses) == 2


def test_info_tells_how_the_cross_march_built_it(tmp_path):
    from click.testing import CliRunner

    from pgdcli.cli.main import cli

    path = tmp_path / "duffing4.h5"
    pgdcli.solve(parse_spec(DUFFING, source="duffing4.yaml")).codebook.save(path)
    result = CliRunner().invoke(cli, ["info", str(path)])
    assert result.exit_code == 0, result.output
    assert "march: the cross of trajectories (cross march):" in result.output
    summary = CliRunner().invoke(cli, ["info", str(path), "--format", "json"])
    import json

    cross = json.loads(summary.stdout)["cross_march"]
    assert cross["trajectories"] > 0 and cross["sweeps"] >= 1 and cross["error"] <= 1e-6


def test_nodes_the_pilot_missed_join_it(monkeypatch):
    """A pilot kept away from the blow-up (u0 <= 1.5): the cross's trajectories at u0 = 3 overflow, join
    the pilot, and the new pilot names the blow-up where it is."""
    spec = """
name: late
coordinates:
  t: {domain: [0, 0.6]}
  u0: {domain: [0.2, 3], nodes: 12}
  k: {domain: [0.5, 1], nodes: 12}
unknowns:
  u: {initial: u0}
equations:
  - "der(u) = k*u**2"
solver:
  tolerance: 1e-6
  march: cross
"""
    problem = parse_spec(spec, source="late.yaml")
    nodes = compile_system(problem, 1e-6).bases["u0"].nodes
    safe = np.flatnonzero(nodes <= 1.5)
    pilots = []

    def pilot_indices(shape, rng):
        found = np.stack(np.meshgrid(safe, np.arange(shape[1]), indexing="ij"), axis=-1).reshape(-1, 2)
        pilots.append(found)
        return found

    monkeypatch.setattr(cross_march, "_pilot_indices", pilot_indices)
    result = pgdcli.solve(problem)
    assert len(pilots) == 1  # the pilot ran again from the nodes that overflowed, not from a new draw
    assert not result.converged
    assert "blows up" in result.message
    import re

    assert float(re.search(r"near u0=([0-9.]+)", result.message).group(1)) > 2.0  # where the pilot never was

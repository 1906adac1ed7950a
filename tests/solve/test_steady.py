"""Steady problems: no time coordinate, Dirichlet lift, against exact solutions and the
independent collocation reference."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

import pgdcli
from conftest import codebook_points, assert_solved, spec_text
from pgdcli.cli.main import cli
from pgdcli.errors import SolverError, SpecError
from pgdcli.checks.reference import solve_reference, solve_reference_pde


def poisson_exact(x, y, a, g, q):
    s = np.pi / np.sqrt(a)
    return (g * np.sin(np.pi * x) * np.sinh(s * y) / np.sinh(s)
            + q * np.sin(np.pi * x) * np.sin(np.pi * y) / (np.pi**2 * (1 + a)))


@pytest.fixture(scope="module")
def poisson():
    return pgdcli.solve(pgdcli.load_spec("problems/poisson.yaml"))


def _solve(text, source="steady.yaml"):
    result = pgdcli.solve(pgdcli.parse_spec(text, source=source))
    assert_solved(result)
    return result


def test_poisson_is_steady_with_space_and_parameter_coordinates(poisson):
    problem = pgdcli.load_spec("problems/poisson.yaml")
    assert problem.time is None and problem.steady and problem.time_coordinate is None
    assert [c.role for c in poisson.codebook.coordinates] == ["space", "space", "parameter", "parameter", "parameter"]
    assert poisson.converged, poisson.message
    assert poisson.warnings == []


def test_poisson_matches_the_exact_solution(poisson):
    cb = poisson.codebook
    p = codebook_points(cb, 1000, 1)
    error = np.abs(cb(**p)["u"] - poisson_exact(p["x"], p["y"], p["a"], p["g"], p["q"]))
    assert np.max(error) <= 1e-9


def test_poisson_dirichlet_values_hold_on_the_boundary(poisson):
    cb = poisson.codebook
    rng = np.random.default_rng(2)
    s, a, g, q = (rng.uniform(0, 1, 60), rng.uniform(0.5, 2, 60), rng.uniform(-1, 1, 60), rng.uniform(0, 4, 60))
    for side in ({"x": 0.0, "y": s}, {"x": 1.0, "y": s}, {"x": s, "y": 0.0}):
        assert np.max(np.abs(cb(**side, a=a, g=g, q=q)["u"])) <= 1e-13
    top = cb(x=s, y=1.0, a=a, g=g, q=q)["u"]
    assert np.max(np.abs(top - g * np.sin(np.pi * s))) <= 1e-13


def test_dirichlet_on_every_side_with_values_of_the_other_space_coordinate():
    # u = a (x^2 - y^2) + b x y is harmonic; its boundary values depend on the other space
    # coordinate and on both parameters, and agree at the corners
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 6}', 'y': '{domain: [-1, 2], nodes: 7}', 'a': '{domain: [-1, 1], nodes: 3}', 'b': '{domain: [0, 2], nodes: 3}'},
        unknowns={'u': '\n    boundary:\n      x: {low: "-a*y**2", high: "a*(1 - y**2) + b*y"}\n      y: {low: "a*(x**2 - 1) - b*x", high: "a*(x**2 - 4) + 2*b*x"}'},
        equations=['"der(u, x, 2) + der(u, y, 2) = 0"'],
        solver=' {tolerance: 1e-14}',
    )
    cb = _solve(text).codebook
    p = codebook_points(cb, 500, 3)
    exact = p["a"] * (p["x"] ** 2 - p["y"] ** 2) + p["b"] * p["x"] * p["y"]
    # the nodes represent the polynomial exactly: the error is the solver's (relative residual 1e-14)
    assert np.max(np.abs(cb(**p)["u"] - exact)) <= 1e-12


def test_reaction_with_a_neumann_flux_as_a_coordinate():
    # u'' = c u, u(0) = 1, u'(1) = h: u = cosh(r x) + B sinh(r x), r = sqrt(c)
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 24}', 'c': '{domain: [1, 4], nodes: 16}', 'h': '{domain: [-1, 1], nodes: 2, discretization: linear}'},
        unknowns={'u': '\n    boundary:\n      x: {low: 1, high: {gradient: h}}'},
        equations=['"der(u, x, 2) - c*u = 0"'],
        solver=' {tolerance: 1e-12}',
    )
    cb = _solve(text).codebook
    p = codebook_points(cb, 600, 4)
    r = np.sqrt(p["c"])
    B = (p["h"] / r - np.sinh(r)) / np.cosh(r)
    exact = np.cosh(r * p["x"]) + B * np.sinh(r * p["x"])
    assert np.max(np.abs(cb(**p)["u"] - exact)) <= 1e-10


def test_coupled_steady_system():
    # a simply supported beam as two second-order equations: u'' = v, v'' = -q pi^4 sin(pi x)
    # exact u = -q sin(pi x), v = q pi^2 sin(pi x)
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 22}', 'q': '{domain: [0.5, 2], nodes: 2, discretization: linear}'},
        unknowns={'u': '{boundary: {x: {low: 0, high: 0}}}', 'v': '{boundary: {x: {low: 0, high: 0}}}'},
        equations=['"der(u, x, 2) - v = 0"', '"der(v, x, 2) + q*pi**4*sin(pi*x) = 0"'],
        solver=' {tolerance: 1e-12}',
    )
    cb = _solve(text).codebook
    p = codebook_points(cb, 300, 5)
    out = cb(**p)
    s = np.sin(np.pi * p["x"])
    assert np.max(np.abs(out["u"] + p["q"] * s)) <= 1e-10
    assert np.max(np.abs(out["v"] - p["q"] * np.pi**2 * s)) <= 1e-9


def test_linear_elements_converge_at_second_order():
    # -u'' = k pi^2 sin(pi x) on [0, 1], u = 0 at both ends: u = k sin(pi x)
    def max_error(n):
        text = f"""
coordinates:
  x: {{domain: [0, 1], nodes: {n}, discretization: linear}}
  k: {{domain: [1, 2], nodes: 2, discretization: linear}}
unknowns:
  u: {{boundary: {{x: {{low: 0, high: 0}}}}}}
equations:
  - "der(u, x, 2) + k*pi**2*sin(pi*x) = 0"
solver: {{tolerance: 1e-12}}
"""
        cb = _solve(text).codebook
        x = cb.coordinate("x").basis().nodes
        return float(np.max(np.abs(cb(x=x, k=2.0)["u"] - 2.0 * np.sin(np.pi * x))))

    coarse, fine = max_error(17), max_error(33)
    assert 3.5 < coarse / fine < 4.5  # second order at the nodes (lumped mass)
    assert fine < 2e-3


def test_time_null_makes_a_coordinate_named_t_a_parameter():
    text = """
time: null
coordinates:
  x: {domain: [0, 1], nodes: 12}
  t: {domain: [1, 2], nodes: 3}
unknowns:
  u: {boundary: {x: {low: 0, high: t}}}
equations:
  - "der(u, x, 2) = 0"
"""
    problem = pgdcli.parse_spec(text)
    assert problem.time is None and problem.coordinate("t").role == "parameter"
    cb = pgdcli.solve(problem).codebook
    x = np.linspace(0, 1, 7)
    assert np.max(np.abs(cb(x=x, t=1.5)["u"] - 1.5 * x)) <= 1e-12


STEADY_BASE = """
coordinates:
  x: {domain: [0, 1], nodes: 8}
  k: {domain: [1, 2], nodes: 3}
unknowns:
  u: {boundary: {x: {low: 0, high: 1}}}
equations:
  - "k*der(u, x, 2) + 1 = 0"
"""


@pytest.mark.parametrize(
    "old, new, expected",
    [
        ("  u: {boundary:", "  u: {initial: 0, boundary:",
         "steady.yaml: time: no coordinate is named 't'; add 'time: <name>' naming the time coordinate (coordinates: "
         "x, k), or remove the initial values for a steady problem"),
        ("k*der(u, x, 2) + 1 = 0", "der(u) + k*der(u, x, 2) + 1 = 0",
         "there is no time coordinate to differentiate by"),
        ("  u: {boundary: {x: {low: 0, high: 1}}}\nequations:\n  - \"k*der(u, x, 2) + 1 = 0\"",
         "  u: {}\nequations:\n  - \"k*u + 1 = 0\"", "time: no coordinate is named 't' and no equation has a space"),
    ],
)
def test_steady_spec_errors(old, new, expected):
    with pytest.raises(SpecError) as info:
        pgdcli.parse_spec(STEADY_BASE.replace(old, new), source="steady.yaml")
    message = str(info.value)
    assert expected in message and "\n" not in message


def test_nonlinear_steady_problem_is_refused_with_one_line():
    text = STEADY_BASE.replace("k*der(u, x, 2) + 1 = 0", "k*der(u, x, 2) + u**2 = 0")
    with pytest.raises(SolverError, match="a steady problem .* needs equations linear in the unknowns"):
        pgdcli.solve(pgdcli.parse_spec(text, source="steady.yaml"))


def test_reference_solves_the_steady_problem_directly():
    problem = pgdcli.load_spec("problems/poisson.yaml")
    params = {"a": np.array([0.5, 1.3, 2.0]), "g": np.array([1.0, -0.4, 0.2]), "q": np.array([0.0, 2.5, 4.0])}
    xs, ys = np.linspace(0, 1, 7), np.linspace(0, 1, 5)
    ref = solve_reference_pde(problem, params, {"x": xs, "y": ys}, None, space_nodes=30)
    assert ref.success.all() and ref.values["u"].shape == (3, 7, 5)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    for i in range(3):
        exact = poisson_exact(X, Y, params["a"][i], params["g"][i], params["q"][i])
        assert np.max(np.abs(ref.values["u"][i] - exact)) <= 1e-10
    with pytest.raises(SolverError, match="a steady problem .* takes times=None"):
        solve_reference_pde(problem, params, None, np.array([0.0]))
    scattered = solve_reference(problem, {"x": xs[:3], "y": ys[:3], "a": params["a"], "g": params["g"],
                                          "q": params["q"]}, None, space_nodes=30)
    assert scattered.values["u"].shape == (3,)
    exact = poisson_exact(xs[:3], ys[:3], params["a"], params["g"], params["q"])
    assert np.max(np.abs(scattered.values["u"] - exact)) <= 1e-10


def test_reference_reports_a_singular_steady_system():
    text = STEADY_BASE.replace("x: {low: 0, high: 1}", "x: {low: {gradient: 0}, high: {gradient: 0}}")
    problem = pgdcli.parse_spec(text, source="neumann.yaml")
    ref = solve_reference_pde(problem, {"k": np.array([1.0, 2.0])}, None, None, space_nodes=12)
    assert not ref.success.any()
    assert "singular" in ref.messages[0]


def test_cli_solve_query_verify(tmp_path):
    runner = CliRunner()
    out = tmp_path / "poisson.h5"
    result = runner.invoke(cli, ["solve", "problems/poisson.yaml", "-o", str(out)])
    assert result.exit_code == 0, result.output
    result = runner.invoke(cli, ["query", str(out), "--x", "0.5", "--y", "0.5", "--a", "1", "--g", "1", "--q", "1"])
    assert result.exit_code == 0, result.output
    assert abs(float(result.stdout) - poisson_exact(0.5, 0.5, 1.0, 1.0, 1.0)) <= 1e-10
    result = runner.invoke(cli, ["verify", str(out), "--samples", "3", "--max-error", "1e-9", "--format", "json"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    assert report["passed"] and report["settings"]["method"] == "direct" and report["settings"]["times"] == 0
    assert report["unknowns"]["u"]["max_abs_error"] <= 1e-9
    assert set(report["unknowns"]["u"]["where"]) == {"x", "y", "a", "g", "q"}


def test_cli_refuses_a_nonlinear_steady_problem(tmp_path):
    spec = tmp_path / "bad.yaml"
    spec.write_text(STEADY_BASE.replace("k*der(u, x, 2) + 1 = 0", "k*der(u, x, 2) + u**2 = 0"))
    out = tmp_path / "bad.h5"
    result = CliRunner().invoke(cli, ["solve", str(spec), "-o", str(out)])
    assert result.exit_code == 2
    assert "needs equations linear in the unknowns" in result.output and "Traceback" not in result.output
    assert not out.exists()


def test_plot_data_of_a_steady_codebook_runs_along_space(poisson):
    from pgdcli.plot import error_data, solution_data

    cb = poisson.codebook
    lines = solution_data(cb, at=["a=0.7,g=1,q=3"], points=11)
    assert lines["layout"] == "lines" and lines["time"] == "x" and lines["values"].shape == (1, 11)
    exact = poisson_exact(lines["t"], 0.5, 0.7, 1.0, 3.0)
    assert np.max(np.abs(lines["values"][0] - exact)) <= 1e-9
    error_map = error_data(cb, points=9)  # default map: the two space coordinates
    assert (error_map["x"], error_map["y"]) == ("x", "y") and error_map["values"].shape == (9, 9)
    assert error_map["failures"] == [] and error_map["max"] <= 1e-9
    error_lines = error_data(cb, at=["y=0.3,a=2,g=-1,q=0"], points=7)
    assert error_lines["values"].shape == (1, 7) and error_lines["max"] <= 1e-9


def _advection_diffusion_error(n, discretization):
    # u'' = b u', u(0) = 0, u(1) = 1: u = (exp(b x) - 1) / (exp(b) - 1)
    text = f"""
coordinates:
  x: {{domain: [0, 1], nodes: {n}, discretization: {discretization}}}
  b: {{domain: [0.5, 2], nodes: 12}}
unknowns:
  u: {{boundary: {{x: {{low: 0, high: 1}}}}}}
equations:
  - "der(u, x, 2) - b*der(u, x) = 0"
solver: {{tolerance: 1e-13}}
"""
    cb = _solve(text).codebook
    x = cb.coordinate("x").basis().nodes
    b = np.array([0.5, 1.1, 2.0])[:, None]
    exact = np.expm1(b * x) / np.expm1(b)
    return float(np.max(np.abs(cb(x=x[None, :], b=b)["u"] - exact)))


def test_first_derivative_in_space_in_both_discretizations():
    assert _advection_diffusion_error(20, "chebyshev") <= 1e-11
    coarse, fine = _advection_diffusion_error(17, "linear"), _advection_diffusion_error(33, "linear")
    assert 3.5 < coarse / fine < 4.5 and fine < 1e-3  # second order at the nodes

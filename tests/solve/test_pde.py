"""Space coordinates: weak-form PGD for parametric heat equations against exact solutions."""

from __future__ import annotations


import numpy as np
import pytest
from click.testing import CliRunner

import pgdcli
from conftest import codebook_points, assert_solved, spec_text
from pgdcli.cli.main import cli
from pgdcli.errors import SolverError, SpecError

# the convergence studies below solve to a residual of 1e-11, below what the gate's method-of-lines
# reference can check (their codebooks are refused as unchecked-tight; assert_solved accepts that)
HEAT1D = open("problems/heat1d.yaml").read().replace("tolerance: 1e-8", "tolerance: 1e-11")


@pytest.fixture(scope="module")
def heat1d():
    return pgdcli.solve(pgdcli.load_spec("problems/heat1d.yaml"))


@pytest.fixture(scope="module")
def heat2d():
    return pgdcli.solve(pgdcli.load_spec("problems/heat2d.yaml"))


def test_heat1d_matches_the_exact_solution(heat1d):
    assert heat1d.converged, heat1d.message
    cb = heat1d.codebook
    assert cb.coordinate("x").role == "space"
    p = codebook_points(cb, 600, 1)
    exact = np.exp(-p["kappa"] * np.pi**2 * p["t"]) * np.sin(np.pi * p["x"])
    assert np.max(np.abs(cb(**p)["u"] - exact)) <= 1e-8


def test_heat2d_matches_the_exact_solution(heat2d):
    assert heat2d.converged, heat2d.message
    cb = heat2d.codebook
    assert [c.role for c in cb.coordinates] == ["space", "space", "time", "parameter", "parameter", "parameter"]
    p = codebook_points(cb, 600, 2)
    x, y, t, k, g, q = (p[n] for n in ("x", "y", "t", "kappa", "g", "q"))
    exact = (g * x + np.exp(-2 * k * np.pi**2 * t) * np.sin(np.pi * x) * np.cos(np.pi * y)
             + q * (1 - np.exp(-k * np.pi**2 * t)) * np.sin(np.pi * x) / (k * np.pi**2))
    assert np.max(np.abs(cb(**p)["u"] - exact)) <= 1e-8


def test_dirichlet_values_hold_exactly_on_the_boundary(heat2d):
    cb = heat2d.codebook
    rng = np.random.default_rng(3)
    y, t, k, g, q = (rng.uniform(*cb.coordinate(n).domain, 50) for n in ("y", "t", "kappa", "g", "q"))
    low = cb(x=0.0, y=y, t=t, kappa=k, g=g, q=q)["u"]
    high = cb(x=1.0, y=y, t=t, kappa=k, g=g, q=q)["u"]
    assert np.max(np.abs(low)) <= 1e-13 and np.max(np.abs(high - g)) <= 1e-12


def test_neumann_only_problem():
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 18}', 't': '{domain: [0, 0.3], nodes: 20}', 'kappa': '{domain: [0.2, 1], nodes: 14}'},
        unknowns={'u': '\n    initial: "1 + cos(pi*x)"\n    boundary:\n      x: {low: {gradient: 0}, high: {gradient: 0}}'},
        equations=['"der(u) = kappa*der(u, x, 2)"'],
        solver=' {tolerance: 1e-11}',
    )
    result = pgdcli.solve(pgdcli.parse_spec(text, source="neumann.yaml"))
    assert_solved(result)
    p = codebook_points(result.codebook, 500, 4)
    exact = 1 + np.exp(-p["kappa"] * np.pi**2 * p["t"]) * np.cos(np.pi * p["x"])
    assert np.max(np.abs(result.codebook(**p)["u"] - exact)) <= 1e-8


def test_nonzero_neumann_flux_enters_through_the_weak_form():
    # u_t = u_xx, u_x(0) = a, u_x(1) = a, u(x, 0) = a x + cos(pi x): u = a x + exp(-pi^2 t) cos(pi x)
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 18}', 't': '{domain: [0, 0.2], nodes: 20}', 'a': '{domain: [-1, 1], nodes: 2, discretization: linear}'},
        unknowns={'u': '\n    initial: "a*x + cos(pi*x)"\n    boundary:\n      x: {low: {gradient: a}, high: {gradient: a}}'},
        equations=['"der(u) = der(u, x, 2)"'],
        solver=' {tolerance: 1e-11}',
    )
    result = pgdcli.solve(pgdcli.parse_spec(text, source="flux.yaml"))
    assert_solved(result)
    p = codebook_points(result.codebook, 500, 5)
    exact = p["a"] * p["x"] + np.exp(-np.pi**2 * p["t"]) * np.cos(np.pi * p["x"])
    assert np.max(np.abs(result.codebook(**p)["u"] - exact)) <= 1e-8


@pytest.mark.parametrize("kind, nodes, expected", [("chebyshev", (8, 11, 14), "spectral"),
                                                    ("linear", (9, 17, 33), 2.0)])
def test_error_falls_with_space_nodes(kind, nodes, expected):
    errors = []
    for n in nodes:
        text = HEAT1D.replace("x: {domain: [0, 1], nodes: 20}",
                              f"x: {{domain: [0, 1], nodes: {n}, discretization: {kind}}}")
        result = pgdcli.solve(pgdcli.parse_spec(text, source="h.yaml"))
        assert_solved(result)
        cb = result.codebook
        p = codebook_points(cb, 400, 6)
        exact = np.exp(-p["kappa"] * np.pi**2 * p["t"]) * np.sin(np.pi * p["x"])
        errors.append(np.max(np.abs(cb(**p)["u"] - exact)))
    assert errors[0] > errors[1] > errors[2]
    if expected == "spectral":
        assert errors[2] < 1e-3 * errors[0]
    else:  # piecewise-linear interpolation between nodes: second order in h
        orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
        assert np.all(orders > 1.7), orders


def test_initial_value_must_satisfy_dirichlet_conditions():
    text = HEAT1D.replace('initial: "sin(pi*x)"', 'initial: "sin(pi*x) + 0.5"')
    message = ("bad.yaml: unknowns.u.initial is 0.5 at x=0 but unknowns.u.boundary.x.low is 0: they "
               "differ by 0.5, more than 1e-11, which puts a layer at t = 0 that no codebook resolves; make the "
               "initial value meet the boundary value there")
    with pytest.raises(SpecError) as caught:
        pgdcli.solve(pgdcli.parse_spec(text, source="bad.yaml"))
    assert str(caught.value) == message
    # below the tolerance but above what the linear solver's lift allows: its own refusal, same keys
    text = HEAT1D.replace('initial: "sin(pi*x)"', 'initial: "sin(pi*x) + 1e-8*(1 - x)"').replace("1e-11", "1e-6")
    with pytest.raises(SolverError, match="unknowns.u.initial is 1e-08 at x=0.*boundary.x.low is 0.*lift"):
        pgdcli.solve(pgdcli.parse_spec(text, source="bad.yaml"))


def test_space_dependent_diffusivity_meets_its_tolerance_against_the_method_of_lines():
    # the weak form carries f' (tests/solve/test_nonseparable.py checks it at 300 points against a
    # method of lines of its own)
    text = (HEAT1D.replace('"der(u) = kappa*der(u, x, 2)"', '"der(u) = kappa*(1 + x)*der(u, x, 2)"')
            .replace("tolerance: 1e-11", "tolerance: 1e-6").replace("nodes: 24", "nodes: auto"))
    result = pgdcli.solve(pgdcli.parse_spec(text, source="variable.yaml"))
    assert result.converged and result.accurate, result.message


def test_nonlinear_pde_outside_the_pde_march_is_refused():
    # nonlinear PDEs go to the PDE march (tests/solve/test_nonlinear_pde.py); a diffusion depending on x
    # is refused there, with the march's scope
    text = HEAT1D.replace('"der(u) = kappa*der(u, x, 2)"', '"der(u) = kappa*(1 + x)*der(u, x, 2) - u**2"')
    with pytest.raises(SolverError, match="must not depend on x.*PDE march takes one or two space coordinates"):
        pgdcli.solve(pgdcli.parse_spec(text, source="bad.yaml"))


def test_second_derivative_needs_boundary_conditions():
    text = HEAT1D.replace("    boundary:\n      x: {low: 0, high: 0}\n", "")
    with pytest.raises(SpecError, match="unknowns.u.boundary: missing the conditions at both ends of 'x'"):
        pgdcli.parse_spec(text, source="bad.yaml")


def test_query_prints_a_space_profile(heat1d, tmp_path):
    path = heat1d.codebook.save(tmp_path / "heat1d.h5")
    result = CliRunner().invoke(cli, ["query", str(path), "--x", "0:1:101", "--t", "0.1", "--kappa", "0.5"],
                                prog_name="pgd")
    assert result.exit_code == 0, result.stderr
    values = np.array([float(v) for v in result.stdout.split()])
    x = np.linspace(0, 1, 101)
    assert values.shape == (101,)
    assert np.max(np.abs(values - np.exp(-0.5 * np.pi**2 * 0.1) * np.sin(np.pi * x))) <= 1e-8


def test_2d_problem_without_closed_form_matches_the_method_of_lines_reference():
    # independent reference: strong-form Chebyshev collocation + BDF (pgdcli.checks.reference), no shared code.
    # All times, from right after the source switches on (where the error peaks, at the smallest
    # diffusivity and largest source), plus that worst corner of the parameter domain.
    from pgdcli.checks.reference import solve_reference_pde

    problem = pgdcli.load_spec("problems/heat2d_source.yaml")
    result = pgdcli.solve(problem)
    assert result.converged, result.message
    cb = result.codebook
    rng = np.random.default_rng(1)
    samples = 50
    params = {"kappa": rng.uniform(0.1, 1.0, samples), "q": rng.uniform(0.0, 2.0, samples)}
    xs, ys = rng.uniform(0, 1, 5), rng.uniform(0, 1, 4)
    params = {"kappa": np.append(params["kappa"], 0.1), "q": np.append(params["q"], 2.0)}
    times = np.array([0.0005, 0.001, 0.002, 0.004, 0.007, 0.01, 0.02, 0.1, 0.5])
    ref = solve_reference_pde(problem, params, {"x": xs, "y": ys}, times, space_nodes={"x": 20, "y": 14}, jobs=2)
    assert ref.n_failed == 0
    x, y = np.meshgrid(xs, ys, indexing="ij")
    worst = 0.0
    for s in range(samples + 1):
        for i, t in enumerate(times):
            values = cb(x=x, y=y, t=t, kappa=params["kappa"][s], q=params["q"][s])["u"]
            worst = max(worst, float(np.max(np.abs(values - ref.values["u"][s, i]))))
    assert worst <= 1e-6, worst

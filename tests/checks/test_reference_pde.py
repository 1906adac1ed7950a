"""The method-of-lines reference (problems with space coordinates) and `pgd verify` on them."""

from __future__ import annotations

import json

import numpy as np
import pytest
from click.testing import CliRunner

from conftest import spec_text
import pgdcli
from pgdcli.cli.main import cli
from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor
from pgdcli.errors import PgdError
from pgdcli.checks.reference_pde_modal import METHOD_NAME as MODAL_METHOD
from pgdcli.checks.reference import (
    barycentric_matrix,
    chebyshev_differentiation,
    chebyshev_points,
    chebyshev_weights,
    solve_reference,
    solve_reference_pde,
)

PI = np.pi

HEAT_1D = spec_text(
    name=' heat1d',
    coordinates={'x': '{domain: [0, 1], nodes: 40}', 't': '{domain: [0, 0.5], nodes: 24}', 'kappa': '{domain: [0.1, 1], nodes: 16}'},
    unknowns={'u': '\n    initial: "sin(pi*x)"\n    boundary:\n      x: {low: 0, high: 0}'},
    equations=['"der(u) = kappa*der(u, x, 2)"'],
)

HEAT_2D = spec_text(
    coordinates={'x': '{domain: [0, 1], nodes: 40}', 'y': '{domain: [0, 1], nodes: 40}', 't': '{domain: [0, 0.5], nodes: 24}', 'kappa': '{domain: [0.1, 1], nodes: 16}', 'g': '{domain: [-1, 1], nodes: 4}', 'q': '{domain: [0, 2], nodes: 4}'},
    unknowns={'u': '\n    initial: "g*x + sin(pi*x)*cos(pi*y)"\n    boundary:\n      x: {low: 0, high: g}\n      y: {low: {gradient: 0}, high: {gradient: 0}}'},
    equations=['"der(u) = kappa*(der(u, x, 2) + der(u, y, 2)) + q*sin(pi*x)"'],
)

NEUMANN_1D = spec_text(  # HEAT_1D with gradient conditions
    HEAT_1D, name=None,
    unknowns={'u': '\n    initial: "x + cos(pi*x)"\n    boundary:\n      x: {low: {gradient: 1}, high: {gradient: 1}}'},
)


def spec(text: str):
    return pgdcli.parse_spec(text)


def heat_exact(kappa, t, x):
    return np.exp(-kappa * PI**2 * t) * np.sin(PI * x)


# ----------------------------------------------------------------------------------------------
# building blocks
# ----------------------------------------------------------------------------------------------
def test_chebyshev_differentiation_and_interpolation_are_exact_on_polynomials():
    n = 12
    x = chebyshev_points(n, (-0.5, 2.0))
    assert x[0] == -0.5 and x[-1] == 2.0 and np.all(np.diff(x) > 0)
    mid = 0.75
    assert np.allclose(x - mid, -(x[::-1] - mid), atol=1e-15)  # symmetric
    D = chebyshev_differentiation(n, (-0.5, 2.0))
    p = np.polynomial.Polynomial([0.3, -1.0, 0.5, 2.0, 0.0, -0.7, 0.1, 0.02, 0.0, 0.0, 0.001, -1e-4])  # degree 11
    assert np.max(np.abs(D @ p(x) - p.deriv()(x))) < 1e-10
    assert np.max(np.abs(D @ D @ p(x) - p.deriv(2)(x))) < 1e-8
    points = np.array([-0.5, -0.1234, 0.75, x[3], 1.999, 2.0])
    W = barycentric_matrix(x, chebyshev_weights(n), points)
    assert np.max(np.abs(W @ p(x) - p(points))) < 1e-12
    assert W[3].tolist() == np.eye(n)[3].tolist()  # a node takes its nodal value


# ----------------------------------------------------------------------------------------------
# exact solutions
# ----------------------------------------------------------------------------------------------
def test_heat_1d_exact():
    problem = spec(HEAT_1D)
    rng = np.random.default_rng(0)
    kappa = np.concatenate([[0.1, 1.0], rng.uniform(0.1, 1.0, 14)])
    x = np.concatenate([[0.0, 1.0], rng.uniform(0, 1, 40)])
    times = np.concatenate([[0.0, 0.5], rng.uniform(0, 0.5, 30)])
    result = solve_reference_pde(problem, {"kappa": kappa}, {"x": x}, times)
    assert result.success.all() and result.method == MODAL_METHOD and result.space == ["x"]
    u = result.values["u"]
    assert u.shape == (16, 32, 42)
    exact = heat_exact(kappa[:, None, None], times[None, :, None], x[None, None, :])
    assert np.max(np.abs(u - exact)) <= 1e-8
    # at the collocation nodes (no points given), and at scattered points (grid=False)
    nodes = solve_reference_pde(problem, {"kappa": kappa[:3]}, None, [0.25], space_nodes=24)
    xn = nodes.space_points["x"]
    assert nodes.values["u"].shape == (3, 1, 24) and nodes.nodes == {"x": 24}
    assert np.allclose(xn, chebyshev_points(24, (0, 1)))
    assert np.max(np.abs(nodes.values["u"] - heat_exact(kappa[:3, None, None], 0.25, xn))) <= 1e-8
    scattered = solve_reference_pde(problem, {"kappa": kappa[:3]}, {"x": x[:5]}, times[:4], grid=False, method="Radau")
    assert scattered.values["u"].shape == (3, 4, 5)
    exact = heat_exact(kappa[:3, None, None], times[None, :4, None], x[None, None, :5])
    assert np.max(np.abs(scattered.values["u"] - exact)) <= 1e-8


def test_heat_2d_with_dirichlet_neumann_and_source_is_exact():
    problem = spec(HEAT_2D)
    P = {"kappa": np.array([0.1, 1.0, 0.43]), "g": np.array([-1.0, 1.0, 0.37]), "q": np.array([2.0, 0.0, 1.21])}
    rng = np.random.default_rng(1)
    x = np.concatenate([[0.0, 1.0], rng.uniform(0, 1, 6)])
    y = np.concatenate([[0.0, 1.0], rng.uniform(0, 1, 5)])
    times = np.array([0.0, 0.05, 0.2, 0.5])
    result = solve_reference_pde(problem, P, {"x": x, "y": y}, times)
    assert result.success.all()
    k, g, q = (P[c][:, None, None, None] for c in ("kappa", "g", "q"))
    T, X, Y = times[None, :, None, None], x[None, None, :, None], y[None, None, None, :]
    exact = (g * X + np.exp(-2 * k * PI**2 * T) * np.sin(PI * X) * np.cos(PI * Y)
             + q * (1 - np.exp(-k * PI**2 * T)) * np.sin(PI * X) / (k * PI**2))
    assert result.values["u"].shape == (3, 4, 8, 7)
    assert np.max(np.abs(result.values["u"] - exact)) <= 1e-8


def test_neumann_1d_exact():
    # u = x + exp(-kappa pi^2 t) cos(pi x): du/dx = 1 at both ends (the derivative along x, not the outward normal)
    problem = spec(NEUMANN_1D)
    kappa = np.array([0.1, 0.35, 1.0])
    x = np.linspace(0, 1, 21)
    times = np.linspace(0, 0.5, 11)
    result = solve_reference_pde(problem, {"kappa": kappa}, {"x": x}, times)
    K, T, X = kappa[:, None, None], times[None, :, None], x[None, None, :]
    assert np.max(np.abs(result.values["u"] - (X + np.exp(-K * PI**2 * T) * np.cos(PI * X)))) <= 1e-8


def test_pure_neumann_2d_and_corners():
    # gradient conditions on both coordinates: the corners take the first coordinate's condition
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 8}', 'y': '{domain: [0, 2], nodes: 8}', 't': '{domain: [0, 0.2], nodes: 8}'},
        unknowns={'u': '\n    initial: "cos(pi*x)*cos(pi*y/2) + 0.5*y"\n    boundary:\n      x: {low: {gradient: 0}, high: {gradient: 0}}\n      y: {low: {gradient: 0.5}, high: {gradient: 0.5}}'},
        equations=['"der(u) = der(u, x, 2) + der(u, y, 2)"'],
    )
    result = solve_reference_pde(spec(text), {}, {"x": [0, 0.3, 1], "y": [0, 0.7, 2]}, [0.2], space_nodes=16)
    X, Y = np.meshgrid([0, 0.3, 1], [0, 0.7, 2], indexing="ij")
    exact = np.exp(-1.25 * PI**2 * 0.2) * np.cos(PI * X) * np.cos(PI * Y / 2) + 0.5 * Y
    assert result.values["u"].shape == (1, 1, 3, 3)
    assert np.max(np.abs(result.values["u"][0, 0] - exact)) <= 1e-8


def test_boundary_value_depending_on_the_other_space_coordinate():
    # u = (1 - x) cos(pi y) + exp(-2 pi^2 t) sin(pi x) cos(pi y): u(0, y) = cos(pi y)
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 8}', 'y': '{domain: [0, 1], nodes: 8}', 't': '{domain: [0, 0.1], nodes: 8}'},
        unknowns={'u': '\n    initial: "(1 - x)*cos(pi*y) + sin(pi*x)*cos(pi*y)"\n    boundary:\n      x: {low: "cos(pi*y)", high: 0}\n      y: {low: {gradient: 0}, high: {gradient: 0}}'},
        equations=['"der(u) = der(u, x, 2) + der(u, y, 2) + pi**2*(1 - x)*cos(pi*y)"'],
    )
    x, y = np.array([0.0, 0.2, 0.9]), np.array([0.0, 0.45, 1.0])
    result = solve_reference_pde(spec(text), {}, {"x": x, "y": y}, [0.05, 0.1], space_nodes=20)
    T, X, Y = np.array([0.05, 0.1])[:, None, None], x[None, :, None], y[None, None, :]
    exact = (1 - X) * np.cos(PI * Y) + np.exp(-2 * PI**2 * T) * np.sin(PI * X) * np.cos(PI * Y)
    assert np.max(np.abs(result.values["u"][0] - exact)) <= 1e-8


def test_advection_time_dependent_terms_and_systems():
    # u: manufactured exp(-t) sin(pi x) with advection and a time-dependent source;
    # v: time-dependent diffusivity, exact exp(-kappa pi^2 (t + t^2/2)) sin(pi x);
    # w: a space-dependent der() coefficient, exact as the heat equation
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 40}', 't': '{domain: [0, 1], nodes: 16}', 'kappa': '{domain: [0.1, 1], nodes: 8}'},
        unknowns={'u': '{initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}', 'v': '{initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}', 'w': '{initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}'},
        equations=['"der(u) = kappa*der(u, x, 2) - der(u, x) + exp(-t)*((kappa*pi**2 - 1)*sin(pi*x) + pi*cos(pi*x))"', '"der(v) = kappa*(1 + t)*der(v, x, 2)"', '"(2 + x)*der(w) = (2 + x)*kappa*der(w, x, 2)"'],
    )
    kappa = np.array([0.1, 0.6, 1.0])
    x = np.linspace(0, 1, 13)
    times = np.array([0.0, 0.3, 1.0])
    result = solve_reference_pde(spec(text), {"kappa": kappa}, {"x": x}, times)
    K, T, X = kappa[:, None, None], times[None, :, None], x[None, None, :]
    assert np.max(np.abs(result.values["u"] - np.exp(-T) * np.sin(PI * X))) <= 1e-8
    assert np.max(np.abs(result.values["v"] - np.exp(-K * PI**2 * (T + T**2 / 2)) * np.sin(PI * X))) <= 1e-8
    assert np.max(np.abs(result.values["w"] - heat_exact(K, T, X))) <= 1e-8


def test_coupled_and_time_dependent_der_coefficients_in_worker_processes():
    # der() of two unknowns per equation (a non-diagonal mass), and a time-dependent one
    text = spec_text(
        coordinates={'x': '{domain: [0, 1], nodes: 40}', 't': '{domain: [0, 1], nodes: 16}', 'kappa': '{domain: [0.1, 1], nodes: 8}'},
        unknowns={'u': '{initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}', 'v': '{initial: "2*sin(2*pi*x)", boundary: {x: {low: 0, high: 0}}}', 'w': '{initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}'},
        equations=['"der(u) + der(v) = kappa*(der(u, x, 2) + der(v, x, 2))"', '"der(u) - der(v) = kappa*(der(u, x, 2) - der(v, x, 2))"', '"(1 + t)*der(w) = (1 + t)*kappa*der(w, x, 2)"'],
    )
    kappa = np.array([0.1, 0.6, 1.0])
    x = np.linspace(0, 1, 13)
    times = np.array([0.0, 0.3, 1.0])
    result = solve_reference_pde(spec(text), {"kappa": kappa}, {"x": x}, times, jobs=2, chunk_size=1)
    K, T, X = kappa[:, None, None], times[None, :, None], x[None, None, :]
    assert result.success.all()
    assert np.max(np.abs(result.values["u"] - heat_exact(K, T, X))) <= 1e-8
    assert np.max(np.abs(result.values["v"] - 2 * np.exp(-4 * K * PI**2 * T) * np.sin(2 * PI * X))) <= 1e-8
    assert np.max(np.abs(result.values["w"] - heat_exact(K, T, X))) <= 1e-8


def test_solve_reference_reads_each_sample_at_its_own_space_point():
    problem = spec(NEUMANN_1D)
    rng = np.random.default_rng(2)
    kappa = rng.choice([0.1, 0.5, 1.0], 200)  # three distinct parameter points: three solves
    x = rng.uniform(0, 1, 200)
    times = np.array([0.5, 0.0, 0.1, 0.1])
    result = solve_reference(problem, {"kappa": kappa, "x": x}, times)
    assert result.method == "BDF" and result.rtol == 1e-10 and result.success.all()
    exact = x[:, None] + np.exp(-kappa[:, None] * PI**2 * times) * np.cos(PI * x[:, None])
    assert result.values["u"].shape == (200, 4)
    assert np.max(np.abs(result.values["u"] - exact)) <= 1e-8
    assert np.array_equal(result.values["u"][:, 1], x + np.cos(PI * x))  # the initial value, exactly


def test_failures_are_per_sample():
    text = HEAT_1D.replace('"der(u) = kappa*der(u, x, 2)"', '"kappa*der(u) = der(u, x, 2)"').replace("0.1, 1", "0, 1")
    result = solve_reference_pde(spec(text), {"kappa": np.array([1.0, 0.0, 2.0])}, {"x": [0.5]}, [0.1])
    assert result.success.tolist() == [True, False, True]
    assert "der()" in result.messages[1] and np.isnan(result.values["u"][1]).all()
    assert abs(result.values["u"][0, 0, 0] - np.exp(-PI**2 * 0.1)) <= 1e-8


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda p: solve_reference_pde(p, {"kappa": [1.0]}, None, [0.1], method="DOP853"), "stiff"),
        (lambda p: solve_reference_pde(p, {"kappa": [1.0], "x": [0.5]}, None, [0.1]), "space coordinate"),
        (lambda p: solve_reference_pde(p, {"kappa": [1.0]}, {"x": [1.5]}, [0.1]), "outside the domain"),
        (lambda p: solve_reference_pde(p, {"kappa": [1.0]}, {"x": [0.5]}, [-0.1]), "before the start"),
        (lambda p: solve_reference_pde(p, {"kappa": [1.0]}, None, [0.1], space_nodes=2), "space_nodes"),
        (lambda p: solve_reference(p, {"kappa": [1.0]}, [0.1]), "missing"),
        (lambda p: solve_reference(p, {"kappa": [1.0], "x": [0.5]}, [0.1], method="RK45"), "stiff"),
    ],
)
def test_invalid_input(call, match):
    with pytest.raises(PgdError, match=match):
        call(spec(HEAT_1D))


def test_problem_without_space_is_refused():
    text = "coordinates:\n  t: {domain: [0, 1], nodes: 4}\nunknowns:\n  u: {initial: 1}\nequations:\n  - der(u) = -u\n"
    with pytest.raises(PgdError, match="no space coordinate"):
        solve_reference_pde(spec(text), {}, None, [0.5])


# ----------------------------------------------------------------------------------------------
# pgd verify on a problem with space coordinates (hand-built codebooks of the exact solution)
# ----------------------------------------------------------------------------------------------
def cheb_nodes(c: CoordinateInfo) -> np.ndarray:
    return np.asarray(c.basis().nodes, dtype=float)


def rank_one_heat_codebook(kappa: float = 0.5) -> Codebook:
    """sin(pi x) (x) exp(-kappa pi^2 t): the exact solution of the 1D heat equation, rank 1."""
    text = HEAT_1D.replace("  kappa: {domain: [0.1, 1], nodes: 16}\n", "").replace("kappa*", f"{kappa}*")
    coords = [CoordinateInfo("x", (0.0, 1.0), 40, role="space"), CoordinateInfo("t", (0.0, 0.5), 24, role="time")]
    x, t = (cheb_nodes(c) for c in coords)
    modes = (np.sin(PI * x)[:, None], np.exp(-kappa * PI**2 * t)[:, None])
    return Codebook(coords, {"u": CPTensor(np.ones(1), modes)}, name="heat1d", spec_text=text)


def run(*args):
    result = CliRunner().invoke(cli, [str(a) for a in args])
    assert not isinstance(result.exception, Exception) or isinstance(result.exception, SystemExit), result.exception
    return result


def test_verify_rank_one_codebook_passes_and_perturbed_modes_fail(tmp_path):
    cb = rank_one_heat_codebook()
    report = pgdcli.verify(cb, times=8, jobs=1, max_error=1e-6)
    assert report.passed(1e-6) and report.n_points == 1  # no parameters: one trajectory
    stats = report.unknowns["u"]
    assert stats.max_abs_error <= 1e-8  # the codebook is the exact solution
    assert list(stats.where) == ["x", "t"]
    assert report.settings["method"] == "BDF" and report.settings["space_nodes"] == {"x": 40}
    assert report.settings["space_points"] == {"x": 44} and report.settings["random_space_points"] == 4
    assert set(cheb_nodes(cb.coordinate("x"))) <= set(report.space_points["x"])
    assert report.reference["u"].shape == (1, report.times.size, 44)

    path = cb.save(tmp_path / "heat.h5")
    ok = run("verify", path, "--max-error", "1e-6", "-j", 1, "--format", "json", "-q")
    assert ok.exit_code == 0, ok.output
    assert json.loads(ok.stdout)["passed"] is True

    x, t = cheb_nodes(cb.coordinate("x")), cheb_nodes(cb.coordinate("t"))
    modes = [m.copy() for m in cb.fields["u"].factors]
    modes[0][17, 0] *= 1.0 + 1e-5  # one nodal value of the x mode
    bad = Codebook(cb.coordinates, {"u": CPTensor(np.ones(1), tuple(modes))}, name="heat1d",
                   spec_text=cb.spec_text)
    path = bad.save(tmp_path / "perturbed.h5")
    failed = run("verify", path, "--max-error", "1e-6", "-j", 1, "--format", "json", "-q")
    assert failed.exit_code == 1
    report = json.loads(failed.stdout)
    assert report["passed"] is False and report["unknowns"]["u"]["max_abs_error"] > 1e-6
    assert report["unknowns"]["u"]["where"]["x"] == pytest.approx(x[17])
    assert t.size == 24


def test_verify_samples_parameters_but_not_space(tmp_path):
    # kappa as a coordinate: exp(-kappa pi^2 t) on the (t, kappa) nodes as a truncated SVD
    problem = spec(HEAT_1D)
    coords = [CoordinateInfo(c.name, c.domain, c.nodes, role=c.role) for c in problem.coordinates]
    x, t, k = (cheb_nodes(c) for c in coords)
    U, s, Vt = np.linalg.svd(np.exp(-PI**2 * np.outer(t, k)))
    r = int(np.sum(s > 1e-14 * s[0]))
    modes = (np.repeat(np.sin(PI * x)[:, None], r, axis=1), U[:, :r], Vt[:r].T)
    cb = Codebook(coords, {"u": CPTensor(s[:r], modes)}, name="heat1d", spec_text=HEAT_1D)
    report = pgdcli.verify(cb, samples=16, times=4, space_points=3, jobs=1)
    assert report.passed(1e-6) and report.unknowns["u"].max_abs_error <= 1e-6
    assert set(report.samples) == {"kappa"} and report.n_points == 18  # 16 Sobol + 2 corners
    assert {0.1, 1.0} <= set(report.samples["kappa"].tolist())
    assert list(report.unknowns["u"].where) == ["x", "t", "kappa"]
    assert report.reference["u"].shape == (18, report.times.size, 43)
    # the reference is the exact solution
    K, T, X = report.samples["kappa"][:, None, None], report.times[None, :, None], report.space_points["x"][None, None]
    assert np.max(np.abs(report.reference["u"] - heat_exact(K, T, X))) <= 1e-8
    # a points file names the parameters only
    points = tmp_path / "points.csv"
    points.write_text("x,kappa\n0.5,0.3\n")
    with pytest.raises(PgdError, match="space coordinate"):
        pgdcli.verify(cb, points=points, jobs=1)
    points.write_text("kappa\n0.3\n0.9\n")
    report = pgdcli.verify(cb, points=points, times=2, jobs=1, method="Radau")
    assert report.n_points == 2 and report.settings["method"] == "Radau" and report.passed(1e-6)

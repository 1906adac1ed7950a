"""General terms (pgdcli.general, pgdcli.general_rhs): trees, parsing hooks, reference, march messages."""

from __future__ import annotations

import ast
import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from conftest import spec_text, train_march
import pgdcli
from pgdcli.errors import PgdError
from pgdcli.problem.expressions import Atom, parse_equation
from pgdcli.problem.general import build_tree, evaluate, has_general, is_general, render, tree_names, tree_of
from pgdcli.checks.reference import solve_reference

KW = dict(coordinates=["t", "L", "k"], constants={"g": 9.81}, unknowns=["th", "w", "u", "v"], time="t", where="e")


class Names:
    def resolve(self, node):
        return ("name", node.id)

    def refuse(self, node, what=None):
        return ValueError(ast.unparse(node))


def tree(text):
    return build_tree(ast.parse(text, mode="eval").body, Names())


@pytest.mark.parametrize("text", ["sin(th)", "1/(1 + u)", "u**0.5", "(-u)**0.5", "-u**2", "2**-u", "(u**2)**1.5",
                                  "a - (b - c)", "a/(b*c)", "a*(b/c)", "(a + b)*c", "-(a*b)", "exp(-(u - 2.5e-17))",
                                  "a**b**c", "(a**b)**c", "sqrt(vx**2 + vy**2)", "u - -3"])
def test_render_parses_back_to_the_same_tree(text):
    t = tree(text)
    assert tree(render(t)) == t
    assert tree_of(Atom(render(t), "<general>", 0)) == t


def test_evaluate_matches_numpy_and_folds_numbers():
    x = np.linspace(-1, 1, 7)
    y = np.linspace(0.5, 2, 7)
    t = tree("sqrt(x**2 + y**2)*x - exp(-y)/(1 + abs(x)) + 2**3")
    assert t[2] == ("num", 8.0)  # folded
    np.testing.assert_allclose(evaluate(t, {"x": x, "y": y}),
                               np.hypot(x, y) * x - np.exp(-y) / (1 + np.abs(x)) + 8, rtol=1e-15)
    assert tree_names(t) == {"x", "y"}
    assert np.isnan(evaluate(tree("sqrt(x)"), {"x": -1.0}))  # undefined: NaN, no warning raised


def test_parser_keeps_polynomial_coefficients_separated():
    poly = parse_equation("der(w) = -(g/L)*sin(th) - k*abs(w)*w + u*v", **KW)
    general = {m: sep for m, sep in poly.items() if any(is_general(a) for a in m)}
    assert has_general(poly) and len(general) == 2
    (sin_mono,) = [m for m in general if len(m) == 1]
    assert render(tree_of(sin_mono[0])) == "sin(th)"
    coef = general[sin_mono]
    np.testing.assert_allclose(coef.evaluate(L=np.array([0.5, 2.0])), 9.81 / np.array([0.5, 2.0]))
    assert any(a == Atom("u") for m in poly for a in m)  # u*v stays polynomial


def test_constants_fold_and_coordinates_stay_names():
    poly = parse_equation("der(u) = exp(-g*u/k) + sin(th + L*t)", **KW)
    texts = sorted(a.unknown for a in poly.atoms if is_general(a))
    assert texts == ["exp(-9.81*u/k)", "sin(th + L*t)"]


def test_initial_value_with_a_function_of_an_unknown_is_refused():
    spec = spec_text(
        coordinates=' {t: {domain: [0, 1]}}',
        unknowns=' {u: {initial: sin(u)}}',
        equations=' ["der(u) = -u"]',
    )
    with pytest.raises(PgdError, match="must not depend on unknowns"):
        pgdcli.parse_spec(spec, source="s.yaml")


def test_enrichment_solver_refuses_general_terms():
    spec = spec_text(
        coordinates=' {t: {domain: [0, 1]}, k: {domain: [1, 2], nodes: 5}}',
        unknowns=' {u: {initial: 1}}',
        equations=' ["der(u) = -k*sin(u)"]',
        solver=' {method: pgd}',
    )
    with pytest.raises(PgdError, match="linear in the unknowns only"):
        pgdcli.solve(pgdcli.parse_spec(spec, source="s.yaml"))


PENDULUM = spec_text(
    coordinates=' {t: {domain: [0, 2]}, L: {domain: [0.5, 2], nodes: 5}, th0: {domain: [0.1, 2.5], nodes: 5}}',
    constants=' {grav: 9.81}',
    unknowns=' {th: {initial: th0}, w: {initial: 0}}',
    equations=' ["der(th) = w", "der(w) = -(grav/L)*sin(th + 0*t)"]',
)


def test_reference_evaluates_general_terms():
    problem = pgdcli.parse_spec(PENDULUM, source="p.yaml")
    rng = np.random.default_rng(3)
    params = {"L": rng.uniform(0.5, 2, 6), "th0": rng.uniform(0.1, 2.5, 6)}
    times = np.array([0.5, 1.3, 2.0])
    ref = solve_reference(problem, params, times)
    for s in range(6):
        L, th0 = params["L"][s], params["th0"][s]
        sol = solve_ivp(lambda t, y: [y[1], -9.81 / L * math.sin(y[0])], (0, 2), [th0, 0.0], method="DOP853",
                        rtol=1e-12, atol=1e-12, t_eval=times)
        np.testing.assert_allclose(ref.values["th"][s], sol.y[0], rtol=0, atol=1e-9)
        np.testing.assert_allclose(ref.values["w"][s], sol.y[1], rtol=0, atol=1e-9)


def test_undefined_function_is_named_in_the_failure():
    spec = spec_text(
        coordinates=' {t: {domain: [0, 3]}, u0: {domain: [0.5, 1], nodes: 5}}',
        unknowns=' {u: {initial: u0}}',
        equations=' ["der(u) = -sqrt(u)"]',
    )
    result = pgdcli.solve(pgdcli.parse_spec(spec, source="s.yaml"))
    assert not result.converged
    assert "not finite" in result.message and "sqrt or log of a negative number" in result.message


def test_march_reports_its_crosses_and_pgd_info_prints_them(tmp_path):
    from click.testing import CliRunner

    from pgdcli.cli.main import cli

    spec = PENDULUM.replace("[0, 2]", "[0, 1]").replace(", nodes: 5", "") + "solver: {tolerance: 1e-5}\n"
    problem = pgdcli.parse_spec(spec, source="p.yaml")
    with train_march():  # the crosses of the tensor-train march (the grid march evaluates the whole grid)
        result = pgdcli.solve(problem)
    assert result.accurate, result.message
    cb = result.codebook
    assert cb.report["crosses"] > 0 and cb.report["crosses_not_converged"] == 0
    path = tmp_path / "p.h5"
    cb.save(path)
    info = cb.info(path)["crosses"]
    assert info["count"] == cb.report["crosses"] and info["evaluations"] > 0
    run = CliRunner().invoke(cli, ["info", str(path)])
    assert "functions of the unknowns:" in run.stderr + run.stdout


def test_single_trajectory_with_a_function_of_the_unknown():
    spec = spec_text(
        coordinates=' {t: {domain: [0, 3]}}',
        unknowns=' {u: {initial: 1}}',
        equations=' ["der(u) = -sin(u) + exp(-u)*t"]',
        solver=' {tolerance: 1e-8}',
    )
    result = pgdcli.solve(pgdcli.parse_spec(spec, source="one.yaml"))
    assert result.accurate, result.message
    ts = np.linspace(0, 3, 301)
    sol = solve_ivp(lambda t, y: [-np.sin(y[0]) + np.exp(-y[0]) * t], (0, 3), [1.0], method="DOP853", rtol=1e-12,
                    atol=1e-12, t_eval=ts)
    assert np.max(np.abs(result.codebook(t=ts)["u"] - sol.y[0])) <= 1e-8

"""The independent reference (pgdcli.checks.reference) against exact solutions."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from conftest import spec_text
from pgdcli.errors import PgdError
from pgdcli.checks.reference import METHODS, solve_reference
from pgdcli.problem.spec import load_spec, parse_spec

ROOT = Path(__file__).resolve().parents[2]
PROBLEMS = ROOT / "problems"


def spec(text: str):
    return parse_spec(text, allow_nonlinear=True)


def rel_err(a, b):
    return float(np.max(np.abs(a - b)) / max(1.0, float(np.max(np.abs(b)))))


RELAX = spec_text(
    coordinates={'t': '{domain: [0, 2], nodes: 8}', 'k': '{domain: [0.5, 5], nodes: 8}', 'u0': '{domain: [-1, 1], nodes: 2, discretization: linear}'},
    unknowns={'u': '{initial: u0}'},
    equations=['"der(u) = -k*u"'],
)


def test_reference_imports_nothing_of_the_solver():
    imported = set()
    sources = ("reference.py", "reference_base.py", "reference_ode.py", "reference_pde.py", "reference_pde_points.py", "collocation_grid.py",
               "collocation.py")
    trees = [ast.parse((ROOT / "pgdcli" / "checks" / name).read_text()) for name in sources]
    for node in (node for tree in trees for node in ast.walk(tree)):
        if isinstance(node, ast.ImportFrom):
            imported.update((node.module or "").split("."))
            imported.update(alias.name for alias in node.names)
        elif isinstance(node, ast.Import):
            imported.update(part for alias in node.names for part in alias.name.split("."))
    assert not imported & {"solver", "driver", "basis", "separated", "codebook", "discretization", "tensors",
                           "algorithms", "cp", "tt", "march"}


def test_parametric_exact():
    problem = load_spec(PROBLEMS / "parametric.yaml")
    k = np.array([1.0, 10.0, 2.5, 3.7, 7.1])
    times = np.array([0.0, 0.3, 5.0, 9.99, 10.0])
    result = solve_reference(problem, {"k": k}, times)
    assert result.success.all() and result.messages == [""] * 5
    exact = (10.0 / k[:, None] - 1.0) * times[None, :]
    assert result.values["u"].shape == (5, 5)
    assert np.max(np.abs(result.values["u"] - exact)) < 1e-10


def test_relaxation_exact():
    problem = spec(RELAX)
    rng = np.random.default_rng(0)
    k = np.concatenate([rng.uniform(0.5, 5, 30), [0.5, 5, 0.5, 5]])
    u0 = np.concatenate([rng.uniform(-1, 1, 30), [-1, -1, 1, 1]])
    times = np.concatenate([np.linspace(0, 2, 9), rng.uniform(0, 2, 10)])
    result = solve_reference(problem, {"k": k, "u0": u0}, times)
    exact = u0[:, None] * np.exp(-k[:, None] * times[None, :])
    assert result.success.all()
    assert np.max(np.abs(result.values["u"] - exact)) < 1e-10


def test_shipped_relaxation_and_spring_exact():
    from conftest import exact_relaxation, exact_spring

    rng = np.random.default_rng(1)
    times = np.concatenate([np.linspace(0, 3, 7), rng.uniform(0, 3, 5)])
    p = {"k": rng.uniform(0.5, 5, 20), "a": rng.uniform(-1, 1, 20), "u0": rng.uniform(0, 1, 20)}
    result = solve_reference(load_spec(PROBLEMS / "relaxation.yaml"), p, times)
    exact = exact_relaxation({"t": times[None, :], **{n: v[:, None] for n, v in p.items()}})
    assert np.max(np.abs(result.values["u"] - exact["u"])) < 1e-10

    times = np.linspace(0, 4, 13)
    p = {"k": np.array([1.0, 4.0, 2.2]), "c": np.array([0.1, 0.5, 0.3])}
    result = solve_reference(load_spec(PROBLEMS / "spring.yaml"), p, times)
    exact = exact_spring({"t": times[None, :], **{n: v[:, None] for n, v in p.items()}})
    for u in ("x", "v"):
        assert np.max(np.abs(result.values[u] - exact[u])) < 1e-10


@pytest.mark.parametrize("method", METHODS)
def test_every_method(method):
    problem = spec(RELAX)
    k = np.array([0.5, 2.0, 5.0])
    u0 = np.array([1.0, -0.5, 0.25])
    times = np.linspace(0, 2, 5)
    result = solve_reference(problem, {"k": k, "u0": u0}, times, method=method)
    exact = u0[:, None] * np.exp(-k[:, None] * times[None, :])
    assert result.success.all()
    assert np.max(np.abs(result.values["u"] - exact)) < 1e-8
    assert result.method == method


def test_coupled_and_time_dependent_der_coefficients():
    # the spring with a non-diagonal, time-dependent matrix of der() coefficients
    text = spec_text(
        coordinates={'t': '{domain: [0, 4], nodes: 8}', 'k': '{domain: [1, 4], nodes: 4}', 'c': '{domain: [0.1, 0.5], nodes: 4}'},
        unknowns={'x': '{initial: 1}', 'v': '{initial: 0}'},
        equations=['"(1 + t)*der(x) = (1 + t)*v"', '"(2 + t)*(der(v) + 3*der(x)) = (2 + t)*(-k*x - c*v + 3*v)"'],
    )
    from conftest import exact_spring

    p = {"k": np.array([1.0, 4.0, 2.5]), "c": np.array([0.1, 0.5, 0.2])}
    times = np.linspace(0, 4, 9)
    for method in ("DOP853", "Radau"):
        result = solve_reference(spec(text), p, times, method=method)
        exact = exact_spring({"t": times[None, :], **{n: v[:, None] for n, v in p.items()}})
        tol = 1e-10 if method == "DOP853" else 1e-8
        for u in ("x", "v"):
            assert np.max(np.abs(result.values[u] - exact[u])) < tol, (method, u)


def test_polynomial_nonlinearities():
    # logistic growth: u' = r u (1 - u)
    logistic = spec_text(
        coordinates={'t': '{domain: [0, 3], nodes: 8}', 'r': '{domain: [0.5, 3], nodes: 4}'},
        unknowns={'u': '{initial: 0.1}'},
        equations=['"der(u) = r*u - r*u**2"'],
    )
    r = np.array([0.5, 1.3, 3.0])
    times = np.linspace(0, 3, 7)
    result = solve_reference(spec(logistic), {"r": r}, times)
    exact = 1.0 / (1.0 + 9.0 * np.exp(-r[:, None] * times[None, :]))
    assert np.max(np.abs(result.values["u"] - exact)) < 1e-10
    # a product of two unknowns: x' = -x y, y' = 0, y(0) = k  ->  x = exp(-k t)
    product = spec_text(
        coordinates={'t': '{domain: [0, 2], nodes: 8}', 'k': '{domain: [0, 2], nodes: 4}'},
        unknowns={'x': '{initial: 1}', 'y': '{initial: k}'},
        equations=['"der(x) = -x*y"', '"der(y) = 0"'],
    )
    k = np.array([0.0, 0.7, 2.0])
    result = solve_reference(spec(product), {"k": k}, times[:5])
    assert np.max(np.abs(result.values["x"] - np.exp(-k[:, None] * times[None, :5]))) < 1e-10
    assert np.max(np.abs(result.values["y"] - k[:, None])) == 0.0


BLOWUP = spec_text(
    coordinates={'t': '{domain: [0, 2], nodes: 8}', 'u0': '{domain: [0.2, 1], nodes: 4}'},
    unknowns={'u': '{initial: u0}'},
    equations=['"der(u) = u*u"'],
)


@pytest.mark.parametrize("jobs", [1, 2])
def test_blow_up_is_a_failure_of_exactly_those_samples(jobs):
    # u = u0 / (1 - u0 t) blows up at t = 1/u0 < 2 for u0 > 0.5
    u0 = np.array([0.2, 0.6, 0.4, 1.0, 0.3, 0.45, 0.55, 0.25])
    times = np.array([0.0, 0.5, 1.0, 1.9])
    result = solve_reference(spec(BLOWUP), {"u0": u0}, times, jobs=jobs, chunk_size=4)
    expected = u0 < 0.5
    assert result.success.tolist() == expected.tolist()
    for i in np.flatnonzero(~expected):
        assert result.messages[i] and np.isnan(result.values["u"][i]).all()
    ok = expected
    exact = u0[ok, None] / (1.0 - u0[ok, None] * times[None, :])
    assert rel_err(result.values["u"][ok], exact) < 1e-10
    assert all(m == "" for m, good in zip(result.messages, expected) if good)


def test_evaluation_budget_and_singular_der_coefficient():
    problem = spec(RELAX)
    result = solve_reference(problem, {"k": np.array([1.0, 2.0]), "u0": np.array([1.0, 1.0])},
                             np.array([0.0, 2.0]), max_evaluations=5)
    assert not result.success.any()
    assert "gave up" in result.messages[0]
    singular = spec(RELAX.replace("der(u) = -k*u", "k*der(u) = -u").replace("[0.5, 5]", "[-1, 1]"))
    k = np.array([0.5, 0.0, 1.0])
    result = solve_reference(singular, {"k": k, "u0": np.ones(3)}, np.array([0.0, 1.0]))
    assert result.success.tolist() == [True, False, True]
    assert "der()" in result.messages[1]
    assert abs(result.values["u"][0, 1] - np.exp(-2.0)) < 1e-10


def test_times_keep_their_order_and_repeats():
    problem = spec(RELAX)
    times = np.array([1.5, 0.0, 0.7, 1.5, 2.0])
    result = solve_reference(problem, {"k": np.array([2.0]), "u0": np.array([1.0])}, times)
    assert np.max(np.abs(result.values["u"][0] - np.exp(-2.0 * times))) < 1e-11
    np.testing.assert_array_equal(result.times, times)


def test_no_parameters_is_one_trajectory():
    text = spec_text(
        unknowns={'u': '{initial: 2}'},
        equations=['"der(u) = -u + sin(t)"'],
    )
    times = np.linspace(0, 1, 5)
    result = solve_reference(spec(text), {}, times)
    exact = 2.5 * np.exp(-times) + 0.5 * (np.sin(times) - np.cos(times))
    assert result.values["u"].shape == (1, 5)
    assert np.max(np.abs(result.values["u"][0] - exact)) < 1e-11


@pytest.mark.parametrize(
    "params, times, kwargs, match",
    [
        ({"k": [1.0]}, [0.0], {}, "missing"),
        ({"k": [1.0], "u0": [1.0], "z": [1.0]}, [0.0], {}, "'z'"),
        ({"k": [1.0], "u0": [1.0], "t": [1.0]}, [0.0], {}, "time coordinate"),
        ({"k": [1.0, 2.0], "u0": [1.0]}, [0.0], {}, "one length"),
        ({"k": [1.0], "u0": [1.0]}, [-0.5], {}, "before the start"),
        ({"k": [1.0], "u0": [1.0]}, [0.5], {"method": "Euler"}, "method"),
        ({"k": [1.0], "u0": [1.0]}, [0.5], {"rtol": 0.0}, "rtol"),
    ],
)
def test_invalid_input(params, times, kwargs, match):
    with pytest.raises(PgdError, match=match):
        solve_reference(spec(RELAX), {n: np.array(v) for n, v in params.items()}, np.array(times), **kwargs)

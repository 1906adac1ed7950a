"""The collocated system of the nonlinear reference: derivatives, boundary values and right-hand side
against the manufactured solutions of tests/manufactured_rd.py (exact functions, not the solver)."""

import numpy as np
import pytest

from pgdcli.checks.reference_pde_collocated import CollocatedModel
from pgdcli.problem.spec import parse_spec

import manufactured_rd


def _plane(n=24, c=0.07):
    return CollocatedModel(parse_spec(manufactured_rd.PLANE), n, {"c": c})


@pytest.mark.parametrize("axis, order", [(0, 1), (1, 1), (0, 2), (1, 2)])
def test_derivatives_along_each_axis_are_spectral(axis, order):
    model = _plane()
    x, y = model.grid["x"], model.grid["y"]
    u = np.sin(2 * x) * np.cos(3 * y)
    exact = {(0, 1): 2 * np.cos(2 * x) * np.cos(3 * y), (1, 1): -3 * np.sin(2 * x) * np.sin(3 * y),
             (0, 2): -4 * u, (1, 2): -9 * u}[(axis, order)]
    assert np.abs(model.derivative(axis, order, u) - exact).max() < 1e-8 * 9
    assert np.allclose(model.derivative(axis, order, u), model.ops[(axis, order)] @ u, rtol=0, atol=1e-9)


def test_full_values_meet_the_boundary_conditions():
    model = _plane()
    x, y = model.grid["x"], model.grid["y"]
    rng = np.random.default_rng(3)
    U = model.full(rng.normal(size=model.m))[0]
    low, high = np.isclose(x, 0), np.isclose(x, 1)
    assert np.abs(U[low] - 1).max() < 1e-12 and np.abs(U[high] - (1 + y[high])).max() < 1e-12
    inner = ~(low | high)
    for end in (0, 1):  # the gradient condition du/dy = x on the ends of y (not on those of x)
        rows = inner & np.isclose(y, end)
        assert np.abs(model.derivative(1, 1, U)[rows] - x[rows]).max() < 1e-9
    lift = model.full(np.zeros(model.m))[0]  # the Jacobian's map Z is the linear part of full()
    Z = np.stack([model.Z[0] @ v for v in np.eye(model.m)[:3]])
    assert np.allclose(Z, np.stack([model.full(v)[0] - lift for v in np.eye(model.m)[:3]]), rtol=0, atol=1e-12)


@pytest.mark.parametrize("t", [0.0, 0.4, 1.0])
def test_rhs_of_the_exact_solution_is_its_time_derivative(t):
    c = 0.07
    model = _plane(n=28, c=c)
    x, y = model.grid["x"], model.grid["y"]
    exact = manufactured_rd.plane_exact(t, x, y)
    du = -np.exp(-t) * np.sin(np.pi * x) * (1 - np.cos(np.pi * y))
    rhs = model.rhs(t, exact[model.interior])
    assert np.abs(rhs - du[model.interior]).max() < 1e-7

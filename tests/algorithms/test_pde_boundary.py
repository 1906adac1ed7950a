"""Boundary conditions of the PDE march (pgdcli.algorithms.pde_boundary): the elimination meets the
homogeneous conditions, the lift meets the data (1-D and 2-D, value and gradient, data depending on the
other coordinate), and data that disagree at a corner are found."""

import numpy as np
import pytest

from pgdcli.algorithms.pde_boundary import (boundary_rows, corner_mismatch, elimination, lift_basis, lift_grid,
                                            mode_product)
from pgdcli.discretization.basis import make_basis

KINDS = [("value", "value"), ("value", "gradient"), ("gradient", "value"), ("gradient", "gradient")]


def _axis(n=13, domain=(0.0, 2.0)):
    basis = make_basis("chebyshev", domain, n)
    return np.asarray(basis.nodes), np.asarray(basis.derivative)


@pytest.mark.parametrize("kinds", KINDS)
def test_elimination_meets_the_homogeneous_conditions(kinds):
    xs, D = _axis()
    C = boundary_rows(kinds, D)
    Z = elimination(C)
    assert np.abs(C @ Z).max() < 1e-12
    assert np.array_equal(Z[1:-1], np.eye(xs.size - 2))


@pytest.mark.parametrize("kinds", KINDS)
def test_one_dimensional_lift_meets_the_data(kinds):
    xs, D = _axis()
    C = boundary_rows(kinds, D)
    data = (np.array([[0.7, 0.2, -0.1]]), np.full((1, 3), -1.3))  # at three nodes of a parameter
    L = lift_grid([C], [lift_basis(C, xs)], [data])
    assert L.shape == (xs.size, 3)
    assert np.allclose(C @ L, np.vstack(data), atol=1e-12)


@pytest.mark.parametrize("kx", KINDS)
@pytest.mark.parametrize("ky", KINDS)
def test_two_dimensional_lift_meets_compatible_data(kx, ky):
    """Data taken from one smooth function F(x, y, p) (so they agree at the corners): the lift meets all
    four conditions on the nodes, whatever the kinds."""
    xs, Dx = _axis(13, (0.0, 2.0))
    ys, Dy = _axis(11, (-1.0, 1.0))
    p = np.array([0.5, 1.5])
    X, Y, P = np.meshgrid(xs, ys, p, indexing="ij")
    F = np.sin(X + 0.3 * Y) * P + X * Y ** 2
    Cx, Cy = boundary_rows(kx, Dx), boundary_rows(ky, Dy)
    gx = [mode_product(Cx[s:s + 1], F, 0) for s in range(2)]  # (1, ny, np): functions of y and p
    gy = [mode_product(Cy[s:s + 1], F, 1) for s in range(2)]  # (nx, 1, np)
    y, q = Y[:1], P[:1]  # the data of x as the user writes them: exact values and derivatives
    exact_x = [np.cos(xe + 0.3 * y) * q + y ** 2 if k == "gradient" else np.sin(xe + 0.3 * y) * q + xe * y ** 2
               for k, xe in zip(kx, (0.0, 2.0))]
    assert all(np.abs(a - b).max() < 1e-9 for a, b in zip(gx, exact_x))  # the nodes resolve F
    L = lift_grid([Cx, Cy], [lift_basis(Cx, xs), lift_basis(Cy, ys)], [gx, gy])
    for s in range(2):
        assert np.abs(mode_product(Cx[s:s + 1], L, 0) - gx[s]).max() < 1e-10
        assert np.abs(mode_product(Cy[s:s + 1], L, 1) - gy[s]).max() < 1e-10
    assert max(np.abs(m).max() for m in corner_mismatch([Cx, Cy], [gx, gy]).ravel()) < 1e-10


def test_data_that_disagree_at_a_corner_are_found():
    xs, Dx = _axis(9, (0.0, 1.0))
    ys, Dy = _axis(9, (0.0, 1.0))
    Cx, Cy = boundary_rows(("value", "value"), Dx), boundary_rows(("value", "gradient"), Dy)
    one = np.ones((1, 9))
    gx = [0.0 * one, ys.reshape(1, -1)]  # u(0, y) = 0, u(1, y) = y
    gy = [np.zeros((9, 1)), np.ones((9, 1))]  # u(x, 0) = 0, u_y(x, 1) = 1
    mismatch = corner_mismatch([Cx, Cy], [gx, gy])
    assert np.abs(mismatch[1, 1]).max() < 1e-12  # d/dy of y at the corner (1, 1) is 1, as asked
    assert abs(float(mismatch[0, 1].ravel()[0]) - 1.0) < 1e-12  # u(0, y) = 0 has d/dy 0, asked 1
    assert np.abs(mismatch[0, 0]).max() < 1e-12 and np.abs(mismatch[1, 0]).max() < 1e-12

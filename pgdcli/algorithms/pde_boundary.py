"""Boundary conditions of the PDE march on Chebyshev-Lobatto nodes: elimination and lift.

Along each space coordinate a species has two conditions, one per end: a value ``u = g`` or a
gradient ``du/dx = g``, the rows ``C`` (2, n) of the identity or of the differentiation matrix.
The solution is split as ``u = Z w + L``:

* ``Z`` (n, n - 2) maps the interior values ``w`` to the full nodal values meeting the homogeneous
  conditions (``C Z = 0``): the boundary values are eliminated. With two space coordinates the
  state is ``Z_x w Z_y^T`` (the conditions of ``x`` hold on every row, those of ``y`` on every column).
* ``L`` is a lift meeting the conditions with their data. In one space coordinate it is
  ``Phi g`` with ``Phi`` (n, 2) a linear (or, for two gradient conditions, ``s``, ``s**2``) basis,
  ``C Phi = I``. In two, the data of ``x`` (functions of ``y`` and the parameters) are lifted
  first, ``P = Phi_x g_x``, and what the conditions of ``y`` still ask is lifted along ``y``:
  ``L = P + Phi_y (g_y - C_y P)`` (a transfinite, Gordon-Hall, interpolation). It meets the
  conditions of ``x`` too exactly where the data agree at the corners:
  ``C_x g_y = C_y g_x`` at each of the four corners (equal values where both are values; the
  gradient along ``y`` of one equal to the data of the other where a gradient meets a value).
  Where they disagree the solution is not smooth at that corner, and the problem is refused.

The lift is not harmonic: its diffusion ``sum_a c_a D_a^2 L`` is a source of the equation of ``w``.
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError

__all__ = ["boundary_rows", "elimination", "lift_basis", "lift_grid", "mode_product", "corner_mismatch"]


def boundary_rows(kinds, D: np.ndarray) -> np.ndarray:
    """The rows ``C`` (2, n) of the conditions ``kinds`` (``'value'`` or ``'gradient'``, low then high)."""
    n = D.shape[0]
    C = np.zeros((2, n))
    for side, kind in enumerate(kinds):
        node = 0 if side == 0 else n - 1
        C[side] = np.eye(n)[node] if kind == "value" else D[node]
    return C


def elimination(C: np.ndarray) -> np.ndarray:
    """``Z`` (n, n - 2): full nodal values meeting ``C u = 0`` from the interior values."""
    n = C.shape[1]
    B, interior = np.array([0, n - 1]), np.arange(1, n - 1)
    Z = np.zeros((n, n - 2))
    Z[interior, np.arange(n - 2)] = 1.0
    Z[B] = -np.linalg.solve(C[:, B], C[:, interior])
    return Z


def lift_basis(C: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """``Phi`` (n, 2) on the nodes ``xs`` with ``C Phi = I``.

    ``a + b (x - x0)`` where it can; two gradient conditions fix only the slope (with ``1`` in
    the basis the 2 x 2 system is singular), so there ``b (x - x0) + c (x - x0)**2``.
    """
    s = xs - xs[0]
    for basis in (np.stack([np.ones_like(xs), s], axis=1), np.stack([s, s * s], axis=1)):
        M = C @ basis
        if abs(np.linalg.det(M)) > 1e-12 * float(np.abs(M).max()) ** 2:
            break
    return basis @ np.linalg.inv(M)


def mode_product(M: np.ndarray, X: np.ndarray, axis: int) -> np.ndarray:
    """``M`` (k, n) applied along ``axis`` of ``X`` (size n there, or 1: a constant along it, broadcast)."""
    if X.shape[axis] == 1 and M.shape[1] != 1:
        X = np.broadcast_to(X, X.shape[:axis] + (M.shape[1],) + X.shape[axis + 1:])
    return np.moveaxis(np.tensordot(M, X, axes=(1, axis)), 0, axis)


def lift_grid(C: list, Phi: list, data: list) -> np.ndarray:
    """The lift on the grid.

    Parameters
    ----------
    C, Phi : list of ndarray
        Per space axis (the first one or two axes of the grid), the rows (2, n_a) and the basis (n_a, 2).
    data : list of (ndarray, ndarray)
        Per space axis, the data at its low and high end, each broadcastable to the grid with size 1
        along that axis.

    Returns
    -------
    ndarray
        Broadcastable to the grid, full along the space axes.
    """
    L = _lift_along(Phi[0], data[0], 0)
    for a in range(1, len(C)):
        rest = [g - mode_product(C[a][side:side + 1], L, a) for side, g in enumerate(data[a])]
        L = L + _lift_along(Phi[a], rest, a)
    return L


def _lift_along(Phi: np.ndarray, data, axis: int) -> np.ndarray:
    """``sum_side Phi[:, side] g_side`` with ``Phi``'s column along ``axis``."""
    out = 0.0
    for side, g in enumerate(data):
        g = np.asarray(g, dtype=float)
        shape = [1] * max(g.ndim, axis + 1)
        shape[axis] = -1
        out = out + Phi[:, side].reshape(shape) * g
    return out


def corner_mismatch(C: list, data: list) -> np.ndarray:
    """``C_x g_y - C_y g_x`` at the four corners (2 sides of x, 2 sides of y, parameters...), two axes.

    Zero where the conditions of the two space coordinates agree at the corners (see the module
    docstring); ``data`` as for :func:`lift_grid`.
    """
    out = np.empty((2, 2), dtype=object)
    for i in range(2):
        for j in range(2):
            along_y = mode_product(C[1][j:j + 1], np.asarray(data[0][i], dtype=float), 1)  # C_y g_x
            along_x = mode_product(C[0][i:i + 1], np.asarray(data[1][j], dtype=float), 0)  # C_x g_y
            out[i, j] = along_x - along_y
    return out


def check_corners(C: list, data: list, names: list, domains: list, tolerance: float, species: str) -> None:
    """Refuse data of two space coordinates that disagree at a corner by more than ``tolerance``."""
    if len(C) < 2:
        return
    mismatch = corner_mismatch(C, data)
    for i in range(2):
        for j in range(2):
            gap = float(np.max(np.abs(mismatch[i, j]), initial=0.0))
            if gap > tolerance:
                corner = f"{names[0]}={domains[0][i]:g}, {names[1]}={domains[1][j]:g}"
                raise SolverError(f"unknowns.{species}.boundary: the conditions on {names[0]} "
                                  f"({('low', 'high')[i]}) and on {names[1]} ({('low', 'high')[j]}) disagree at the "
                                  f"corner {corner} by {gap:.2g} (a value against a value, or a gradient against "
                                  f"the derivative of the other's data): the solution is not smooth there; make "
                                  f"them agree")

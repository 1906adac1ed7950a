"""The one-dimensional pieces of the linear discretization: per coordinate, and in time.

:class:`CoordinateOps` tests a non-time coordinate (parameters collocated, space in weak form,
left-preconditioned); :class:`TimeOps` holds the time rows of the state mode, preconditioned by
the inverse of the discrete ``d/dt``; :class:`SteadyOps` stands in for time in a steady
problem. :func:`pgdcli.discretization.linear.discretize` assembles them into the separated system.
"""

from __future__ import annotations

import numpy as np

from ..errors import SolverError
from .basis import Basis1D

__all__ = ["CoordinateOps", "TimeOps", "SteadyOps", "boundary_kinds"]


class CoordinateOps:
    """The 1D pieces of one non-time coordinate: test/trial nodes, matrices, left preconditioner.

    Parameters are collocated (diagonal matrices). Space coordinates are in weak form with
    the basis's quadrature: mass ``W``, stiffness ``K`` (Chebyshev ``D^T W D``; linear
    elements the exact tridiagonal one), advection ``int f phi_i phi_j'`` (Chebyshev: exact
    Gauss-Legendre; linear elements: f at the element midpoints); a Dirichlet
    end drops its node from the trial and test functions (the lift carries the value), a
    gradient (Neumann) end enters as a boundary flux. Every matrix is returned already
    multiplied by the left preconditioner: ``1/sqrt(w)`` for parameters, and
    ``sqrt(W) (M + tau K)^-1`` for space, which keeps the stiff operator bounded in the
    minimal-residual normal equations (their conditioning is squared).
    """

    def __init__(self, name: str, basis: Basis1D, role: str, ends: tuple[str, str] | None, tau: float):
        self.name, self.basis = name, basis
        n = basis.nodes.size
        w = basis.weights
        self.space = role == "space"
        keep = np.ones(n, dtype=bool)
        if self.space and ends is not None:
            keep[0] = ends[0] != "value"
            keep[-1] = ends[1] != "value"
        self.test = self.trial = np.flatnonzero(keep)
        self.w = w
        self.interp = None
        if not self.space:
            self.left = np.diag(1.0 / np.sqrt(w))
            return
        if basis.kind == "chebyshev":
            # exact Galerkin integrals: Gauss-Legendre with n + 1 points integrates the products
            # of two degree n - 1 polynomials exactly (Clenshaw-Curtis at the nodes would alias
            # and converge only algebraically, measured)
            xg, wg = np.polynomial.legendre.leggauss(n + 1)
            low, high = basis.domain
            self.quad_w = wg * (high - low) / 2.0
            self.interp = basis.interpolation_matrix(low + (xg + 1.0) * (high - low) / 2.0)  # (n + 1, n)
            self.interp_d = self.interp @ basis.derivative
            self.derivative = basis.derivative
            self.stiffness = self.interp_d.T @ (self.quad_w[:, None] * self.interp_d)
            mass = self.interp.T @ (self.quad_w[:, None] * self.interp)
        else:
            h = np.diff(basis.nodes)
            k = np.zeros((n, n))
            for e, he in enumerate(h):
                k[e:e + 2, e:e + 2] += np.array([[1.0, -1.0], [-1.0, 1.0]]) / he
            self.derivative = None
            self.interp = None
            self.stiffness = k
            self.h = h
            mass = np.diag(w)  # lumped: second order, like the elements themselves
        t = self.test
        self.left = np.sqrt(w[t])[:, None] * np.linalg.inv(mass[np.ix_(t, t)] + tau * self.stiffness[np.ix_(t, t)])

    def _rows(self, full: np.ndarray) -> np.ndarray:
        return self.left @ full[self.test]

    def _weighted(self, f: np.ndarray) -> np.ndarray:
        """Quadrature weights times ``f`` at the quadrature points (f interpolated from the nodes)."""
        return self.quad_w * (self.interp @ f)

    def mass(self, f: np.ndarray) -> np.ndarray:
        """``f u`` tested: (test, all nodes)."""
        if not self.space or self.interp is None:
            return self._rows(np.diag(self.w * f))
        return self._rows(self.interp.T @ (self._weighted(f)[:, None] * self.interp))

    def first(self, f: np.ndarray) -> np.ndarray:
        """``f du/dx`` tested: (test, all nodes)."""
        if self.derivative is not None:
            return self._rows(self.interp.T @ (self._weighted(f)[:, None] * self.interp_d))
        # hat functions: on element e, phi_j' = -+1/h and int phi_i = h/2, with f at the midpoint
        n = self.basis.nodes.size
        mid = 0.5 * (f[:-1] + f[1:])
        a = np.zeros((n, n))
        for e, fe in enumerate(mid):
            a[e:e + 2, e:e + 2] += 0.5 * fe * np.array([[-1.0, 1.0], [-1.0, 1.0]])
        return self._rows(a)

    def second(self, f: np.ndarray) -> np.ndarray:
        """``f d2u/dx2`` tested (weak form, boundary fluxes apart): (test, all nodes).

        ``int f u'' phi = [f u' phi] - int f u' phi' - int f' u' phi``: a stiffness weighted by
        ``f`` and an advection by ``f'`` (Chebyshev: the derivative of f's interpolant, both
        integrals by the Gauss rule; linear elements: f at the element midpoints, f' the slope
        of f on each element, second order).
        """
        if self.derivative is not None:
            stiffness = self.interp_d.T @ (self._weighted(f)[:, None] * self.interp_d)
            return self._rows(-stiffness) - self.first(self.derivative @ f)
        n = self.basis.nodes.size
        k = np.zeros((n, n))
        a = np.zeros((n, n))
        for e, he in enumerate(self.h):
            k[e:e + 2, e:e + 2] += 0.5 * (f[e] + f[e + 1]) * np.array([[1.0, -1.0], [-1.0, 1.0]]) / he
            a[e:e + 2, e:e + 2] += 0.5 * (f[e + 1] - f[e]) / he * np.array([[-1.0, 1.0], [-1.0, 1.0]])
        return self._rows(-k - a)

    def load(self, f: np.ndarray) -> np.ndarray:
        """A source ``f`` tested: (test,)."""
        if not self.space or self.interp is None:
            return self.left @ (self.w * f)[self.test]
        return self.left @ (self.interp.T @ self._weighted(f))[self.test]

    def flux(self, side: int) -> np.ndarray:
        """``[du/dx phi]`` at one end: +phi(high), -phi(low), tested: (test,)."""
        e = np.zeros(self.basis.nodes.size)
        e[0 if side == 0 else -1] = -1.0 if side == 0 else 1.0
        return self.left @ e[self.test]


def boundary_kinds(problem, coord: str) -> tuple[str, str] | None:
    kinds = {tuple(b.kind for b in u.boundary[coord]) for u in problem.unknowns if coord in u.boundary}
    if len(kinds) > 1:
        raise SolverError(f"{problem.source}: unknowns: every unknown needs the same kinds of boundary conditions "
                          f"on {coord!r} (value or gradient at each end), found {sorted(kinds)}")
    return kinds.pop() if kinds else None


class TimeOps:
    """The time direction of the state mode: free nodes, the d/dt and mass rows, preconditioned.

    The rows are multiplied by ``sqrt(weights) (d/dt)^-1``, so the residual is the L2 norm of
    the time-integrated equation (see the module docstring).
    """

    def __init__(self, basis: Basis1D):
        self.basis = basis
        nt = basis.nodes.size
        self.size = nt - 1  # v(t0) = 0: the first node is not free
        integrate = np.linalg.inv(basis.time_stiffness(np.ones(nt))[:, 1:])
        self.left = np.sqrt(basis.time_weights())[:, None] * integrate

    def operator(self, values: np.ndarray, is_der: bool) -> np.ndarray:
        """``c(t) du/dt`` or ``c(t) u`` on the free nodes: (size, size)."""
        full = self.basis.time_stiffness(values) if is_der else self.basis.time_mass(values)
        return self.left @ full[:, 1:]

    def load(self, values: np.ndarray) -> np.ndarray:
        """A source ``f(t)``: (size,)."""
        return self.left @ self.basis.time_load(values)

    def constant(self, values: np.ndarray) -> np.ndarray:
        """``c(t) w`` for a ``w`` constant in time (the lift): (size,)."""
        return self.left @ (self.basis.time_mass(values) @ np.ones(self.basis.nodes.size))


class SteadyOps:
    """The time direction of a steady problem: none (one entry per unknown, no weight)."""

    size = 1

    def operator(self, values, is_der: bool) -> np.ndarray:
        return np.ones((1, 1))

    def load(self, values) -> np.ndarray:
        return np.ones(1)

    constant = load

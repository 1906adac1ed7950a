"""Independent method-of-lines reference for nonlinear PDEs in one space coordinate.

Fisher-KPP ``der(u) = D*der(u, x, 2) + r*u*(1 - u)`` and viscous Burgers
``der(u) = nu*der(u, x, 2) - u*der(u, x)`` are polynomial in the unknowns *and their space
derivatives*; the linear method-of-lines reference (:func:`pgdcli.checks.reference.solve_reference_pde`)
refuses them. This module solves them, one parameter sample at a time, by strong-form
Chebyshev-Gauss-Lobatto collocation in the space coordinate (the reference's own nodes and
differentiation matrices, never the solvers' bases), the boundary rows replaced by the
conditions (value ``u = g`` or gradient ``du/dx = g``) and the boundary values eliminated, and
``solve_ivp`` (Radau, the exact Jacobian) on the interior values. Every monomial of the parsed
equation is evaluated pointwise at the nodes: an atom ``u`` is the nodal values, ``der(u, x)`` and
``der(u, x, 2)`` are ``D u`` and ``D^2 u``, a general atom (``sin(u)``) its expression tree
(Jacobian then by finite differences).

Its own error is measured, not assumed: the solve is repeated on nested grids
(``n -> 2n - 1`` nodes) until two successive grids agree at the requested points within
``space_tolerance``; the returned ``error_estimate`` is that last difference (the coarser grid's
error, an upper estimate of the finer one's when the spectral convergence has set in) and a
caller must not certify errors below it. Measured against the exact Cole-Hopf solution of
Burgers (``tests/test_reference_pde_nonlinear.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from ..errors import SolverError
from ..problem.general import evaluate as general_tree_values, is_general, tree_of
from .reference import barycentric_matrix, chebyshev_differentiation, chebyshev_points, chebyshev_weights

__all__ = ["NonlinearPdeReference", "solve_reference_nonlinear_pde", "START_NODES", "MAX_NODES"]

START_NODES = 33
MAX_NODES = 513


@dataclass
class NonlinearPdeReference:
    """Values of the reference at the requested points.

    Attributes
    ----------
    values : dict of str to ndarray (S, T, P)
        Per unknown: sample, time, space point.
    error_estimate : float
        Max abs difference between the last two grids at the points (the reference's own error).
    nodes : int
        Space nodes of the finest grid.
    """

    values: dict
    error_estimate: float
    nodes: int


class _Model:
    """The collocated system at ``n`` nodes for one parameter sample."""

    def __init__(self, problem, n: int, sample: Mapping[str, float]) -> None:
        space = [c for c in problem.coordinates if getattr(c, "role", "") == "space"]
        if len(space) != 1:
            raise SolverError(f"{problem.source}: the nonlinear method-of-lines reference takes one space "
                              f"coordinate, got {len(space)}")
        coord = space[0]
        self.x_name, self.time = coord.name, problem.time
        self.x = chebyshev_points(n, coord.domain)
        D1 = chebyshev_differentiation(n, coord.domain)
        self.L = {0: None, 1: D1, 2: D1 @ D1}
        self.sample = {k: float(v) for k, v in sample.items()}
        names = list(problem.unknown_names)
        self.index = {u: i for i, u in enumerate(names)}
        self.q, self.n = len(names), n
        self.interior = np.arange(1, n - 1)
        # boundary elimination per unknown: u = Z y + h (y the interior values)
        self.Z, self.h = [], []
        for unknown in problem.unknowns:
            ends = unknown.boundary.get(coord.name)
            if ends is None:
                raise SolverError(f"{problem.source}: unknowns.{unknown.name}.boundary.{coord.name}: the nonlinear "
                                  "method-of-lines reference needs a condition at both ends")
            C, g = np.zeros((2, n)), np.zeros(2)
            for side, bc in enumerate(ends):
                node = 0 if side == 0 else n - 1
                C[side] = np.eye(n)[node] if bc.kind == "value" else D1[node]
                g[side] = float(np.broadcast_to(bc.value.evaluate(**self.sample), ()))
            B = np.array([0, n - 1])
            CBB, CBI = C[:, B], C[:, self.interior]
            Z = np.zeros((n, n - 2))
            Z[self.interior, np.arange(n - 2)] = 1.0
            Z[B] = -np.linalg.solve(CBB, CBI)
            h = np.zeros(n)
            h[B] = np.linalg.solve(CBB, g)
            self.Z.append(Z)
            self.h.append(h)
        self.owner, self.mass, self.rest, self.general = [], [], [], False
        for r, equation in enumerate(problem.equations):
            owner, mass, rest = None, None, []
            for monomial, sep in equation.polynomial.items():
                ders = [a for a in monomial if a.order > 0 and a.coordinate == self.time]
                if ders:
                    if len(monomial) != 1 or ders[0].order != 1:
                        raise SolverError(f"{problem.source}: equations[{r}]: the nonlinear method-of-lines "
                                          "reference takes der(u) linearly, first order in time")
                    owner, mass = self.index[ders[0].unknown], sep
                else:
                    self.general |= any(is_general(a) for a in monomial)
                    rest.append((monomial, sep))
            if owner is None:
                raise SolverError(f"{problem.source}: equations[{r}]: no der() of an unknown")
            self.owner.append(owner)
            self.mass.append(mass)
            self.rest.append(rest)

    def _coef(self, sep, t: float) -> np.ndarray:
        values = {**self.sample, self.x_name: self.x, self.time: np.asarray(t)}
        return np.broadcast_to(np.asarray(sep.evaluate(**values), dtype=float), (self.n,))

    def full(self, y: np.ndarray) -> np.ndarray:
        """Full nodal values (q, n) from the interior state (q (n - 2),)."""
        Y = y.reshape(self.q, self.n - 2)
        return np.stack([Z @ Y[s] + h for s, (Z, h) in enumerate(zip(self.Z, self.h))])

    def _atom(self, atom, U: np.ndarray, t: float) -> np.ndarray:
        if is_general(atom):
            values = {u: U[i] for u, i in self.index.items()}
            values.update({**self.sample, self.x_name: self.x, self.time: t})
            return np.broadcast_to(general_tree_values(tree_of(atom), values), (self.n,))
        L = self.L[atom.order] if atom.order else None
        return U[self.index[atom.unknown]] if L is None else L @ U[self.index[atom.unknown]]

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        U = self.full(y)
        out = np.empty((self.q, self.n - 2))
        for r, rest in enumerate(self.rest):
            G = np.zeros(self.n)
            for monomial, sep in rest:
                product = self._coef(sep, t).copy()
                for atom in monomial:
                    product = product * self._atom(atom, U, t)
                G += product
            out[self.owner[r]] = -G[self.interior] / self._coef(self.mass[r], t)[self.interior]
        return out.ravel()

    def jacobian(self, t: float, y: np.ndarray) -> np.ndarray:
        """Exact Jacobian (q (n-2), q (n-2)) of :meth:`rhs` (polynomial monomials only)."""
        U = self.full(y)
        m = self.n - 2
        J = np.zeros((self.q * m, self.q * m))
        for r, rest in enumerate(self.rest):
            rows = slice(self.owner[r] * m, (self.owner[r] + 1) * m)
            scale = -1.0 / self._coef(self.mass[r], t)[self.interior]
            for monomial, sep in rest:
                coef = self._coef(sep, t)
                values = [self._atom(a, U, t) for a in monomial]
                for k, atom in enumerate(monomial):
                    others = coef.copy()
                    for j, v in enumerate(values):
                        if j != k:
                            others = others * v
                    s = self.index[atom.unknown]
                    L = self.L[atom.order] if atom.order else np.eye(self.n)
                    block = (others[:, None] * L) @ self.Z[s]
                    J[rows, s * m:(s + 1) * m] += scale[:, None] * block[self.interior]
        return J

    def initial(self, problem) -> np.ndarray:
        values = {**self.sample, self.x_name: self.x}
        u0 = [np.broadcast_to(u.initial.evaluate(**values), (self.n,)) for u in problem.unknowns]
        return np.concatenate([v[self.interior] for v in u0])


def _solve_sample(problem, n: int, sample, times, points, rtol, atol) -> np.ndarray:
    """Values (q, T, P) of one sample on an ``n``-node grid."""
    from scipy.integrate import solve_ivp

    model = _Model(problem, n, sample)
    t0 = float(next(c.domain[0] for c in problem.coordinates if c.name == problem.time))
    sol = solve_ivp(model.rhs, (t0, float(np.max(times))), model.initial(problem), method="Radau",
                    t_eval=np.asarray(times, dtype=float), rtol=rtol, atol=atol,
                    jac=None if model.general else model.jacobian)
    if sol.status != 0 or sol.y.shape[1] != len(times) or not np.isfinite(sol.y).all():
        raise SolverError(f"{problem.source}: the nonlinear method-of-lines reference failed at {dict(sample)} "
                          f"on {n} nodes: {sol.message}")
    W = barycentric_matrix(model.x, chebyshev_weights(n), points)
    full = np.stack([model.full(sol.y[:, k]) for k in range(sol.y.shape[1])], axis=1)  # (q, T, n)
    return full @ W.T


def solve_reference_nonlinear_pde(problem, params: Mapping[str, np.ndarray], times: np.ndarray,
                                  points: np.ndarray, *, space_tolerance: float = 1e-9, rtol: float = 1e-11,
                                  atol: float = 1e-11, start_nodes: int = START_NODES,
                                  max_nodes: int = MAX_NODES) -> NonlinearPdeReference:
    """The problem at samples x times x space points, on nested grids until they agree.

    Parameters
    ----------
    problem : Problem
        One space coordinate, equations ``A der(u) + sum of monomials = 0`` (monomials of unknowns,
        their space derivatives and general atoms).
    params : mapping of str to ndarray (S,)
        The parameter samples.
    times : ndarray (T,)
        Ascending output times (the start time may be included).
    points : ndarray (P,)
        Space points.
    space_tolerance : float
        Two successive grids must agree to this (max abs at the points) to stop.

    Returns
    -------
    NonlinearPdeReference
    """
    S = int(np.broadcast_shapes(*(np.shape(v) for v in params.values()))[0]) if params else 1
    arrays = {k: np.broadcast_to(np.asarray(v, dtype=float), (S,)) for k, v in params.items()}
    times = np.asarray(times, dtype=float)
    points = np.asarray(points, dtype=float)
    names = list(problem.unknown_names)
    n, previous, estimate = start_nodes, None, np.inf
    while True:
        current = np.stack([_solve_sample(problem, n, {k: v[i] for k, v in arrays.items()}, times, points,
                                          rtol, atol) for i in range(S)])  # (S, q, T, P)
        if previous is not None:
            estimate = float(np.max(np.abs(current - previous)))
            if estimate <= space_tolerance:
                break
        if 2 * n - 1 > max_nodes:
            break
        previous, n = current, 2 * n - 1
    return NonlinearPdeReference({u: current[:, i] for i, u in enumerate(names)}, estimate, n)

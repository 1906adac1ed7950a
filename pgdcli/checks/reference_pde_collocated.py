"""The collocated nonlinear PDE system of one parameter sample, for the nonlinear method-of-lines reference.

Strong-form Chebyshev-Gauss-Lobatto collocation on the tensor grid of one or two space coordinates
(the reference's own nodes and differentiation matrices, :mod:`.collocation_grid`, never the
solvers' bases), ``n`` nodes along each. Every unknown has the values at all grid nodes; those on
the boundary are eliminated: at a node on an end of ``x`` (the corners included) the condition of
``x`` holds, at the other boundary nodes that of ``y`` (value ``u = g``: the node's row of the
identity; gradient ``du/dx_a = g``: its row of ``D_a``), and the conditions of all boundary nodes
are solved together for their values from the interior ones: ``u = Z y + h`` with ``y`` the
interior values. (The solver instead eliminates the conditions of each coordinate on every line of
it, tensor-product fashion, with both conditions holding at the corners; the two agree as the grids
are refined wherever the data agree at the corners.)

Every monomial of each equation ``m der(u_s) + sum coefficient * monomial = 0`` is evaluated pointwise
at the nodes (the diffusion included, as any other monomial): an atom ``u`` is the nodal values,
``der(u, x_a)`` and ``der(u, x_a, 2)`` are ``D_a u`` and ``D_a^2 u`` along its axis, a general atom
(``sin(u)``) its expression tree. The Jacobian is exact for polynomial monomials; a general atom's
(pointwise) derivative is a central difference.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np
import scipy.sparse as sp

from ..errors import SolverError
from ..problem.general import evaluate as general_tree_values, is_general, tree_names, tree_of
from ..problem.separable import TimeSplit
from .collocation_grid import chebyshev_differentiation, chebyshev_points
from .reference_base import check_deadline

__all__ = ["CollocatedModel", "GridMap", "MAX_SPACE"]

#: Space coordinates the reference takes.
MAX_SPACE = 2
#: Relative step of the central difference of a general atom's derivative.
GENERAL_STEP = 1e-6


@dataclass(frozen=True)
class GridMap:
    """The grid of a collocated system and its map from interior states to nodal values: what a solution's
    values need besides the solution (picklable: a worker process sends it back with the solution).

    Attributes
    ----------
    n : int
        Nodes along each space coordinate.
    axes : list of ndarray (n,)
        Nodes per space coordinate.
    shape : tuple of int
        The grid, ``(n,)`` or ``(n, n)``.
    interior, boundary : ndarray of int
        Flattened indices (C order) of the interior and the boundary nodes.
    fill : list of (ndarray (boundary, interior), ndarray (boundary,))
        Per unknown, the boundary values ``B y + b`` of its interior values ``y``.
    """

    n: int
    axes: list
    shape: tuple
    interior: np.ndarray
    boundary: np.ndarray
    fill: list

    def full(self, y: np.ndarray) -> np.ndarray:
        """Full nodal values (q, N) from the interior state (q m,): ``Z y + h`` of each unknown, its
        boundary rows as one dense product (a sparse product's overhead is most of a small grid's step)."""
        q, m = len(self.fill), self.interior.size
        Y = y.reshape(q, m)
        U = np.empty((q, int(np.prod(self.shape))))
        U[:, self.interior] = Y
        for s, (B, b) in enumerate(self.fill):
            U[s, self.boundary] = B @ Y[s] + b
        return U


class CollocatedModel:
    """The collocated system at ``n`` nodes per space coordinate for one parameter sample.

    Attributes
    ----------
    space : list of str
    axes : list of ndarray
        Nodes per space coordinate.
    q : int
        Unknowns.
    """

    def __init__(self, problem, n: int, sample: Mapping[str, float]) -> None:
        self._steady: dict = {}
        space = [c for c in problem.coordinates if getattr(c, "role", "") == "space"]
        if not 1 <= len(space) <= MAX_SPACE:
            raise SolverError(f"{problem.source}: the nonlinear method-of-lines reference takes one or two space "
                              f"coordinates, got {len(space)}")
        self.space, self.time, self.n = [c.name for c in space], problem.time, n
        self.axes = [chebyshev_points(n, c.domain) for c in space]
        self.shape = (n,) * len(space)
        self.N = n ** len(space)
        D = [chebyshev_differentiation(n, c.domain) for c in space]
        self.ops = {}  # (axis, order) -> sparse (N, N) on the flattened grid (C order): the Jacobian's
        self._along = {}  # (axis, order) -> dense (n, n) along its axis: the right-hand side's
        eye = sp.identity(n, format="csr")
        for a, Da in enumerate(D):
            for order, M in ((1, Da), (2, Da @ Da)):
                self._along[(a, order)] = np.ascontiguousarray(M)
                factors = [sp.csr_matrix(M) if b == a else eye for b in range(len(space))]
                op = factors[0]
                for f in factors[1:]:
                    op = sp.kron(op, f, format="csr")
                self.ops[(a, order)] = op
        self.sample = {k: float(v) for k, v in sample.items()}
        self.grid = self._grid_values()
        names = list(problem.unknown_names)
        self.index = {u: i for i, u in enumerate(names)}
        self.q = len(names)
        self._boundary(problem, D)
        self._equations(problem)

    def _grid_values(self) -> dict:
        mesh = np.meshgrid(*self.axes, indexing="ij")
        return {name: m.ravel() for name, m in zip(self.space, mesh)}

    # -- boundary elimination ------------------------------------------------------------------
    def _boundary(self, problem, D: list) -> None:
        """Per unknown, ``Z`` (N, N_interior) sparse (the Jacobian's) and the :class:`GridMap`'s boundary
        values ``B y + b``: ``u = Z y + h``, ``h`` the ``b`` at the boundary nodes.

        One condition per boundary node (that of the first space coordinate whose end it is on), the
        system of all boundary nodes solved for their values from the interior ones.
        """
        n, N = self.n, self.N
        multi = np.stack(np.unravel_index(np.arange(N), self.shape), axis=1)  # (N, d)
        at_end = (multi == 0) | (multi == n - 1)
        boundary = np.flatnonzero(at_end.any(axis=1))
        self.interior = np.flatnonzero(~at_end.any(axis=1))
        self.m = self.interior.size
        axis_of = np.argmax(at_end[boundary], axis=1)  # the first coordinate whose end the node is on
        side_of = (multi[boundary, axis_of] == n - 1).astype(int)
        self.Z, fill = [], []  # fill: per unknown, the boundary values' (B, b): B y + b
        for unknown in problem.unknowns:
            C = np.zeros((boundary.size, N))
            g = np.zeros(boundary.size)
            for k, (node, a, side) in enumerate(zip(boundary, axis_of, side_of)):
                ends = unknown.boundary.get(self.space[a])
                if ends is None:
                    raise SolverError(f"{problem.source}: unknowns.{unknown.name}.boundary.{self.space[a]}: the "
                                      "nonlinear method-of-lines reference needs a condition at both ends")
                bc = ends[side]
                if bc.kind == "value":
                    C[k, node] = 1.0
                else:
                    C[k] = self.ops[(a, 1)][node].toarray()[0]
                point = {name: float(self.grid[name][node]) for b, name in enumerate(self.space) if b != a}
                values = {**self.sample, **point}
                g[k] = float(np.broadcast_to(bc.value.evaluate(**{c: values[c] for c in bc.value.coordinates}), ()))
            inverse = np.linalg.inv(C[:, boundary])
            Z = sp.lil_matrix((N, self.m))
            Z[self.interior, np.arange(self.m)] = 1.0
            Z[boundary] = -inverse @ C[:, self.interior]
            self.Z.append(sp.csr_matrix(Z))
            fill.append((-inverse @ C[:, self.interior], inverse @ g))
        self.grid_map = GridMap(n, self.axes, self.shape, self.interior, boundary, fill)

    # -- equations ------------------------------------------------------------------------------
    def _equations(self, problem) -> None:
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
        """A coefficient at the nodes at time ``t`` (the parts free of time evaluated once)."""
        key = id(sep)  # the Separable is kept alive by the problem
        if key not in self._steady:
            values = {**self.sample, **self.grid}
            if self.time in sep.coordinates:
                self._steady[key] = TimeSplit(sep, self.time, values)
            else:
                self._steady[key] = np.broadcast_to(
                    np.asarray(sep.evaluate(**{k: values[k] for k in sep.coordinates}), float), (self.N,))
        coef = self._steady[key]
        return np.broadcast_to(coef(t), (self.N,)) if callable(coef) else coef

    def full(self, y: np.ndarray) -> np.ndarray:
        """Full nodal values (q, N) from the interior state (q m,) (:meth:`GridMap.full`)."""
        return self.grid_map.full(y)

    def derivative(self, axis: int, order: int, u: np.ndarray) -> np.ndarray:
        """``der(u, x_axis, order)`` at the nodes (N,): the dense 1-D matrix along its axis of the grid."""
        M = self._along[(axis, order)]
        if len(self.shape) == 1:
            return M @ u
        grid = u.reshape(self.shape)
        return (M @ grid if axis == 0 else grid @ M.T).ravel()

    def _values(self, U: np.ndarray, t: float) -> dict:
        return {**self.sample, **self.grid, self.time: t, **{u: U[i] for u, i in self.index.items()}}

    def _atom(self, atom, U: np.ndarray, t: float, values=None) -> np.ndarray:
        if is_general(atom):
            return np.broadcast_to(general_tree_values(tree_of(atom), values or self._values(U, t)), (self.N,))
        u = U[self.index[atom.unknown]]
        if not atom.order:
            return u
        return self.derivative(self.space.index(atom.coordinate), atom.order, u)

    def rhs(self, t: float, y: np.ndarray) -> np.ndarray:
        check_deadline()
        U = self.full(y)
        values = self._values(U, t) if self.general else None
        out = np.empty((self.q, self.m))
        for r, rest in enumerate(self.rest):
            G = np.zeros(self.N)
            for monomial, sep in rest:
                product = self._coef(sep, t).copy()
                for atom in monomial:
                    product = product * self._atom(atom, U, t, values)
                G += product
            out[self.owner[r]] = -G[self.interior] / self._coef(self.mass[r], t)[self.interior]
        return out.ravel()

    def jacobian(self, t: float, y: np.ndarray):
        """The Jacobian (q m, q m) of :meth:`rhs`, sparse: exact for polynomial monomials, a central
        difference of each general atom along the unknowns it holds (pointwise)."""
        check_deadline()
        U = self.full(y)
        values = self._values(U, t) if self.general else None
        blocks = [[None] * self.q for _ in range(self.q)]
        for r, rest in enumerate(self.rest):
            row = self.owner[r]
            scale = -1.0 / self._coef(self.mass[r], t)[self.interior]
            for monomial, sep in rest:
                coef = self._coef(sep, t)
                atoms = [self._atom(a, U, t, values) for a in monomial]
                for k, atom in enumerate(monomial):
                    others = coef.copy()
                    for j, v in enumerate(atoms):
                        if j != k:
                            others = others * v
                    for s, L in self._derivative(atom, U, t, values):
                        block = (sp.diags(others[self.interior] * scale) @ L[self.interior]) @ self.Z[s]
                        blocks[row][s] = block if blocks[row][s] is None else blocks[row][s] + block
        for i in range(self.q):
            for j in range(self.q):
                if blocks[i][j] is None:
                    blocks[i][j] = sp.csr_matrix((self.m, self.m))
        return sp.bmat(blocks, format="csc")

    def _derivative(self, atom, U, t, values):
        """``[(species, d atom / d u_species as a sparse (N, N) operator)]``."""
        if not is_general(atom):
            s = self.index[atom.unknown]
            L = self.ops[(self.space.index(atom.coordinate), atom.order)] if atom.order else \
                sp.identity(self.N, format="csr")
            return [(s, L)]
        tree = tree_of(atom)
        out = []
        for name in tree_names(tree) & set(self.index):
            s = self.index[name]
            step = GENERAL_STEP * np.maximum(1.0, np.abs(U[s]))
            up = general_tree_values(tree, {**values, name: U[s] + step})
            down = general_tree_values(tree, {**values, name: U[s] - step})
            out.append((s, sp.diags(np.broadcast_to((up - down) / (2 * step), (self.N,)), format="csr")))
        return out

    def initial(self, problem) -> np.ndarray:
        values = {**self.sample, **self.grid}
        u0 = [np.broadcast_to(u.initial.evaluate(**{k: values[k] for k in u.initial.coordinates}), (self.N,))
              for u in problem.unknowns]
        return np.concatenate([v[self.interior] for v in u0])

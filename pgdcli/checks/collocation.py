"""The linear operator of a problem on the collocation grid of :mod:`.collocation_grid`, for the
method-of-lines reference: its boundary elimination (:class:`PdeModel`) and its time-dependent
assembly per sample (:class:`PdeSystem`). Written here from scratch so that it shares nothing with
the PGD solver's weak-form discretization (pgdcli.discretization).

``PdeModel`` and ``PdeSystem`` are the one linear operator of a problem, built once and assembled
per sample and time (:class:`~pgdcli.checks.collocation_system.PdeSystem`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import SolverError
from ..problem.expressions import format_monomial
from .collocation_grid import (SpaceGrid, barycentric_matrix, chebyshev_differentiation, chebyshev_points,
                               chebyshev_weights)
from .reference_base import sampled_coordinates, space_coordinates

__all__ = ["chebyshev_points", "chebyshev_weights", "chebyshev_differentiation", "barycentric_matrix"]


def _term_parts(term, time: str, space: list[str]):
    """A SepTerm split into (coef, time function or None, parameter factors, space factors)."""
    time_func, param_factors, space_factors = None, [], []
    for name, func in term.factors:
        if name == time:
            time_func = func
        elif name in space:
            space_factors.append((name, func))
        else:
            param_factors.append((name, func))
    return term.coef, time_func, param_factors, space_factors


class PdeModel:
    """Sample-independent pieces of the method-of-lines system.

    Per unknown ``s``, the grid points on an end of a coordinate where ``s`` has boundary
    conditions are boundary points; each carries one condition (a value condition if one of its
    coordinates gives one, else the gradient condition of its first coordinate) in place of the
    collocated equation there. The conditions ``C_BB u_B + C_BI u_I = g`` give
    ``u_B = E u_I + C_BB^-1 g`` with ``E = -C_BB^-1 C_BI``; the full state is ``u = Z y + h``
    over the interior values ``y``. The equation rows kept (``R``) are, for every equation, the
    interior points of the unknown whose ``der()`` it holds. Each term of each coefficient gives a
    matrix ``R (c * L) Z`` (``L`` the identity or a derivative) weighted per sample by its
    parameter factors and per time by its time function.
    """

    def __init__(self, problem, nodes: Mapping[str, int]) -> None:
        import scipy.sparse as sp

        self.problem = problem
        time = problem.time
        self.time = time
        coords = space_coordinates(problem)
        self.space = [c.name for c in coords]
        self.params = [c.name for c in sampled_coordinates(problem)]
        grid = SpaceGrid(coords, nodes)
        self.grid = grid
        n = grid.n
        self.index = {u: i for i, u in enumerate(problem.unknown_names)}
        q = self.q = len(self.index)
        self.owners = self._equation_owners(problem, self.index, q)

        # -- boundary points, conditions and the elimination u = Z y + h ----------------------------
        interior_cols, z_blocks, self.boundary = [], [], []
        offsets = np.zeros(q + 1, dtype=int)
        for s, unknown in enumerate(problem.unknowns):
            B, Iidx, choice, lu, Zs = self._eliminate_boundary(unknown)
            self.boundary.append((B, Iidx, choice, lu))
            z_blocks.append(Zs)
            interior_cols.append(Iidx)
            offsets[s + 1] = offsets[s] + Iidx.size
        self.interior = interior_cols
        self.offsets = offsets
        self.m = int(offsets[-1])
        self.Z = sp.block_diag(z_blocks, format="csr")
        # kept rows of the full (q n) system, in the order of the interior unknowns
        self.rows = np.concatenate([r * n + interior_cols[self.owners[r]] for r in range(q)])

        self.ops = []  # (kind 'mass'|'op', time key, time func, param factors, coef, R A Z, R A (for h))
        self.sources = []  # (time key, time func, param factors, coef, R-rows vector)
        self.joint_sources = []  # (equation row, Joint): non-separable sources, evaluated from their trees
        self.joint_ops = []  # (equation row, unknown, derivative or None, Joint): non-separable coefficients
        for r, equation in enumerate(problem.equations):
            for monomial, sep in equation.polynomial.items():
                self._add_term(r, monomial, sep)
        self.time_funcs = {}
        for entry in self.ops:
            if entry[1] is not None:
                self.time_funcs[entry[1]] = entry[2]
        for entry in self.sources:
            if entry[0] is not None:
                self.time_funcs[entry[0]] = entry[1]
        self.static_mass = all(key is None for kind, key, *_ in self.ops if kind == "mass")

    @staticmethod
    def _equation_owners(problem, index: Mapping[str, int], q: int) -> list[int]:
        """The unknown each equation belongs to (its rows at boundary points are replaced): the one
        whose ``der()`` it holds, or the unknowns in order when that does not assign them one to one."""
        owners = []
        for equation in problem.equations:
            ders = {a.unknown for m in equation.polynomial for a in m if a.order == 1 and a.coordinate == problem.time}
            owners.append(index[next(iter(ders))] if len(ders) == 1 else None)
        if None in owners or len(set(owners)) != q:
            owners = list(range(q))  # equations in unknown order
        return owners

    def _boundary_choice(self, conds: Mapping, B: np.ndarray) -> list[tuple]:
        """Per boundary point ``p``: ``(p, coordinate, side, Boundary)``, a value condition of one of
        its coordinates if there is one, else the first coordinate's (gradient) condition."""
        grid = self.grid
        choice = []
        for p in B:
            candidates = []
            for c in grid.names:
                if c not in conds:
                    continue
                ix = grid.index[c][p]
                last = grid.shape[grid.names.index(c)] - 1
                if ix == 0 or ix == last:
                    side = 0 if ix == 0 else 1
                    candidates.append((c, side, conds[c][side]))
            values = [cand for cand in candidates if cand[2].kind == "value"]
            choice.append((int(p),) + (values[0] if values else candidates[0]))
        return choice

    def _eliminate_boundary(self, unknown) -> tuple:
        """One unknown's boundary points ``B``, interior points ``I``, conditions, the LU of ``C_BB`` (or
        None) and ``Z_s`` (n, |I|): identity rows at ``I``, ``E = -C_BB^-1 C_BI`` at ``B``."""
        import scipy.sparse as sp

        grid, n = self.grid, self.grid.n
        conds = {c: ends for c, ends in unknown.boundary.items() if c in self.space}
        on_end = np.zeros(n, dtype=bool)
        for c in conds:
            ix = grid.index[c]
            on_end |= (ix == 0) | (ix == grid.shape[grid.names.index(c)] - 1)
        B = np.flatnonzero(on_end)
        Iidx = np.flatnonzero(~on_end)
        choice = self._boundary_choice(conds, B)
        E = np.zeros((B.size, Iidx.size))
        lu = None
        if B.size:
            import scipy.linalg as sla

            C = np.zeros((B.size, n))
            for row, (p, c, side, bc) in enumerate(choice):
                if bc.kind == "value":
                    C[row, p] = 1.0
                else:
                    C[row] = grid.derivative(c, 1)[p].toarray().ravel()
            CBB, CBI = C[:, B], C[:, Iidx]
            cond = np.linalg.cond(CBB)
            if not cond < 1e12:
                raise SolverError(f"{self.problem.source}: unknowns.{unknown.name}.boundary: the boundary conditions "
                                  "do not determine the boundary values of the method-of-lines reference "
                                  f"(condition number {cond:.3g})")
            lu = sla.lu_factor(CBB)
            E = -sla.lu_solve(lu, CBI)
            E[np.abs(E) <= 1e-15 * max(1.0, float(np.max(np.abs(E))))] = 0.0
        Zs = sp.lil_matrix((n, Iidx.size))
        Zs[Iidx, np.arange(Iidx.size)] = 1.0
        if B.size:
            Zs[B, :] = E
        return B, Iidx, choice, lu, Zs.tocsr()

    def _place(self, r: int, s: int, block):
        """The (q n, q n) matrix with ``block`` at block row ``r`` (equation), column ``s`` (unknown)."""
        import scipy.sparse as sp

        q, n = self.q, self.grid.n
        blocks = [[None] * q for _ in range(q)]
        blocks[r][s] = block
        for i in range(q):  # bmat needs every block row and column sized
            if blocks[i][i] is None:
                blocks[i][i] = sp.csr_matrix((n, n))
        return sp.bmat(blocks, format="csr")

    def _add_term(self, r: int, monomial, sep) -> None:
        """Equation ``r``'s term in ``monomial`` (no unknown: a source; one unknown, maybe differentiated:
        an operator) into :attr:`ops`, :attr:`sources`, :attr:`joint_ops` or :attr:`joint_sources`."""
        import scipy.sparse as sp

        problem, time, grid, n = self.problem, self.time, self.grid, self.grid.n
        if len(monomial) > 1:
            raise SolverError(
                f"{problem.source}: equations[{r}]: nonlinear term '{format_monomial(monomial, time)}': the "
                "method-of-lines reference supports equations linear in the unknowns"
            )
        if sep.joints and monomial:
            atom = monomial[0]
            if atom.order == 1 and atom.coordinate == time:
                raise SolverError(
                    f"{problem.source}: equations[{r}]: the method-of-lines reference does not support a "
                    f"non-separable coefficient of der({atom.unknown}) ('{sep.joints[0].function_text()}')")
            L = None if atom.order == 0 else grid.derivative(atom.coordinate, atom.order)
            self.joint_ops += [(r, self.index[atom.unknown], L, joint) for joint in sep.joints]
        elif sep.joints:
            self.joint_sources += [(r, joint) for joint in sep.joints]
        for term in sep.terms:
            coef, tfunc, pf, sf = _term_parts(term, time, self.space)
            values = np.ones(n)
            for name, func in sf:
                values = values * np.broadcast_to(func(grid.values[name]), (n,))
            key = None if tfunc is None else tfunc.tree
            if not monomial:
                full = np.zeros(self.q * n)
                full[r * n:(r + 1) * n] = values
                self.sources.append((key, tfunc, pf, coef, full[self.rows]))
                continue
            atom = monomial[0]
            if atom.order == 1 and atom.coordinate == time:
                kind, L = "mass", None
            elif atom.order == 0:
                kind, L = "op", None
            else:
                kind, L = "op", grid.derivative(atom.coordinate, atom.order)
            block = sp.diags(values) if L is None else sp.diags(values) @ L
            A = self._place(r, self.index[atom.unknown], sp.csr_matrix(block))[self.rows]
            self.ops.append((kind, key, tfunc, pf, coef, (A @ self.Z).tocsr(), A))

    # -- per-sample data ---------------------------------------------------------------------------
    @staticmethod
    def weights(pf, coef: float, params: Mapping[str, np.ndarray], S: int) -> np.ndarray:
        w = np.full(S, float(coef))
        for name, func in pf:
            w = w * np.broadcast_to(func(params[name]), (S,))
        return w

    def boundary_lift(self, params: Mapping[str, np.ndarray], S: int) -> np.ndarray:
        """``h`` (S, q n): boundary values from the conditions at every sample."""
        import scipy.linalg as sla

        n = self.grid.n
        h = np.zeros((S, self.q * n))
        for s, (B, _, choice, lu) in enumerate(self.boundary):
            if not B.size:
                continue
            g = np.zeros((S, B.size))
            for row, (p, c, side, bc) in enumerate(choice):
                if bc.value.is_zero:
                    continue
                at = {name: params[name] for name in self.params}
                at.update({name: np.full(S, self.grid.values[name][p]) for name in self.space})
                g[:, row] = np.broadcast_to(bc.value.evaluate(**at), (S,))
            h[:, s * n + B] = sla.lu_solve(lu, g.T).T
        return h

    def joint_values(self, joint, params: Mapping[str, np.ndarray], S: int, t: float | None) -> np.ndarray:
        """A non-separable coefficient on the grid at every sample, from its tree: (S, n)."""
        at = {name: params[name][:, None] for name in self.params}
        at.update({name: self.grid.values[name][None, :] for name in self.space})
        if t is not None:
            at[self.time] = np.asarray(float(t))
        return np.broadcast_to(joint.evaluate(**at), (S, self.grid.n))

    def joint_source(self, joints, params: Mapping[str, np.ndarray], S: int, t: float | None) -> np.ndarray:
        """Non-separable sources at time t (None: steady or not timed), on the kept rows: (S m,)."""
        n = self.grid.n
        full = np.zeros((S, self.q * n))
        for r, joint in joints:
            full[:, r * n:(r + 1) * n] += self.joint_values(joint, params, S, t)
        return full[:, self.rows].reshape(-1)

    def joint_operators(self, entries, params: Mapping[str, np.ndarray], S: int, t: float | None) -> list:
        """Per sample, the rows ``R (c L)`` of non-separable coefficients ``c`` of unknowns: (m, q n) each."""
        import scipy.sparse as sp

        n, q = self.grid.n, self.q
        out = [sp.csr_matrix((self.rows.size, q * n)) for _ in range(S)]
        for r, s, L, joint in entries:
            values = self.joint_values(joint, params, S, t)
            place = sp.csr_matrix(([1.0], ([r], [s])), shape=(q, q))
            for i in range(S):
                block = sp.diags(values[i]) if L is None else sp.diags(values[i]) @ L
                out[i] = out[i] + sp.kron(place, block, format="csr")[self.rows]
        return out

    def initial_grid(self, params: Mapping[str, np.ndarray], S: int) -> np.ndarray:
        """Initial values (S, q, n) at the grid nodes."""
        n = self.grid.n
        at = {name: params[name][:, None] for name in self.params}
        at.update({name: self.grid.values[name][None, :] for name in self.space})
        out = np.empty((S, self.q, n))
        for s, unknown in enumerate(self.problem.unknowns):
            out[:, s, :] = np.broadcast_to(unknown.initial.evaluate(**at), (S, n)) if unknown.initial.terms else 0.0
        return out

    def interior_values(self, full: np.ndarray) -> np.ndarray:
        """Interior values (S, m) of full grid values (S, q, n)."""
        return np.concatenate([full[:, s, self.interior[s]] for s in range(self.q)], axis=1)

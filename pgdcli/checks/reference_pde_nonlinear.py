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
from functools import partial
from typing import Mapping

import numpy as np

from .. import executors
from ..errors import SolverError
from ..problem.general import evaluate as general_tree_values, has_general, is_general, tree_of
from .collocation import barycentric_matrix, chebyshev_differentiation, chebyshev_points, chebyshev_weights
from .reference_base import TIME_UP, ReferenceTimeUp, check_deadline, under_deadline
from .reference_ode import parse_cached
from .reference_pde import PdeReferenceResult

__all__ = ["NonlinearPdeReference", "solve_reference_nonlinear_pde", "solve_reference_nonlinear_grid",
           "is_nonlinear_pde", "START_NODES", "MAX_NODES"]

START_NODES = 33
MAX_NODES = 513
#: Radau's rtol = atol.
RTOL = 1e-11
#: A sample whose two finest grids still differ by more than this (at MAX_NODES) counts as failed.
SPACE_TOLERANCE_LIMIT = 1e-8


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
        self._steady: dict = {}  # coefficients without time, by id of their (kept alive) Separable
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
        steady = self.time not in sep.coordinates  # evaluated once (it was a quarter of the solve)
        if steady and id(sep) in self._steady:
            return self._steady[id(sep)]
        values = {**self.sample, self.x_name: self.x, self.time: np.asarray(t)}
        out = np.broadcast_to(np.asarray(sep.evaluate(**values), dtype=float), (self.n,))
        if steady:
            self._steady[id(sep)] = out
        return out

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
        check_deadline()
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


#: Solutions kept (dense output per sample and grid): the error gate checks the codebooks of successive
#: rounds of the automatic resolution at the same parameter samples, and the reference is most of its time.
CACHE_SIZE = 64
_SOLUTIONS: dict = {}


def _sample_solution(problem, n: int, sample, t_end: float, rtol, atol):
    """``(model, OdeSolution)`` of one sample on an ``n``-node grid over ``[t0, t_end]`` (cached)."""
    from scipy.integrate import solve_ivp

    key = (problem.source_text, tuple(sorted((k, float(v)) for k, v in sample.items())), n, float(t_end), rtol, atol)
    if key in _SOLUTIONS:
        return _SOLUTIONS[key]
    model = _Model(problem, n, sample)
    t0 = float(next(c.domain[0] for c in problem.coordinates if c.name == problem.time))
    # solve_ivp's t_eval is read from the same dense output: keeping it changes nothing in accuracy
    sol = solve_ivp(model.rhs, (t0, t_end), model.initial(problem), method="Radau", dense_output=True,
                    rtol=rtol, atol=atol, jac=None if model.general else model.jacobian)
    if sol.status != 0 or not np.isfinite(sol.y).all():
        raise SolverError(f"{problem.source}: the nonlinear method-of-lines reference failed at {dict(sample)} "
                          f"on {n} nodes: {sol.message}")
    if len(_SOLUTIONS) >= CACHE_SIZE:
        _SOLUTIONS.pop(next(iter(_SOLUTIONS)))
    _SOLUTIONS[key] = (model, sol.sol)
    return model, sol.sol


def _solve_sample(problem, n: int, sample, times, points, rtol, atol) -> np.ndarray:
    """Values (q, T, P) of one sample on an ``n``-node grid."""
    t_end = float(next(c.domain[1] for c in problem.coordinates if c.name == problem.time))
    model, sol = _sample_solution(problem, n, sample, max(t_end, float(np.max(times))), rtol, atol)
    W = barycentric_matrix(model.x, chebyshev_weights(n), points)
    Y = sol(np.asarray(times, dtype=float))  # (q (n - 2), T)
    full = np.stack([model.full(Y[:, k]) for k in range(Y.shape[1])], axis=1)  # (q, T, n)
    return full @ W.T


def solve_reference_nonlinear_pde(problem, params: Mapping[str, np.ndarray], times: np.ndarray,
                                  points: np.ndarray, *, space_tolerance: float = 1e-9, rtol: float = RTOL,
                                  atol: float = RTOL, start_nodes: int = START_NODES,
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


def is_nonlinear_pde(problem) -> bool:
    """A problem with space coordinates whose equations are not linear in the unknowns (this module's case)."""
    space = any(getattr(c, "role", "") == "space" for c in problem.coordinates)
    return space and any(eq.polynomial.degree >= 2 or has_general(eq.polynomial) for eq in problem.equations)


def solve_reference_nonlinear_grid(problem, params: Mapping[str, np.ndarray], space_points: Mapping[str, np.ndarray],
                                   times: np.ndarray, *, progress=None, executor=None, **_ignored) -> PdeReferenceResult:
    """:func:`solve_reference_nonlinear_pde` in the form of the linear reference's grid result (``pgd verify``).

    Each sample is solved on its own (its grids refined until they agree), so that a failing sample is
    reported alone (NaN values, ``success`` False, the message), by the workers of ``executor`` (default:
    the one in effect, :mod:`pgdcli.executors`). The method-of-lines options of the linear reference
    (``method``, ``space_nodes``, ...) do not apply and are ignored.

    Returns
    -------
    pgdcli.checks.reference_pde.PdeReferenceResult
        ``values[u]`` of shape (S, T, P) on the space points of the one space coordinate.
    """
    (x_name, points), = space_points.items()
    S = int(np.broadcast_shapes(*(np.shape(v) for v in params.values()))[0]) if params else 1
    arrays = {k: np.broadcast_to(np.asarray(v, dtype=float), (S,)) for k, v in params.items()}
    times = np.asarray(times, dtype=float)
    names = list(problem.unknown_names)
    values = {u: np.full((S, times.size, np.size(points)), np.nan) for u in names}
    success, messages, nodes = np.zeros(S, dtype=bool), [""] * S, START_NODES
    samples = [{k: v[i:i + 1] for k, v in arrays.items()} for i in range(S)]
    runner = executors.as_executor(executor) if executor is not None else executors.current()
    if problem.source_text and not isinstance(runner, executors.SerialExecutor):
        task = under_deadline(partial(_sample_task, problem.source_text, problem.source, times, points))
    else:
        runner, task = executors.SERIAL, partial(_one_sample, problem, times=times, points=points)
    for done, (i, outcome) in enumerate(runner.as_completed(task, samples), 1):
        try:
            found, message = outcome.result()
        except ReferenceTimeUp:  # the samples after it stop at once too
            found, message = None, TIME_UP
        messages[i] = message
        if found is not None:
            success[i] = True
            nodes = max(nodes, found.nodes)
            for u in names:
                values[u][i] = found.values[u][0]
        if progress is not None:
            progress(done)
    return PdeReferenceResult(values=values, success=success, messages=messages, space=[x_name],
                              space_points={x_name: np.asarray(points)}, nodes={x_name: nodes}, method="Radau",
                              rtol=RTOL, atol=RTOL, times=times)


def _one_sample(problem, sample, times, points) -> tuple[NonlinearPdeReference | None, str]:
    """One sample's reference and ``''``, or None and why it failed (ReferenceTimeUp: the time budget)."""
    try:
        ref = solve_reference_nonlinear_pde(problem, sample, times, points)
    except SolverError as exc:
        return None, " ".join(str(exc).split())
    if ref.error_estimate > SPACE_TOLERANCE_LIMIT:
        return None, (f"the reference's grids did not agree (difference {ref.error_estimate:.2g} with "
                      f"{ref.nodes} nodes)")
    return ref, ""


def _sample_task(spec_text: str, source: str, times, points, sample):
    """A worker's task: parse the spec again, solve one sample (:func:`_one_sample`)."""
    return _one_sample(parse_cached(spec_text, source), sample, times, points)

"""The ODE reference's right-hand side: the equations compiled pointwise from their parsed polynomials,
evaluated at S parameter samples at once, and its exact Jacobian.

Used by the references (:mod:`pgdcli.checks.reference_ode`), their cost estimate
(:mod:`pgdcli.checks.budget`) and the choice of their method (:mod:`pgdcli.checks.stiffness`).
"""

from __future__ import annotations

import functools
from typing import Mapping

import numpy as np

from ..errors import SolverError
from ..problem.derivative import derivative
from ..problem.expressions import format_monomial
from ..problem.general import evaluate as general_tree_values
from ..problem.general import is_general, tree_of
from ..problem.trees import num_value
from .reference_base import count_evaluation

__all__ = ["CompiledCoefficient", "CompiledSystem", "reference_jacobian"]

class CompiledCoefficient:
    """A Separable coefficient at S parameter samples: ``static(p) + sum_i w_i(p) f_i(t) + sum_j g_j(t, p)``.

    The non-separable parts ``g_j`` (joints) are evaluated from their expression trees
    directly, at the samples and the time of each call: never from the solvers' separation.
    """

    __slots__ = ("static", "timed", "is_static", "joints", "params", "time", "S", "_recent")

    #: Values kept by time: an implicit step's Newton iterations evaluate the same stage times again.
    RECENT = 8

    def __init__(self, sep, time: str, params: Mapping[str, np.ndarray], S: int) -> None:
        self.params, self.time, self.S = params, time, S
        self.joints = [joint for joint in sep.joints if time in joint.coordinates]
        static = np.zeros(S)
        for joint in sep.joints:
            if time not in joint.coordinates:
                static = static + np.broadcast_to(joint.evaluate(**params), (S,))
        timed: dict = {}
        for term in sep.terms:
            weight = np.full(S, term.coef)
            time_func = None
            for name, func in term.factors:
                if name == time:
                    time_func = func
                else:
                    weight = weight * func(params[name])
            if time_func is None:
                static = static + weight
            else:
                # terms with the same time function share one evaluation
                key = time_func.tree
                if key in timed:
                    timed[key] = (time_func, timed[key][1] + weight)
                else:
                    timed[key] = (time_func, weight)
        self.static = static
        self.timed = list(timed.values())
        self.is_static = not self.timed and not self.joints
        self._recent: dict = {}

    def at(self, t: float) -> np.ndarray:
        """The coefficient at time ``t``, shape (S,) (read-only: the value may be shared between calls)."""
        if self.is_static:
            return self.static
        t = float(t)
        out = self._recent.get(t)
        if out is None:
            if len(self._recent) >= self.RECENT:
                self._recent.clear()
            out = self._recent[t] = self._evaluate(t)
            out.flags.writeable = False
        return out

    def _evaluate(self, t: float) -> np.ndarray:
        out = self.static
        for func, weight in self.timed:
            out = out + weight * float(func(t))
        if self.joints:
            values = {**self.params, self.time: np.asarray(float(t))}
            for joint in self.joints:
                out = out + np.broadcast_to(joint.evaluate(**values), (self.S,))
        return out


class CompiledSystem:
    """``u' = F(t, u)`` for S samples at once, from the problem's polynomials."""

    def __init__(self, problem, params: Mapping[str, np.ndarray], S: int, max_evaluations: int) -> None:
        time = problem.time
        names = list(problem.unknown_names)
        index = {name: i for i, name in enumerate(names)}
        self.q = q = len(names)
        self.S = S
        self.max_evaluations = max_evaluations
        self.evaluations = 0
        der: list[list[tuple[int, CompiledCoefficient]]] = [[] for _ in range(q)]
        rest: list[list[tuple[tuple[int, ...], CompiledCoefficient]]] = [[] for _ in range(q)]
        for r, equation in enumerate(problem.equations):
            for monomial, sep in equation.polynomial.items():
                derivatives = [a for a in monomial if a.order > 0]
                for atom in derivatives:
                    if atom.order != 1 or atom.coordinate != time:
                        raise SolverError(
                            f"{problem.source}: equations[{r}]: the reference integrator supports first-order "
                            f"time derivatives only, got '{atom.text(time)}'"
                        )
                coef = CompiledCoefficient(sep, time, params, S)
                if derivatives:
                    if len(monomial) != 1:
                        raise SolverError(
                            f"{problem.source}: equations[{r}]: '{format_monomial(monomial, time)}': der() may "
                            "only appear linearly (not multiplied by unknowns) for the reference integrator"
                        )
                    der[r].append((index[monomial[0].unknown], coef))
                else:  # an unknown's index, or the tree of a general atom (sin(th)), evaluated per call
                    rest[r].append((tuple(tree_of(a) if is_general(a) else index[a.unknown] for a in monomial), coef))
        self.der = der
        self.rest = rest
        self.index, self.time = index, time
        self.params = {name: np.broadcast_to(np.asarray(v, dtype=float), (S,)) for name, v in params.items()}
        self.static_mass = all(c.is_static for row in der for _, c in row)
        # fast path: every equation holds exactly one der(), each of a different unknown
        targets = [row[0][0] for row in der if len(row) == 1]
        self.permutation = np.array(targets) if len(targets) == q and len(set(targets)) == q else None
        self.last_y = None  # the state of the last right-hand-side call: who blew up when a call fails
        self.bad = np.zeros(S, dtype=bool)  # samples whose der() coefficients are singular
        self.bad_reason = ""
        if self.static_mass:
            self._mass = self._mass_at(0.0)
            self._check_static_mass(problem)

    # -- mass matrix --------------------------------------------------------------------------
    def _mass_at(self, t: float) -> np.ndarray:
        if self.permutation is not None:
            return np.stack([row[0][1].at(t) for row in self.der], axis=1)  # (S, q): diagonal after permuting
        A = np.zeros((self.S, self.q, self.q))
        for r, row in enumerate(self.der):
            for s, coef in row:
                A[:, r, s] += coef.at(t)
        return A

    def _check_static_mass(self, problem) -> None:
        A = self._mass
        if self.permutation is not None:
            bad = ~np.isfinite(A).all(axis=1) | (A == 0).any(axis=1)
            reason = "a coefficient of der() vanishes or is not finite at this point"
        else:
            with np.errstate(all="ignore"):
                finite = np.isfinite(A).all(axis=(1, 2))
                cond = np.full(self.S, np.inf)
                if finite.any():
                    cond[finite] = np.linalg.cond(A[finite])
            bad = ~finite | ~(cond < 1e14)
            reason = "the matrix of der() coefficients is singular at this point (not an ODE system there)"
        self.bad = bad
        self.bad_reason = reason

    # -- right-hand side ----------------------------------------------------------------------
    def __call__(self, t: float, y: np.ndarray) -> np.ndarray:
        count_evaluation(self, y)
        K = 1 if y.ndim == 1 else y.shape[1]
        U = y.reshape(self.S, self.q, K)
        G = np.zeros((self.S, self.q, K))
        for r, terms in enumerate(self.rest):
            acc = G[:, r, :]
            for idx, coef in terms:
                product = coef.at(t)[:, None]
                for s in idx:
                    product = product * (U[:, s, :] if isinstance(s, int) else self._general(s, t, U))
                acc += product
        A = self._mass if self.static_mass else self._mass_at(t)
        if self.permutation is not None:
            D = np.empty_like(G)
            D[:, self.permutation, :] = -G / A[:, :, None]
        else:
            D = np.linalg.solve(A, -G)
        return D.reshape(y.shape)

    def jacobian(self, t: float, y: np.ndarray) -> np.ndarray:
        """``d u' / d u`` at every sample, exact: shape (S, q, q) for a state ``y`` of shape (S q,).

        The product rule over every monomial's factors, a general atom's factor by its tree
        differentiated symbolically (:func:`pgdcli.problem.derivative.derivative`); then
        ``-A^-1 dg/du`` with ``A`` the der() coefficients. Not counted in the evaluation budget.
        """
        S, q = self.S, self.q
        U = np.asarray(y, dtype=float).reshape(S, q, 1)
        dG = np.zeros((S, q, q))
        for r, terms in enumerate(self.rest):
            for idx, coef in terms:
                factors = [U[:, s, 0] if isinstance(s, int) else self._at(s, t, U) for s in idx]
                for k, s in enumerate(idx):
                    others = coef.at(t)
                    for i, value in enumerate(factors):
                        others = others * value if i != k else others
                    if isinstance(s, int):
                        dG[:, r, s] += others
                        continue
                    for name, j in self.index.items():
                        slope = _slope(s, name)
                        if num_value(slope) != 0:
                            dG[:, r, j] += others * self._at(slope, t, U)
        A = self._mass if self.static_mass else self._mass_at(t)
        if self.permutation is None:
            return np.linalg.solve(A, -dG)
        J = np.empty_like(dG)
        J[:, self.permutation, :] = -dG / A[:, :, None]
        return J

    def _at(self, tree: tuple, t: float, U: np.ndarray) -> np.ndarray:
        """A tree of the state, the coordinates and time at every sample, shape (S,)."""
        return np.broadcast_to(self._general(tree, t, U), (self.S, 1))[:, 0]

    def _general(self, tree: tuple, t: float, U: np.ndarray) -> np.ndarray:
        """A general atom's tree at the samples (S, K): unknowns from the state, coordinates per sample."""
        values = {name: U[:, i, :] for name, i in self.index.items()}
        values.update({name: v[:, None] for name, v in self.params.items()})
        values[self.time] = t
        return general_tree_values(tree, values)

    def initial(self, problem, params: Mapping[str, np.ndarray]) -> np.ndarray:
        y0 = np.empty((self.S, self.q))
        for i, unknown in enumerate(problem.unknowns):
            y0[:, i] = np.broadcast_to(unknown.initial.evaluate(**params), (self.S,)) if params else \
                np.full(self.S, float(unknown.initial.evaluate()))
        return y0


def reference_jacobian(system: CompiledSystem, t: float, y: np.ndarray) -> np.ndarray:
    """The Jacobian (S, q, q) of the reference's right-hand side at states ``y`` (S, q): exact, or forward
    differences (one call of the vectorized right-hand side) where a function has no derivative rule."""
    try:
        return system.jacobian(t, y.reshape(-1))
    except ValueError:
        q = system.q
        typical = np.max(np.abs(y), axis=0)  # (q,): steps relative to the state, or to its typical size
        h = np.sqrt(np.finfo(float).eps) * np.maximum(np.abs(y), 1e-3 * np.where(typical > 0, typical, 1.0))
        columns = np.repeat(y[:, :, None], q + 1, axis=2)  # column 0: y, column 1 + j: u_j moved
        columns[:, np.arange(q), 1 + np.arange(q)] += h
        f = system(t, columns.reshape(system.S * q, q + 1)).reshape(system.S, q, q + 1)
        return (f[:, :, 1:] - f[:, :, :1]) / h[:, None, :]


@functools.lru_cache(maxsize=1024)
def _slope(tree: tuple, name: str) -> tuple:
    """``d tree / d name``, built once per tree and unknown."""
    return derivative(tree, ("name", name))

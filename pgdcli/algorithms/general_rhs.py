"""The general terms of the march's right-hand side, evaluated on the tensor-train state by cross.

An equation ``a(t, p) der(u) + sum_m c_m(t, p) m(u) + sum_g c_g(t, p) g(t, p, u) = 0``
keeps its polynomial monomials ``m`` on the march's exact path (Hadamard
products and rounding, :func:`pgdcli.algorithms.polynomial_rhs.evaluate_rhs`); the monomials that
hold a general atom (:mod:`pgdcli.problem.general`: ``sin(th)``, ``abs(v)*v``,
``sqrt(vx**2 + vy**2)*vx``) are gathered per unknown into one function

    G_s(t, p) = -sum_g c_g(t, p) g(t, p, u(t, p)) / a(t, p)

on the parameter grid, which :func:`pgdcli.tensors.cross.tt_cross` approximates in
tensor-train form from its values at the fibres it selects: each value needs
only the state's entries there (:func:`pgdcli.tensors.cross.tt_values_at`) and the
expression trees evaluated pointwise. The cross of one stage starts from the
index sets of the previous one (the function changes little between stages).

A cross that does not converge (a rank at the cap, no convergence in its
sweeps: a kink such as ``abs`` at 0) is counted and its first message kept for
the report; the march goes on with its train, and the error gate measures the
codebook. A function that is not finite at a grid point (``sqrt`` of a
negative value, ``1/0``: a trial step too long, or an equation undefined there)
gives a train of NaN, which the march's step control rejects.
"""

from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

from ..tensors.cross import tt_cross, tt_values_at
from ..problem.derivative import DERIVATIVE_FUNCTIONS, derivative
from ..problem.general import evaluate, is_general, render, tree_names, tree_of
from ..problem.trees import NON_SMOOTH, calls, evaluate_tree, values_by_name
from ..tensors.tt import TT

__all__ = ["CROSS_SHARE", "GeneralPart", "general_monomials", "report_entries", "switching_terms", "underflow_hint"]

#: Share of the stage rounding's RMS budget given to the cross.
CROSS_SHARE = 0.5
#: Grids of at most this many nodes are evaluated whole and compressed by TT-SVD instead of a cross
#: (benchmarks/general_rhs.py measures both) ...
DENSE_LIMIT = 4096
#: ... and so are grids of at most this many times the values of one cross sweep, (d - 1) r^2 n^2
#: with the rank r of the last cross: a cross takes 2-4 sweeps (benchmarks/general_rhs.py: on a
#: 3-parameter drag problem, 17^3 nodes, rank 10, the cross asked 2.5x the values of the whole
#: grid and the build took 2.2x as long; on a 4-parameter pendulum 2.2x too).
SWEEPS_PER_CROSS = 4


#: Evaluate the whole right-hand side of an unknown with general terms by cross (its polynomial
#: monomials too) instead of only the general monomials (benchmarks/general_rhs.py measures both).
WHOLE_RHS = False


def general_monomials(polynomial) -> list:
    """The monomials of an equation the cross evaluates: those holding a general atom (the rest keep
    the exact path), or with :data:`WHOLE_RHS` all but the time derivative when there is one."""
    general = [monomial for monomial in polynomial if any(is_general(atom) for atom in monomial)]
    if WHOLE_RHS and general:
        return [monomial for monomial in polynomial if all(atom.order == 0 for atom in monomial)]
    return general


class GeneralPart:
    """``G_s(t, p)`` of one unknown: its general monomials, evaluated by cross on the state.

    Parameters
    ----------
    monomials : sequence of (tuple of Atom, Separable)
        The general monomials of the equation and their coefficients (lhs - rhs form).
    der_term : SepTerm
        The coefficient ``a`` of ``der(u_s)``, a single product.
    unknowns : sequence of str
        The march's unknowns, in state order.
    params : sequence of str
        The tensor-train modes (non-time coordinates).
    nodes : mapping of str to ndarray
        The grid nodes of every mode.
    time : str
    """

    def __init__(self, monomials: Sequence, der_term, unknowns: Sequence[str], params: Sequence[str],
                 nodes: Mapping[str, np.ndarray], time: str):
        self.monomials = [(sep, [tree_of(a) if is_general(a) else ("name", a.unknown) for a in monomial])
                          for monomial, sep in monomials]
        self.der_term = der_term
        names = set().union(*(tree_names(tree) for _, trees in self.monomials for tree in trees))
        self.needed = [(name, i) for i, name in enumerate(unknowns) if name in names]
        self.params, self.nodes, self.time = list(params), nodes, time
        self.slopes = None  # per needed unknown, per monomial: its factors' derivative trees (Jacobians)
        self.right_sets = None  # warm start of the next cross
        self.rank = 4  # the rank of the last cross: its cost

    def values(self, t: float, state: Sequence[TT], indices: np.ndarray | None) -> np.ndarray:
        """``G_s(t, p)`` at grid multi-indices, shape (P, d) -> (P,); None: the whole grid, shape ``state[0].shape``."""
        if indices is None:  # the unknowns from the whole trains
            return self.grid_values(t, {name: state[i].full() for name, i in self.needed})
        return self.point_values(t, indices, {name: tt_values_at(state[i], indices) for name, i in self.needed})

    def point_values(self, t: float, indices: np.ndarray, arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """``G_s(t, p)`` at P grid multi-indices (P, d) from the needed unknowns' values there (name -> (P,))."""
        return self._evaluate(t, self._point_inputs(indices, arrays), indices.shape[0])

    def grid_values(self, t: float, arrays: Mapping[str, np.ndarray]) -> np.ndarray:
        """``G_s(t, p)`` on the whole grid from the needed unknowns' arrays (name -> grid shape)."""
        return self._evaluate(t, self._grid_inputs(arrays), self._grid_shape())

    def point_jacobian(self, t: float, indices: np.ndarray, arrays: Mapping[str, np.ndarray]) -> dict:
        """``{j: dG_s/du_j}`` at P grid multi-indices (as :meth:`point_values`), j the needed unknowns' indices."""
        return self._jacobian(t, self._point_inputs(indices, arrays), indices.shape[0])

    def grid_jacobian(self, t: float, arrays: Mapping[str, np.ndarray]) -> dict:
        """``{j: dG_s/du_j}`` on the whole grid (as :meth:`grid_values`), j the needed unknowns' indices."""
        return self._jacobian(t, self._grid_inputs(arrays), self._grid_shape())

    def _grid_shape(self) -> tuple:
        return tuple(self.nodes[p].size for p in self.params)

    def _point_inputs(self, indices: np.ndarray, arrays: Mapping[str, np.ndarray]) -> dict:
        values = {p: self.nodes[p][indices[:, k]] for k, p in enumerate(self.params)}
        values.update(arrays)
        return values

    def _grid_inputs(self, arrays: Mapping[str, np.ndarray]) -> dict:
        d = len(self.params)
        values = {p: self.nodes[p].reshape([-1 if j == k else 1 for j in range(d)]) for k, p in enumerate(self.params)}
        values.update(arrays)
        return values

    def _jacobian(self, t: float, values: dict, shape) -> dict:
        """The product rule over every monomial's factors, with their derivative trees (built once)."""
        if self.slopes is None:
            self.slopes = {name: [[derivative(tree, ("name", name)) for tree in trees] for _, trees in self.monomials]
                           for name, _ in self.needed}
        values[self.time] = t
        leaf = values_by_name(values)
        out = {}
        with np.errstate(all="ignore"):
            factors = [[evaluate(tree, values) for tree in trees] for _, trees in self.monomials]
            scale = -1.0 / self.der_term.evaluate(**values)
            for name, j in self.needed:
                total = np.zeros(shape)
                for (sep, _), own, slopes in zip(self.monomials, factors, self.slopes[name]):
                    for k, slope in enumerate(slopes):
                        if slope != ("num", 0.0):
                            term = sep.evaluate(**values) * evaluate_tree(slope, leaf, DERIVATIVE_FUNCTIONS)
                            for other in own[:k] + own[k + 1:]:
                                term = term * other
                            total = total + term
                out[j] = total * scale
        return out

    def _evaluate(self, t: float, values: dict, shape) -> np.ndarray:
        """``G_s`` from every leaf's values (parameters, unknowns; the time set here)."""
        values[self.time] = t
        total = np.zeros(shape)
        with np.errstate(all="ignore"):
            for sep, trees in self.monomials:
                term = sep.evaluate(**values)
                for tree in trees:
                    term = term * evaluate(tree, values)
                total = total + term
            return -total / self.der_term.evaluate(**values)

    def at(self, t: float, state: Sequence[TT], tolerance: float, max_rank: int, stats: dict | None) -> TT:
        """The tensor train of ``G_s`` at time t, to a root-mean-square ``tolerance`` over the grid.

        Parameters
        ----------
        t : float
        state : list of TT
            The stage value of every unknown.
        tolerance : float
            RMS accuracy asked of the cross.
        max_rank : int
        stats : dict, optional
            Counters updated in place: ``cross``, ``cross_failed``, ``cross_evaluations``,
            ``cross_rank`` (largest), ``cross_message`` (the first failure).
        """
        shape = state[0].shape
        sweep = (len(shape) - 1) * self.rank ** 2 * max(shape) ** 2
        result = tt_cross(lambda idx: self.values(t, state, idx), shape, tolerance, max_rank=max_rank,
                          right_sets=self.right_sets, rng=np.random.default_rng(11),
                          dense_limit=max(DENSE_LIMIT, SWEEPS_PER_CROSS * sweep),
                          full=lambda: self.values(t, state, None))
        self.rank = max(result.train.ranks, default=1)
        if stats is not None:
            stats["cross"] = stats.get("cross", 0) + 1
            stats["cross_evaluations"] = stats.get("cross_evaluations", 0) + result.evaluations
            stats["cross_rank"] = max(stats.get("cross_rank", 0), max(result.train.ranks, default=1))
            if not result.converged:
                stats["cross_failed"] = stats.get("cross_failed", 0) + 1
                stats.setdefault("cross_message", f"at t = {t:.6g}: {result.message}")
        if not np.isfinite(result.change) and result.message.endswith("not finite at some grid points"):
            if stats is not None:
                stats["cross_nonfinite"] = stats.get("cross_nonfinite", 0) + 1
            return TT([np.full((1, n, 1), np.nan) for n in shape])
        if result.right_sets:
            self.right_sets = result.right_sets
        return result.train


def underflow_hint(parts: Sequence, stats: dict) -> str:
    """Why the march's steps may have shrunk to nothing, from its general terms ('' if none applies)."""
    parts = [part for part in parts or () if part is not None]
    if not parts:
        return ""
    if stats.get("cross_nonfinite"):
        return ("; or a function of the unknowns is undefined there: its values were not finite "
                f"{stats['cross_nonfinite']} times, e.g. sqrt or log of a negative number, or a division by zero")
    kinks = switching_terms(parts)
    if kinks:
        return (f"; or not smooth: {', '.join(kinks)} has a kink or a jump where an argument crosses a switch point, "
                "and every node of the parameter grid marches with the same steps")
    return ""


def switching_terms(parts: Sequence) -> list[str]:
    """The general terms (as text) that call a switching function of the unknowns (``max(-y, 0)``)."""
    return sorted({render(tree) for part in parts or () if part is not None for _, trees in part.monomials
                   for tree in trees if calls(tree, NON_SMOOTH)})


def report_entries(stats: dict) -> dict:
    """The march report's entries about the crosses (empty without general terms)."""
    if not stats.get("cross"):
        return {}
    return {
        "cross_evaluations": int(stats.get("cross_evaluations", 0)),
        "crosses": int(stats["cross"]),
        "crosses_not_converged": int(stats.get("cross_failed", 0)),
        "cross_max_rank": int(stats.get("cross_rank", 0)),
        "cross_failure": str(stats.get("cross_message", "")),
    }

"""Non-separable coefficients of the parsed equations, separated on the solvers' nodes.

The glue between :class:`pgdcli.problem.expressions.Joint` (a function of two or more coordinates
kept as an expression tree) and the numerics of :mod:`pgdcli.discretization.separate`:

* :func:`nodal_terms`: a coefficient as ``[(coef, {coordinate: values at its nodes})]`` for the
  enrichment solver, the joints separated (TT expanded into canonical terms, in the coordinate
  order with the fewest terms);
* :class:`JointTrain`: a joint as a tensor train over the march's parameter nodes, at each time;
* :func:`separation_report_text`: what the report and ``pgd info`` say about each.

The bound is absolute at the nodes: :data:`SEPARATION_FRACTION` of the solver's tolerance.
"""

from __future__ import annotations

import itertools
from typing import Mapping, Sequence

import numpy as np

from ..errors import SolverError
from .separate import (DENSE_LIMIT, MAX_SEPARATION_RANK, Separation, SeparationRankError, cp_from_tt,
                       separate_function)

__all__ = ["CanonicalTermsError", "MAX_CANONICAL_TERMS", "SEPARATION_FRACTION", "JointTrain", "separate_joint", "nodal_terms",
           "separation_report_text"]

#: Most Kronecker terms one coefficient may add to the linear solver's operator (the product of
#: its tensor-train ranks): each term costs a matrix product per mode in every sweep.
MAX_CANONICAL_TERMS = 400
#: The coefficient's entries are separated to this fraction of the solver's tolerance (absolute):
#: its error reaches the solution multiplied by about the time span times |u|, and a smooth
#: coefficient's singular values fall exponentially, so a tenfold tighter bound costs 1-2 terms.
SEPARATION_FRACTION = 1e-2


class CanonicalTermsError(SolverError):
    """A coefficient whose canonical expansion has more Kronecker terms than the solver takes."""


def _one_coordinate_values(func, nodes: np.ndarray, name: str) -> np.ndarray:
    with np.errstate(all="ignore"):
        v = np.broadcast_to(np.asarray(func(nodes), dtype=float), nodes.shape)
    if not np.all(np.isfinite(v)):
        raise SolverError(f"coefficient {func} is not finite at some nodes of coordinate {name!r}")
    return np.array(v)


def separate_joint(joint, nodes: Mapping[str, np.ndarray], tolerance: float, *, where: str = "",
                   max_rank: int = MAX_SEPARATION_RANK, fewest_terms: bool = False) -> tuple[Separation, list[str]]:
    """The joint function of a :class:`~pgdcli.problem.expressions.Joint` separated on the nodes of its coordinates.

    The bound on the joint function is ``tolerance`` divided by the largest value of the
    joint's separable factor, so the whole part is within ``tolerance`` at the nodes.
    With ``fewest_terms``, three or four coordinates are tried in every order (up to
    reversal, which gives the same ranks) and the train with the fewest canonical terms kept:
    ``exp(-a*t)*sin(w*t)`` ordered (a, t, w) has ranks (8, 12), ordered (t, a, w) (19, 12).

    Returns
    -------
    (Separation, list of str)
        The train and the coordinates of its modes (in the order of ``nodes``, or the best order).

    Raises
    ------
    SolverError
        One line naming the coefficient: not finite at some node, or not separable within ``max_rank``.
    """
    names = [c for c in nodes if c in joint.tree_coordinates]
    scale = abs(joint.term.coef)
    for name, func in joint.term.factors:
        if name in nodes:
            scale *= float(np.max(np.abs(_one_coordinate_values(func, nodes[name], name))))
    delta = tolerance / max(scale, 1e-300)
    text = joint.function_text()
    orders = [names]
    if fewest_terms and len(names) in (3, 4) and int(np.prod([nodes[c].size for c in names])) <= DENSE_LIMIT:
        orders = [list(p) for p in itertools.permutations(names) if p <= p[::-1]]
    try:
        separation, names = _fewest_terms(joint, nodes, orders, delta, max_rank)
    except FloatingPointError:
        raise SolverError(f"{where}the coefficient '{text}' is not finite at some nodes of "
                          f"{', '.join(names)}") from None
    except SeparationRankError as exc:
        raise SolverError(f"{where}the coefficient '{text}' does not separate on the nodes of {', '.join(names)}: "
                          f"rank {exc.rank} reached (the cap: solver.max_rank, at most {MAX_SEPARATION_RANK}) with "
                          f"error {exc.error * scale:.2g}, asked {tolerance:.2g}; narrow the domains of "
                          f"{', '.join(names)}") from None
    # the bound is on the whole part, the measured error is on the joint function alone
    separation.error *= scale
    return separation, names


def _fewest_terms(joint, nodes: Mapping[str, np.ndarray], orders: Sequence[list], delta: float,
                  max_rank: int) -> tuple[Separation, list[str]]:
    """The separation with the fewest canonical terms over ``orders`` of the joint's coordinates.

    An order whose ranks exceed the cap does not stop the search: ``exp(-((x - a)**2 + (y - b)**2)/w)``
    ordered (x, y, a, b) needs the square of the rank it needs ordered (x, a, y, b).

    Raises
    ------
    SeparationRankError
        When every order does: the one that got closest (the smallest error left).
    FloatingPointError
    """
    best, refused = None, None
    for order in orders:
        try:
            separation = separate_function(joint.evaluate_tree, {c: nodes[c] for c in order}, delta, max_rank)
        except SeparationRankError as exc:
            refused = exc if refused is None or exc.error < refused.error else refused
            continue
        if best is None or separation.terms < best[0].terms:
            best = (separation, order)
    if best is None:
        raise refused
    return best


def nodal_terms(sep, nodes: Mapping[str, np.ndarray], tolerance: float, *, where: str = "",
                reports: list | None = None, max_rank: int = MAX_SEPARATION_RANK,
                max_terms: int = MAX_CANONICAL_TERMS) -> list[tuple[float, dict[str, np.ndarray]]]:
    """A coefficient as ``[(coef, {coordinate: values at its nodes})]``, joints separated to ``tolerance``.

    Parameters
    ----------
    sep : pgdcli.problem.expressions.Separable
    nodes : mapping of str to ndarray
        Every coordinate's nodes (absent factors are ones).
    tolerance : float
        Max abs error of each non-separable part at the nodes.
    where : str
        Message prefix, e.g. ``"x.yaml: equations[1]: "``.
    reports : list, optional
        Receives one dict per joint: ``{"coefficient", "coordinates", "terms", "ranks", "error", "method"}``.
    max_rank : int
        Cap on every rank of a separation.
    max_terms : int
        Cap on the Kronecker terms of one joint's canonical expansion (the enrichment's
        :data:`MAX_CANONICAL_TERMS`; the tensor-train solver compresses them again).

    Raises
    ------
    SolverError
        A joint not finite at a node, or not separable within ``max_rank``;
        :class:`CanonicalTermsError` when its canonical expansion would exceed ``max_terms``.
    """
    out = []
    for term in sep.terms:
        values = {name: np.ones(x.size) for name, x in nodes.items()}
        for name, func in term.factors:
            values[name] = _one_coordinate_values(func, nodes[name], name)
        out.append((term.coef, values))
    for joint in sep.joints:
        separation, names = separate_joint(joint, nodes, tolerance, where=where, max_rank=max_rank, fewest_terms=True)
        if separation.terms > max_terms:
            raise CanonicalTermsError(
                f"{where}the coefficient '{joint.function_text()}' separates on the nodes of {', '.join(names)} "
                f"with tensor-train ranks {separation.ranks}, {separation.terms} Kronecker terms for the "
                f"enrichment (at most {max_terms}); solver.method: amen (the tensor-train solver) takes it")
        base = {name: np.ones(x.size) for name, x in nodes.items()}
        for name, func in joint.term.factors:
            base[name] = _one_coordinate_values(func, nodes[name], name)
        for vectors in cp_from_tt(separation.cores):
            values = dict(base)
            for name, v in zip(names, vectors):
                values[name] = v
            out.append((joint.term.coef, values))
        if reports is not None:
            reports.append({"coefficient": joint.function_text(), "coordinates": names, "terms": separation.terms,
                            "ranks": separation.ranks, "error": separation.error, "method": separation.method})
    return out


def separation_report_text(reports: Sequence[Mapping]) -> str:
    """One line per separated coefficient for the report: ``sin(t*w) [w, t]: 14 terms (svd), error 2.1e-10``."""
    lines = []
    seen = set()
    for r in reports:
        key = (r["coefficient"], tuple(r["coordinates"]))
        if key in seen:
            continue
        seen.add(key)
        terms = f"{r['terms']} term" + ("s" if r["terms"] != 1 else "")
        how = r["method"] + (f", ranks {tuple(r['ranks'])}" if r["ranks"] else "")
        lines.append(f"{r['coefficient']} [{', '.join(r['coordinates'])}]: {terms} ({how}), error {r['error']:.2g}")
    return "; ".join(lines)


def _embedded(cores: Sequence[np.ndarray], names: Sequence[str], params: Sequence[str],
              sizes: Mapping[str, int]) -> list[np.ndarray]:
    """A train over ``names`` (a subsequence of ``params``) as a train over all ``params``, constant in the others."""
    by_name = dict(zip(names, cores))
    out, rank = [], 1
    for p in params:
        if p in by_name:
            out.append(by_name[p])
            rank = by_name[p].shape[2]
        else:  # the bond passes through: identity in the rank, ones along the mode
            out.append(np.eye(rank)[:, None, :] * np.ones(sizes[p])[None, :, None])
    return out


class JointTrain:
    """The joint function of a :class:`~pgdcli.problem.expressions.Joint` as a tensor train over the parameter nodes.

    For the march, whose time is a number at each stage: a function of parameters only is
    separated once; one of the time and one parameter is a vector at each time (exact); one of
    the time and several parameters is separated again at each time it is asked for.

    Parameters
    ----------
    joint : pgdcli.problem.expressions.Joint
    time : str
        The time coordinate's name.
    params : sequence of str
        The train's modes.
    nodes : mapping of str to ndarray
        Each parameter's nodes.
    tolerance : float
        Max abs error of the joint function at the nodes.
    where : str
        Message prefix.
    reports : list, optional
        Receives one dict as :func:`nodal_terms` (the first separation's ranks for a timed one).
    """

    def __init__(self, joint, time: str, params: Sequence[str], nodes: Mapping[str, np.ndarray], tolerance: float,
                 *, where: str = "", reports: list | None = None, max_rank: int = MAX_SEPARATION_RANK):
        self.joint, self.time, self.params, self.tolerance, self.where = joint, time, list(params), tolerance, where
        self.max_rank = max_rank
        self.nodes = {p: nodes[p] for p in params}
        self.names = [p for p in params if p in joint.tree_coordinates]
        self.timed = time in joint.tree_coordinates
        self.sizes = {p: self.nodes[p].size for p in params}
        self.fixed = None
        # what the report says: the largest ranks and error over every separation made (updated in place)
        self.report = {"coefficient": joint.function_text(), "coordinates": self.names + ([time] if self.timed else []),
                       "terms": 0, "ranks": (), "error": 0.0, "method": ""}
        if reports is not None:
            reports.append(self.report)
        if not self.timed:
            self.fixed = self._separate(None)

    def _separate(self, t: float | None) -> list[np.ndarray]:
        joint = _bare(self.joint if t is None else self.joint.with_value(self.time, float(t)))
        sub = {p: self.nodes[p] for p in self.names}
        if len(self.names) == 1:
            with np.errstate(all="ignore"):
                v = np.broadcast_to(joint.evaluate_tree(sub), (self.sizes[self.names[0]],)).astype(float)
            if not np.all(np.isfinite(v)):
                at = "" if t is None else f" at {self.time} = {t:g}"
                raise SolverError(f"{self.where}the coefficient '{self.joint.function_text()}' is not finite at "
                                  f"some nodes of {self.names[0]}{at}")
            self.last = Separation([v.reshape(1, -1, 1)], 0.0, "exact")
        else:
            self.last, _ = separate_joint(joint, sub, self.tolerance, where=self.where, max_rank=self.max_rank)
        r = self.report
        r["terms"] = max(r["terms"], self.last.terms)
        r["ranks"] = tuple(max(a, b) for a, b in itertools.zip_longest(r["ranks"], self.last.ranks, fillvalue=0))
        r["error"] = max(r["error"], self.last.error)
        r["method"] = self.last.method + (" at each time" if self.timed else "")
        return _embedded(self.last.cores, self.names, self.params, self.sizes)

    def at(self, t: float) -> list[np.ndarray]:
        """Cores (r_{k-1}, n_k, r_k) over the parameters of the joint function at time ``t``."""
        return self.fixed if self.fixed is not None else self._separate(t)


def _bare(joint):
    """The joint function without its separable factor (coefficient 1)."""
    return type(joint)(type(joint.term)(1.0), joint.tree)

"""The compiled right-hand side of the separated time march: ``du_s/dt = f_s(t, p, u)``.

:func:`compile_system` brings every equation polynomial in the unknowns to
``der(u_s) = sum_m c_sm(t, p) prod(u in monomial m)`` over the grid of the non-time
coordinates ``p``; the coefficients ``c_sm`` are separable (sums of products of
one-coordinate functions) or separated non-separable parts (:class:`JointTrain`).
:func:`evaluate_rhs` evaluates it on a tensor-train state: products of unknowns are
Hadamard pairs summed and rounded by :func:`round_terms` without forming rank-r^2
products (exact rounding below ``EXACT_RANK_LIMIT``, the randomized sum-of-products
rounding above).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..discretization.basis import Basis1D
from ..discretization.coefficients import SEPARATION_FRACTION, JointTrain
from ..discretization.coordinates import coordinate_infos
from ..discretization.separate import MAX_SEPARATION_RANK
from ..errors import SolverError
from ..problem.expressions import Separable, SepTerm, merge_to_function
from ..problem.switches import time_switches
from ..tensors.tt import TT, is_ones, tt_hadamard, tt_ones, tt_rank_one, tt_round, tt_round_many, tt_sum
from ..tensors.cross_products import ProductCross, round_products_by_cross
from ..tensors.tt_sketch import tt_round_sum_of_products
from .general_rhs import CROSS_SHARE, GeneralPart, general_monomials

__all__ = ["NonlinearSystem", "SINGLE_POINT", "EXACT_RANK_LIMIT", "compile_system", "evaluate_rhs", "round_terms"]


# Above this implicit rank (sum over terms of the product ranks) a rounding goes
# through the randomized sketch instead of forming the sum explicitly.
EXACT_RANK_LIMIT = 160
# How the right-hand side's products are rounded above that rank: "sketch" (randomized rounding,
# tensors.tt_sketch, ~n r^4 per core) or "cross" (one-site cross on the state, tensors.cross_products,
# ~n r^3 per core and sweep); benchmarks/build_speed.py --issue15 measures both.
PRODUCTS = "cross"


SINGLE_POINT = "<single point>"


class _SinglePoint:
    """The 'grid' of a problem without non-time coordinates: one node."""

    nodes = np.zeros(1)



@dataclass
class _Coefficient:
    """``sum_tau w_tau f_tau(t) * v_tau(p)``: a separable coefficient of one monomial."""

    weights: np.ndarray  # (T,)
    time_funcs: list  # Func1D or None, length T
    param_vectors: list  # per term, list of node vectors per parameter
    joints: list = field(default_factory=list)  # non-separable parts (_JointPart)

    def at(self, t: float) -> TT:
        w = self.weights.copy()
        for i, f in enumerate(self.time_funcs):
            if f is not None:
                w[i] *= float(f(np.array([t]))[0])
        parts = [tt_rank_one(v) for v in self.param_vectors] + [j.at(t) for j in self.joints]
        w = list(w) + [1.0] * len(self.joints)
        if len(parts) == 1:
            return parts[0].scaled(w[0])
        return tt_sum(parts, w)


@dataclass
class _JointPart:
    """``weight * f(t) * prod_p v_p(p) * g(t, p)``: a non-separable part, g separated at each t if timed."""

    weight: float
    time_func: object  # callable or None
    vectors: list  # per parameter, node vector
    train: JointTrain

    def at(self, t: float) -> TT:
        w = self.weight * (1.0 if self.time_func is None else float(self.time_func(np.array([t]))[0]))
        cores = [c * v[None, :, None] for c, v in zip(self.train.at(t), self.vectors)]
        cores[0] = cores[0] * w
        return TT(cores)



@dataclass
class NonlinearSystem:
    """``du_s/dt = sum_m c_sm(t, p) prod(u in monomial m)`` over the parameter grid.

    Attributes
    ----------
    unknowns : list of str
    params : list of str
        Non-time coordinates, spec order: the tensor-train modes.
    bases : dict
        Coordinate name -> basis.
    time_basis : Basis1D
    rhs : list of list of (Coefficient, tuple of int)
        Per unknown, its monomials: coefficient and the unknown indices multiplied.
    initial : list of TT
    general : list of GeneralPart or None
        Per unknown, the terms with functions of the unknowns (:mod:`pgdcli.algorithms.general_rhs`).
    """

    unknowns: list[str]
    params: list[str]
    bases: dict[str, Basis1D]
    time_basis: Basis1D
    rhs: list[list[tuple[_Coefficient, tuple[int, ...]]]]
    initial: list[TT]
    general: list = field(default_factory=list)  # per unknown: GeneralPart of its general terms, or None
    # the switch arguments of time and parameters, and the time's name (the march lands on their switches)
    switches: list = field(default_factory=list)
    time: str = "t"
    # per unknown: the warm-started cross of its products (PRODUCTS == "cross")
    product_crosses: dict = field(default_factory=dict)

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(self.bases[p].nodes.size for p in self.params)


def _param_vectors(term, params, bases, divide=None) -> list[np.ndarray]:
    vecs = []
    factors = dict(term.factors)
    dfactors = dict(divide.factors) if divide is not None else {}
    for p in params:
        nodes = bases[p].nodes
        v = np.ones(nodes.size)
        if p in factors:
            v = v * np.broadcast_to(np.asarray(factors[p](nodes), dtype=float), nodes.shape)
        if p in dfactors:
            v = v / np.broadcast_to(np.asarray(dfactors[p](nodes), dtype=float), nodes.shape)
        if not np.all(np.isfinite(v)):
            raise SolverError(f"a coefficient is not finite at some nodes of coordinate {p!r}")
        vecs.append(v)
    return vecs




def compile_system(problem, tolerance: float | None = None, separations: list | None = None) -> NonlinearSystem:
    """Bring every equation to ``der(u_s) = f_s(t, p, u)`` over the parameter grid.

    Each equation must contain the derivative of exactly one unknown, with a
    coefficient that is a single product of one-coordinate functions (it is
    divided out); together the equations must cover every unknown once.
    Non-separable coefficients are separated over the parameter nodes to
    ``SEPARATION_FRACTION * tolerance`` (:class:`pgdcli.discretization.coefficients.JointTrain`); each
    separation is described in ``separations``.
    """
    delta = SEPARATION_FRACTION * (problem.solver.tolerance if tolerance is None else tolerance)
    cap = min(MAX_SEPARATION_RANK, problem.solver.max_rank)
    tname = problem.time
    unknowns = [u.name for u in problem.unknowns]
    index = {u: i for i, u in enumerate(unknowns)}
    params = [c.name for c in problem.coordinates if c.name != tname]
    bases = {info.name: info.basis() for info in coordinate_infos(problem, march=True)}
    if not params:  # one trajectory: march a train over a single virtual point
        params = [SINGLE_POINT]
        bases[SINGLE_POINT] = _SinglePoint()
    rhs: list = [None] * len(unknowns)
    general: list = [None] * len(unknowns)
    where = problem.source
    for eq in problem.equations:
        der_monomial, atom, dsep = _time_derivative(eq, tname, where)
        s = index[atom.unknown]
        if rhs[s] is not None:
            raise SolverError(f"{where}: der({atom.unknown}) appears in two equations; write one equation per unknown")
        dterm = dsep.terms[0]
        dtime = dict(dterm.factors).get(tname)
        monomials = []
        crossed = general_monomials(eq.polynomial)
        if crossed:
            general[s] = GeneralPart([(m, eq.polynomial[m]) for m in crossed], dterm, unknowns, params,
                                     {p: bases[p].nodes for p in params}, tname)
        for mono, sep in eq.polynomial.items():
            if mono == der_monomial or mono in crossed:
                continue
            weights, tfuncs, pvecs = [], [], []
            for term in sep.terms:
                weights.append(-term.coef / dterm.coef)
                tf = dict(term.factors).get(tname)
                tfuncs.append(_time_ratio(tf, dtime))
                pvecs.append(_param_vectors(term, params, bases, dterm))
            joints = []
            for joint in sep.joints:
                train = JointTrain(joint, tname, params, {p: bases[p].nodes for p in params}, delta,
                                   where=f"{where}: equations[{eq.index}]: ", reports=separations, max_rank=cap)
                joints.append(_JointPart(-joint.term.coef / dterm.coef,
                                         _time_ratio(dict(joint.term.factors).get(tname), dtime),
                                         _param_vectors(joint.term, params, bases, dterm), train))
            monomials.append((_Coefficient(np.array(weights), tfuncs, pvecs, joints),
                              tuple(index[a.unknown] for a in mono)))
        rhs[s] = monomials
    initial = [_initial_train(u, problem, params, bases, delta, cap, separations) for u in problem.unknowns]
    return NonlinearSystem(unknowns, params, bases, bases[tname], rhs, initial, general,
                           switches=time_switches(problem.equations, tname, unknowns), time=tname)


def _initial_train(u, problem, params: list, bases: dict, delta: float, cap: int, separations) -> TT:
    """The initial value of unknown ``u`` over the parameter grid, as a train (joint terms separated)."""
    terms = [tt_rank_one(_param_vectors(term, params, bases), term.coef) for term in u.initial.terms]
    for joint in u.initial.joints:
        train = JointTrain(joint, problem.time, params, {p: bases[p].nodes for p in params}, delta,
                           where=f"{problem.source}: unknowns.{u.name}.initial: ", reports=separations,
                           max_rank=cap)
        terms.append(_JointPart(joint.term.coef, None, _param_vectors(joint.term, params, bases), train).at(0.0))
    if not terms:
        terms = [tt_rank_one([np.zeros(bases[p].nodes.size) for p in params])]
    return tt_round(tt_sum(terms), 1e-15)


def _time_derivative(eq, tname: str, where: str):
    """``(monomial, atom, coefficient)`` of the one ``der(u, t)`` term of an equation; SolverError otherwise."""
    ders = [(m, sep) for m, sep in eq.polynomial.items() if any(a.order > 0 for a in m)]
    if len(ders) != 1 or len(ders[0][0]) != 1:
        raise SolverError(f"{where}: equations[{eq.index}]: the nonlinear solver needs exactly one der(...) "
                          f"term per equation, got {len(ders)} in '{eq.text}'")
    (atom,), dsep = ders[0]
    if atom.coordinate != tname or atom.order != 1:
        raise SolverError(f"{where}: equations[{eq.index}]: only first time derivatives are supported")
    if len(dsep.terms) != 1:
        merged = merge_to_function(dsep)
        if merged is not None:  # e.g. (a + 1)*der(u): one function of one coordinate
            dsep = Separable((SepTerm(1.0, ((merged.coordinate, merged),) if merged.coordinate else ()),))
    if len(dsep.terms) != 1 or dsep.joints:
        raise SolverError(f"{where}: equations[{eq.index}]: the coefficient of der({atom.unknown}) must be a "
                          f"single product of one-coordinate functions, got '{dsep}'")
    return ders[0][0], atom, dsep


class _Ratio:
    """t -> f(t) / g(t) for optional one-coordinate functions (None = 1)."""

    def __init__(self, f, g):
        self.f, self.g = f, g

    def __call__(self, t):
        num = np.ones_like(t) if self.f is None else self.f(t)
        den = np.ones_like(t) if self.g is None else self.g(t)
        return num / den


def _time_ratio(f, g):
    return None if f is None and g is None else _Ratio(f, g)




def evaluate_rhs(system: NonlinearSystem, t: float, state: list[TT], delta: float, max_rank: int,
                 rng: np.random.Generator | None = None, stats: dict | None = None) -> list[TT]:
    """``f_s(t, p, u)`` for every unknown, each rounded to absolute Frobenius error ``delta``.

    Every monomial becomes one Hadamard pair ``(coefficient * u_a, u_b)`` that
    :func:`round_terms` sums without forming products of large rank.
    """
    ones = tt_ones(system.shape)
    per_unknown = []
    for s, monomials in enumerate(system.rhs):
        terms = []
        for coef, unknowns in monomials:
            a = coef.at(t)
            factors = list(unknowns)
            if factors:
                a = tt_hadamard(a, state[factors.pop(0)])
            while len(factors) > 1:  # degree >= 3: fold all but the last factor exactly
                a = tt_round(tt_hadamard(a, state[factors.pop(0)]), absolute=delta / 4, max_rank=max_rank)
            terms.append((1.0, a, state[factors[0]] if factors else ones))
        part = system.general[s] if system.general else None
        if part is not None:  # functions of the unknowns: by cross, to a share of the rounding's RMS budget
            rms = CROSS_SHARE * delta / np.sqrt(float(np.prod(system.shape)))
            terms.append((1.0, part.at(t, state, rms, max_rank, stats), ones))
        if not terms:
            terms.append((1.0, state[0].scaled(0.0), ones))
        per_unknown.append(terms)
    hints = [max(u.ranks, default=1) for u in state]
    # once the step control has found the stage roundings' noise setting the error estimate (a stiff
    # Jacobian amplifies it), the products go back to the deterministic rounding: the cross's error is
    # only sampled, and on the SIR user problem its noise ended the march in a step-size underflow
    crossing = PRODUCTS == "cross" and not (stats or {}).get("stage_tightenings")
    if crossing and not all(implicit_rank(terms) <= EXACT_RANK_LIMIT for terms in per_unknown):
        return [products_by_cross(system, s, terms, delta, hint, max_rank, rng, stats)
                for s, (terms, hint) in enumerate(zip(per_unknown, hints))]
    return round_terms(per_unknown, delta, hints, max_rank, rng, stats)


def products_by_cross(system: NonlinearSystem, slot: int, terms: list, delta: float, hint: int, max_rank: int,
                      rng: np.random.Generator | None, stats: dict | None) -> TT:
    """``sum w A * B`` of one unknown by the warm-started one-site cross of the products
    (:mod:`pgdcli.tensors.cross_products`), O(n r^3) per core; the randomized rounding when the
    cross does not meet its sampled tolerance (counted: ``product_cross_fallbacks``)."""
    stats = {} if stats is None else stats
    cross = system.product_crosses.get(slot)
    if cross is None:
        cross = system.product_crosses[slot] = ProductCross(system.shape, np.random.default_rng(1000 + slot))
    train, info = round_products_by_cross(cross, terms, absolute=delta, max_rank=max_rank, rank_hint=hint + 4)
    stats["product_crosses"] = stats.get("product_crosses", 0) + 1
    stats["product_cross_sweeps"] = stats.get("product_cross_sweeps", 0) + info.sweeps
    if train is not None:
        return train
    stats["product_cross_fallbacks"] = stats.get("product_cross_fallbacks", 0) + 1
    return tt_round_sum_of_products(terms, absolute=delta, rank_hint=hint + 4, rng=rng, max_rank=max_rank,
                                    stats=stats)


def implicit_rank(terms: list) -> int:
    """The largest bond of ``sum w A * B`` formed explicitly: the sum over terms of the rank products."""
    d = terms[0][1].order
    if d == 1:
        return 1
    return sum(max(a.cores[k].shape[2] * b.cores[k].shape[2] for k in range(d - 1)) for _, a, b in terms)


def round_terms(per_unknown: list[list[tuple[float, TT, TT]]], delta: float, hints: list[int], max_rank: int,
                rng: np.random.Generator | None, stats: dict | None = None) -> list[TT]:
    """Sum and round ``sum_m w_m A_m * B_m`` for every unknown (absolute Frobenius bound ``delta``).

    Small implicit ranks: explicit sums rounded together (batched QR/SVD across
    unknowns, the fast path for small problems). Large ones: each unknown by
    the randomized sum-of-products rounding, sized from the unknown's current
    rank, which never forms a product of rank r^2.
    """
    if all(implicit_rank(terms) <= EXACT_RANK_LIMIT for terms in per_unknown):
        sums = []
        for terms in per_unknown:
            parts = [a if is_ones(b) else tt_hadamard(a, b) for _, a, b in terms]
            sums.append(tt_sum(parts, [w for w, _, _ in terms]))
        if stats is not None:
            stats["exact"] = stats.get("exact", 0) + len(sums)
        return tt_round_many(sums, absolute=delta, max_rank=max_rank)
    return [tt_round_sum_of_products(terms, absolute=delta, rank_hint=hint + 4, rng=rng, max_rank=max_rank,
                                     stats=stats)
            for terms, hint in zip(per_unknown, hints)]

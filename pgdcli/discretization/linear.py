"""Discretization of a linear problem for the PGD enrichment: separated operator, source and lifts.

The problem ``sum_s A_rs(x) du_s/dt + B_rs(x) u_s = f_r(x)`` with ``u_s(t0) = u0_s``
is lifted (``u = u0 + v``, ``v(t0) = 0``) and discretized coordinate by
coordinate (:mod:`pgdcli.discretization.basis`), which turns it into one tensor equation
``A v = F`` over the modes ``(field, x_1, ..., x_d)``. The *field* mode, of size
the number of unknowns, carries the coupling between equations, so coupled
linear systems are solved as one separated problem.

Before the enrichment the time rows are multiplied by the inverse of the
discrete ``d/dt`` (an integration matrix) and every mode by the square roots of
its quadrature weights: the residual minimized is then the L2 norm of the
*integrated* equation (u - u0 - int rhs), which is well conditioned and close
to the error itself, so the tolerance means what it says.

The one-dimensional operators (per coordinate, in time) are :mod:`pgdcli.discretization.operators_1d`;
:func:`discretize` reads as its steps (time and lifts, one term, the tensors).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SolverError
from ..problem.compatibility import check_initial_meets_boundary
from ..tensors.cp import CPTensor, SeparatedOperator
from .basis import Basis1D
from .coefficients import MAX_CANONICAL_TERMS, SEPARATION_FRACTION, nodal_terms
from .coordinates import coordinate_infos
from .operators_1d import CoordinateOps, SteadyOps, TimeOps, boundary_kinds
from .separate import MAX_SEPARATION_RANK

__all__ = ["STATE", "Discretization", "discretize"]


STATE = "<state>"
# Space preconditioner (M + tau K)^-1 with tau = TAU_FRACTION * (time span): smaller tau keeps
# the residual norm closer to the error (measured on heat2d_source: error 3.0e-6 at tau = T,
# 6.8e-7 at T/10, 1.6e-7 at T/100 for the same residual), larger tau converges in fewer modes.
# The gap is widest early: a spatial frequency lambda is weighted by about
# (1 + kappa lambda t) / (1 + tau lambda) in the integrated residual, so while kappa t < tau the
# high frequencies count up to tau lambda times less than in the error. Measured on heat2d_source
# (tolerance 3e-8, 36 time nodes) against the method-of-lines reference, worst error over
# x, y in [0.8, 1]^2 and t < 0.02 at kappa = 0.1, q = 2: 1.2e-6 at T/100 (106 modes), 5.9e-7 at
# 0.003 T (120), 4.8e-7 at T/1000 (124); 6.2e-6 at T/10 (81 modes, interior points). heat2d and
# heat1d keep their modes and accuracy.
TAU_FRACTION = 0.003


# ----------------------------------------------------------------------------------------------
# discretization: problem -> separated operator and source
# ----------------------------------------------------------------------------------------------
@dataclass
class Discretization:
    """The discrete separated system of a problem.

    Mode 0 is the *state* mode: the unknowns stacked over the free time nodes
    (size ``q * (n_t - 1)``), so each rank-one term carries its own time
    function for every unknown while the parameter factors are shared; the
    coupling between equations lives in this mode's matrices. Modes 1.. are
    the other coordinates in spec order. A steady problem (``time`` None) has
    a state mode of size ``q``: one weight per unknown.

    Attributes
    ----------
    names : list of str
        ``STATE`` then the parameter coordinate names.
    bases : dict
        Coordinate name -> :class:`~pgdcli.discretization.basis.Basis1D`.
    operator : SeparatedOperator
        Preconditioned operator; ``terms[k][j]`` of shape (n_j, n_j).
    source : CPTensor
        Preconditioned right-hand side.
    lift : dict
        Unknown name -> CPTensor over all coordinates (spec order), in nodal
        values: the initial value (time factor 1), or for a steady problem the
        Dirichlet values on the boundary nodes (zero inside).
    unknowns : list of str
    coordinates : list of str
        All coordinate names in spec order.
    time : str or None
        None for a steady problem.
    """

    names: list[str]
    bases: dict[str, Basis1D]
    operator: SeparatedOperator
    source: CPTensor
    lift: dict[str, CPTensor]
    unknowns: list[str]
    coordinates: list[str]
    time: str | None
    trial: dict = field(default_factory=dict)  # coordinate -> trial node indices (Dirichlet ends removed)
    separations: list = field(default_factory=list)  # per non-separable coefficient: how it was separated
    # per mode (state first), the quadrature weights whose square roots the operator's rows carry
    row_weights: list = field(default_factory=list)

    def nodal_factors(self, factors: list[np.ndarray]) -> dict[str, list[np.ndarray]]:
        """Solver factors -> per unknown, nodal mode matrices over the coordinates (spec order)."""
        free = 1 if self.time is None else self.bases[self.time].nodes.size - 1
        state = factors[0].reshape(len(self.unknowns), free, -1)
        params = {}
        for name, f in zip(self.names[1:], factors[1:]):
            if name in self.trial:  # Dirichlet ends: the lift carries the value, v vanishes there
                full = np.zeros((self.bases[name].nodes.size, f.shape[1]))
                full[self.trial[name]] = f
                f = full
            params[name] = f
        out = {}
        for s, u in enumerate(self.unknowns):
            if self.time is None:  # the unknown's weight goes into the first coordinate's modes
                first = self.coordinates[0]
                out[u] = [params[c] * state[s] if c == first else params[c] for c in self.coordinates]
                continue
            tf = np.vstack([np.zeros((1, state.shape[2])), state[s]])  # v(t0) = 0
            out[u] = [tf if c == self.time else params[c] for c in self.coordinates]
        return out


def _factor_values(term, basis_of: dict[str, Basis1D]) -> dict[str, np.ndarray]:
    """Values at the nodes of every coordinate factor of a SepTerm (absent coordinates: ones)."""
    values = {name: np.ones(b.nodes.size) for name, b in basis_of.items()}
    for coord, func in term.factors:
        nodes = basis_of[coord].nodes
        v = np.broadcast_to(np.asarray(func(nodes), dtype=float), nodes.shape)
        if not np.all(np.isfinite(v)):
            raise SolverError(f"coefficient {func} is not finite at some nodes of coordinate {coord!r}")
        values[coord] = np.array(v)
    return values


def _merge_terms(terms: list[tuple[np.ndarray, ...]]) -> list[tuple[np.ndarray, ...]]:
    """Sum Kronecker terms that differ in at most one mode (fewer terms, cheaper sweeps)."""
    merged: list[list[np.ndarray]] = []
    for term in terms:
        for other in merged:
            differ = [j for j, (a, b) in enumerate(zip(term, other)) if not np.array_equal(a, b)]
            if len(differ) <= 1:
                if differ:
                    other[differ[0]] = other[differ[0]] + term[differ[0]]
                else:
                    other[0] = 2.0 * other[0]
                break
        else:
            merged.append(list(term))
    return [tuple(t) for t in merged]


def _initial_lift(unknown, bases: dict[str, Basis1D], tolerance: float, reports: list,
                  source: str) -> list[tuple[float, dict[str, np.ndarray]]]:
    """The initial value's separated terms as ``(coef, {coordinate: nodal values})``."""
    return nodal_terms(unknown.initial, {c: b.nodes for c, b in bases.items()}, tolerance,
                       where=f"{source}: unknowns.{unknown.name}.initial: ", reports=reports,
                       max_rank=MAX_SEPARATION_RANK)


def _dirichlet_lift(unknown, bases: dict[str, Basis1D]) -> list[tuple[float, dict[str, np.ndarray]]]:
    """A discrete lift of the Dirichlet values: the value on the boundary nodes, zero inside.

    Each term is a cardinal vector at one end of its coordinate times the value's factors, so
    the lift is separated whatever the value depends on. A node on the Dirichlet ends of two
    coordinates (a corner) takes the value of the coordinate listed first: the later
    coordinate's terms vanish there.
    """
    terms = []
    masks: dict[str, np.ndarray] = {}  # earlier Dirichlet coordinates -> 0 on their Dirichlet ends
    for coord, ends in unknown.boundary.items():
        n = bases[coord].nodes.size
        mask = np.ones(n)
        for side, bc in enumerate(ends):
            if bc.kind != "value":
                continue
            end = 0 if side == 0 else n - 1
            mask[end] = 0.0
            for g in bc.value.terms:
                vals = _factor_values(g, bases)
                vals[coord] = np.zeros(n)
                vals[coord][end] = 1.0
                for other, m in masks.items():
                    vals[other] = vals[other] * m
                terms.append((g.coef, vals))
        if np.any(mask == 0.0):
            masks[coord] = mask
    return terms


def discretize(problem, *, tolerance: float | None = None, max_terms: int = MAX_CANONICAL_TERMS) -> Discretization:
    """Assemble the separated operator, source and lift of a linear problem.

    Time-dependent problems are lifted by the initial value (``u = u0 + v``, ``v(t0) = 0``);
    steady ones by the Dirichlet values (``u = g + v``, ``v = 0`` on Dirichlet ends).
    Non-separable coefficients are separated on the nodes (:func:`pgdcli.discretization.coefficients.nodal_terms`)
    to ``SEPARATION_FRACTION * tolerance``; ``Discretization.separations`` says how.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
    tolerance : float, optional
        The solver's tolerance (default ``problem.solver.tolerance``).
    max_terms : int
        Most Kronecker terms of one non-separable coefficient's expansion
        (:class:`~pgdcli.discretization.coefficients.CanonicalTermsError` beyond).

    Returns
    -------
    Discretization
    """
    coords = list(problem.coordinates)
    tname = problem.time
    bases = {info.name: info.basis() for info in coordinate_infos(problem, march=False)}
    nodes = {c: b.nodes for c, b in bases.items()}
    delta = SEPARATION_FRACTION * (problem.solver.tolerance if tolerance is None else tolerance)
    separations: list = []
    cap = min(MAX_SEPARATION_RANK, problem.solver.max_rank)
    params = [c.name for c in coords if c.name != tname]
    time, tau, lifts = _time_and_lifts(problem, bases, delta, separations)
    ops = {c: CoordinateOps(c, bases[c], problem.coordinate(c).role, boundary_kinds(problem, c), tau[c])
           for c in params}
    asm = _Assembly(len(problem.unknowns), params, ops, time, tname)
    index = {u.name: s for s, u in enumerate(problem.unknowns)}
    for eq in problem.equations:
        r = eq.index
        for monomial, sep in eq.polynomial.items():
            terms = nodal_terms(sep, nodes, delta, where=f"{problem.source}: equations[{r}]: ", reports=separations,
                                max_rank=cap, max_terms=max_terms)
            if len(monomial) == 0:
                for coef, vals in terms:
                    asm.add_source(r, -coef, time.load(asm.time_values(vals)), asm.tested_values(vals))
                continue
            if len(monomial) != 1:
                raise SolverError(f"equations[{r}]: nonlinear term; the linear solver needs equations linear in the unknowns")
            atom = monomial[0]
            for term_coef, vals in terms:
                _add_linear_term(asm, problem, r, index[atom.unknown], atom, term_coef, vals, lifts, bases)
    if not asm.op_terms:
        raise SolverError("the equations have no term in the unknowns")
    return _discretization(problem, asm, bases, lifts, separations)


def _time_and_lifts(problem, bases: dict[str, Basis1D], delta: float, separations: list):
    """The time operators (steady: none), the preconditioner's tau per coordinate, and the lift terms."""
    coords = list(problem.coordinates)
    tname = problem.time
    if tname is None:
        # tau = L^2 makes (M + tau K)^-1 K bounded above and below in each space coordinate,
        # so the residual tracks the error (there is no time integration to do it)
        tau = {c.name: (c.domain[1] - c.domain[0]) ** 2 for c in coords}
        return SteadyOps(), tau, {u.name: _dirichlet_lift(u, bases) for u in problem.unknowns}
    span = float(bases[tname].nodes[-1] - bases[tname].nodes[0])
    tau = {c.name: span * TAU_FRACTION for c in coords}
    # a Dirichlet value must equal the initial value there: the lift u0 carries it for all times
    check_initial_meets_boundary(problem, 1e-9, 1e-9, error=SolverError,
                                 why="and the linear solver's lift carries the initial value for all times")
    lifts = {u.name: _initial_lift(u, bases, delta, separations, problem.source) for u in problem.unknowns}
    return TimeOps(bases[tname]), tau, lifts


class _Assembly:
    """The separated operator terms and source terms of :func:`discretize`, as they are collected."""

    def __init__(self, q: int, params: list[str], ops: dict, time, tname: str | None) -> None:
        self.q, self.params, self.ops, self.time, self.tname = q, params, ops, time, tname
        self.op_terms: list[tuple[np.ndarray, ...]] = []
        self.src_w: list[float] = []
        self.src_f: list[list[np.ndarray]] = []

    def unit(self, r: int) -> np.ndarray:
        e = np.zeros(self.q)
        e[r] = 1.0
        return e

    def time_values(self, vals: dict[str, np.ndarray]):
        return None if self.tname is None else vals[self.tname]

    def add_source(self, r: int, coef: float, time_vec: np.ndarray, vectors: dict[str, np.ndarray]) -> None:
        self.src_w.append(coef)
        self.src_f.append([np.kron(self.unit(r), time_vec)] + [vectors[c] for c in self.params])

    def tested_values(self, vals: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {c: self.ops[c].load(vals[c]) for c in self.params}


def _add_linear_term(asm: _Assembly, problem, r: int, s: int, atom, term_coef: float, vals: dict, lifts: dict,
                     bases: dict[str, Basis1D]) -> None:
    """One separated term ``term_coef * prod_c vals[c]`` of unknown ``s`` (or its derivative) in equation ``r``:
    its operator term, the lift moved to the right-hand side, and the known boundary flux of gradient ends."""
    ops, params, time, tname = asm.ops, asm.params, asm.time, asm.tname
    is_der = atom.order == 1 and atom.coordinate == tname
    space_der = atom.order > 0 and atom.coordinate != tname
    coupling = np.zeros((asm.q, asm.q))
    coupling[r, s] = term_coef
    full = {}
    for c in params:
        if space_der and c == atom.coordinate:
            if atom.order == 2:
                full[c] = ops[c].second(vals[c])
            else:
                full[c] = ops[c].first(vals[c])
        else:
            full[c] = ops[c].mass(vals[c])
    asm.op_terms.append((np.kron(coupling, time.operator(asm.time_values(vals), is_der)),)
                        + tuple(full[c][:, ops[c].trial] for c in params))
    if not is_der:
        # the lift (constant in time) moves to the right-hand side
        for coef, lvals in lifts[atom.unknown]:
            asm.add_source(r, -term_coef * coef, time.constant(asm.time_values(vals)),
                           {c: full[c] @ lvals[c] for c in params})
    if space_der and atom.order == 2:
        # weak form: the boundary flux [du/dx phi] of gradient ends is known data
        c = atom.coordinate
        for side, bc in enumerate(problem.unknowns[s].boundary.get(c, ())):
            if bc.kind != "gradient":
                continue
            for g in bc.value.terms:
                gvals = _factor_values(g, bases)
                vectors = {p: ops[p].load(vals[p] * gvals[p]) for p in params if p != c}
                # [f u' phi] at that end: the coefficient's value there times the gradient
                vectors[c] = vals[c][0 if side == 0 else -1] * ops[c].flux(side)
                asm.add_source(r, -term_coef * g.coef, time.constant(asm.time_values(vals)), vectors)


def _discretization(problem, asm: _Assembly, bases: dict[str, Basis1D], lifts: dict, separations: list
                    ) -> Discretization:
    """The collected terms as separated tensors: operator, source, lift per unknown, trial nodes."""
    coords = list(problem.coordinates)
    unknowns = [u.name for u in problem.unknowns]
    names = [STATE] + asm.params
    op_terms = _merge_terms(asm.op_terms)
    sizes = [m.shape[0] for m in op_terms[0]]
    src_f = asm.src_f
    source = CPTensor(np.array(asm.src_w), [np.column_stack([f[j] for f in src_f]) if src_f
                                            else np.zeros((sizes[j], 0)) for j in range(len(names))])
    lift = {}
    for u in unknowns:
        ws = [coef for coef, _ in lifts[u]]
        lift[u] = CPTensor(
            np.array(ws), [np.column_stack([vals[c.name] for _, vals in lifts[u]]) if ws
                           else np.zeros((bases[c.name].nodes.size, 0)) for c in coords])
    trial = {c: asm.ops[c].trial for c in asm.params if asm.ops[c].trial.size != bases[c].nodes.size}
    time_weights = np.ones(1) if problem.time is None else bases[problem.time].time_weights()
    row_weights = [np.tile(time_weights, len(unknowns))] + [asm.ops[c].w[asm.ops[c].test] for c in asm.params]
    return Discretization(names, bases, SeparatedOperator(tuple(op_terms)), source, lift, unknowns,
                          [c.name for c in coords], problem.time, trial, separations, row_weights)

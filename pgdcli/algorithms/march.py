"""Nonlinear problems: a time march of the parameter-separated state.

For equations polynomial in the unknowns (``der(u1) + u2*u3 = 1``), the state
``u(t_n; p)`` is kept as a function of the non-time coordinates ``p`` (initial
conditions, parameters) in tensor-train form (:mod:`pgdcli.tensors.tt`) and advanced
with the explicit Dormand-Prince 8(5,3) Runge-Kutta scheme (the coefficients
of :class:`scipy.integrate.DOP853`), whose embedded estimate controls the step
size. The right-hand side is evaluated in separated form: products of
unknowns are Hadamard products of tensor trains, and every stage value is
recompressed once by SVD-based rounding with an absolute Frobenius bound, so
ranks stay near those of the solution instead of growing as N^2. The state is
stored at the nodes of the time coordinate (steps land on them) and the
codebook interpolates between them with the time basis.

Error control, all in the root-mean-square norm over the nodes of the
parameter grid (the Frobenius norm of the tensor divided by the square root
of its size; a Frobenius bound would bound the largest nodal error but grows
as sqrt(grid size), which in six dimensions asks for 512x the accuracy and
ranks to match): local Runge-Kutta error <=
``0.3 * tolerance * h / T`` per step (error per unit step: the local errors
add up to at most 0.3 tolerance), state rounding <= ``0.02 * tolerance`` per
step, stage rounding <= ``0.05 * tolerance`` (its effect on the step is scaled
by ``h``). The report's ``error_estimate`` adds these up over the march; it
does not include the growth of errors through the dynamics (the Lipschitz
factor), and the worst point of the grid can be 5-20 times the RMS: the user's
tolerance is a max abs error, measured against scipy after the march and
enforced by repeating it with a tighter RMS target (:mod:`pgdcli.checks.check`,
``pgdcli.driver._checked_march``).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import numpy as np

from ..discretization.basis import Basis1D, chebyshev_unit_nodes
from ..discretization.coordinates import coordinate_infos
from ..problem.expressions import Separable, SepTerm, merge_to_function
from ..errors import SolverError
from .general_rhs import CROSS_SHARE, GeneralPart, general_monomials, report_entries, underflow_hint
from ..discretization.coefficients import SEPARATION_FRACTION, JointTrain, separation_report_text
from ..discretization.separate import MAX_SEPARATION_RANK
from ..tensors.tt import (TT, is_ones, tt_concatenate, tt_hadamard, tt_ones, tt_rank_one, tt_round, tt_round_many,
                 tt_round_sum_of_products, tt_sum)

__all__ = ["NonlinearSystem", "MarchResult", "MarchFailure", "compile_system", "march", "join_and_round",
           "solve_march"]


# Step-size control. The error per unit step grows along these solutions, so the
# usual safety factor 0.9 made every other step a rejection (12 wasted stages);
# 0.8 removed them on the shipped problems (measured: 5 steps, 0 rejections on
# coupled.yaml against 5 + 2).
MAX_GROWTH = 3.0
SAFETY = 0.8
# Shares of the tolerance: local Runge-Kutta error, state rounding per step,
# stage rounding (enters the step multiplied by h).
LOCAL_FRACTION, STATE_FRACTION, STAGE_FRACTION = 0.3, 0.02, 0.05
# Share of the tolerance for rounding the joined space-time train of the codebook: it sets
# the codebook's ranks (size, query cost) and is added to the error estimate once.
SPACE_TIME_FRACTION = 0.1
# Blow-up detection: a step below MIN_STEP * (time span), or a state whose norm grew
# by MAX_GROWTH_OF_NORM, ends the march (near a finite-time singularity the steps
# shrink geometrically, so waiting for a floating-point underflow costs hundreds of steps).
MIN_STEP = 1e-7
# Above this implicit rank (sum over terms of the product ranks) a rounding goes
# through the randomized sketch instead of forming the sum explicitly.
EXACT_RANK_LIMIT = 160
MAX_GROWTH_OF_NORM = 1e6
# Stiff problems: a rounding error dY of a stage value reaches the error estimate as J dY, which
# no step size reduces; each time that is detected the stage rounding is made 10x tighter, at
# most this many times (then the step-size floor ends the march: 'blows up or is stiff').
MAX_STAGE_TIGHTENINGS = 4
# Blow-up prediction (see _BlowupWatch): near a pole u ~ c / (t* - t) the error control shrinks
# every step, so the step-size floor above is reached only after hundreds of ever smaller steps
# at growing ranks (the paper's 4.2 on [0, 1]: 504 steps, ~100 s). Once the steps have shrunk
# WATCH_STEPS times in a row and WATCH_SHRINK-fold overall, 1/max|u| is extrapolated to zero.
WATCH_STEPS, WATCH_SHRINK = 8, 10.0
# The prediction stops the march when the state grew BLOWUP_GROWTH-fold and two extrapolations
# a span of at least WATCH_SPAN x (the distance left) apart agree to WATCH_AGREE x that distance:
# a pole's estimates converge, an exponential's (1/max|u| = exp(-lambda t)) move with t.
BLOWUP_GROWTH, WATCH_SPAN, WATCH_AGREE = 10.0, 0.3, 0.1
# Grids up to this many nodes are searched whole for max|u| once armed, larger ones at their corners
# (if the largest value is inside, its 1/M may not fall to zero: no prediction, the floor still holds).
WATCH_POINTS = 200_000


SINGLE_POINT = "<single point>"


class _SinglePoint:
    """The 'grid' of a problem without non-time coordinates: one node."""

    nodes = np.zeros(1)


class _BlowupWatch:
    """Predicts a finite-time blow-up from the accepted steps, long before the steps underflow.

    Only while the steps keep shrinking (``WATCH_STEPS`` in a row, ``WATCH_SHRINK``-fold
    below the largest) does it look at the state: the largest nodal value ``M(t)`` of any
    unknown. Near a pole ``1/M`` falls (almost linearly) to zero at the blow-up time ``t*``, so
    the parabola through the last three samples estimates ``t*`` (the line through two, at
    first). The march is stopped when ``M`` grew ``BLOWUP_GROWTH``-fold since the start, and
    the estimate made at least ``WATCH_SPAN`` x (the distance left) earlier agrees with the
    current one to ``WATCH_AGREE`` x that distance, and ``t*`` plus twice their disagreement
    lies before the end of the time domain. Exponential growth also shrinks the steps
    (absolute error control), but its extrapolated ``t*`` stays ``1/lambda`` ahead of ``t``:
    the two estimates then differ by the span between them and it never fires.
    """

    def __init__(self, system: "NonlinearSystem", state: list[TT], t_final: float):
        self.system, self.t_final = system, t_final
        self.initial = max(_largest(system, state, WATCH_POINTS)[0], 1e-300)
        self.largest = 0.0  # the largest accepted step so far
        self.samples: list[tuple[float, float, float | None]] = []  # (t, 1/M, estimate of t*)

    def __call__(self, t: float, sizes: list[float], state: list[TT]) -> float | None:
        """After an accepted step ending at ``t`` (``sizes``: the march's accepted steps, this one
        last): the predicted blow-up time, or None."""
        h = sizes[-1]
        self.largest = max(self.largest, h)
        recent = sizes[-WATCH_STEPS - 1:]
        shrinking = (len(recent) == WATCH_STEPS + 1 and all(b < a for a, b in zip(recent, recent[1:]))
                     and h * WATCH_SHRINK <= self.largest)
        if not shrinking:
            self.samples.clear()
            return None
        biggest = _largest(self.system, state, WATCH_POINTS)[0]
        inverse = 1.0 / biggest if biggest > 0 else np.inf
        self.samples.append((t, inverse, None))
        estimate = _first_zero_after(self.samples[-3:]) if len(self.samples) >= 2 else None
        self.samples[-1] = (t, inverse, estimate)
        if estimate is None or biggest < BLOWUP_GROWTH * self.initial or estimate >= self.t_final:
            return None
        for t_then, _, earlier in reversed(self.samples[:-1]):
            if t - t_then >= WATCH_SPAN * (estimate - t):
                return estimate if earlier is not None and _confirmed(t, estimate, earlier, self.t_final) else None
        return None


def _confirmed(t: float, estimate: float, earlier: float, t_final: float) -> bool:
    """Two estimates of the blow-up time agree to ``WATCH_AGREE`` x the distance left, and the
    end lies after the estimate by more than twice their disagreement (a pole just past the end is
    no failure: the march goes on and reaches the end)."""
    spread = abs(estimate - earlier)
    return spread <= WATCH_AGREE * (estimate - t) and estimate + 2.0 * spread < t_final


def _first_zero_after(samples: list[tuple]) -> float | None:
    """Where the line (two samples) or parabola (three) through ``(t, 1/M)`` first reaches zero after
    the last ``t``; None if it does not fall to zero. Near a pole ``1/M = (t* - t)/c + O((t* - t)^2)``:
    the parabola's root is accurate to third order in the distance left, the line's to second."""
    ts = np.array([x[0] for x in samples])
    ys = np.array([x[1] for x in samples])
    if not np.all(np.isfinite(ys)):
        return None
    t_last, scale = ts[-1], ts[-1] - ts[0]
    coef = np.polyfit((ts - t_last) / scale, ys, len(ts) - 1)  # about the last sample, unit span
    roots = np.roots(coef)
    ahead = [float(r.real) for r in roots if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0.0]
    return t_last + scale * min(ahead) if ahead else None


def _largest(system: "NonlinearSystem", state: list[TT], max_points: int = 2_000_000) -> tuple[float, tuple]:
    """Largest nodal |value| of any unknown and its grid index: the whole grid if it has at most
    ``max_points`` nodes, else the corners of the box only (where blow-ups start in practice)."""
    shape = system.shape
    if int(np.prod(shape)) <= max_points:
        values = np.max([np.abs(u.full()) for u in state], axis=0)
        idx = np.unravel_index(int(np.argmax(values)), shape)
        return float(values[idx]), tuple(int(i) for i in idx)
    best, idx = -1.0, None
    for corner in np.ndindex(*(2,) * len(shape)):
        ix = tuple(0 if c == 0 else n - 1 for c, n in zip(corner, shape))
        mats = [np.eye(n)[[i]] for n, i in zip(shape, ix)]
        v = max(abs(float(u.evaluate(mats)[0])) for u in state)
        if v > best:
            best, idx = v, ix
    return best, idx


class MarchFailure(Exception):
    """The march could not continue (blow-up, step size underflow, caps).

    Attributes
    ----------
    time : float
        Time reached.
    state : list of TT or None
        The last accepted state (to locate the failure in the domain).
    blowup_time : float or None
        The predicted blow-up time, when the march stopped on that prediction.
    """

    def __init__(self, message: str, time: float, state: list | None = None, blowup_time: float | None = None):
        super().__init__(message)
        self.time = time
        self.state = state
        self.blowup_time = blowup_time


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
            if mono == ders[0][0] or mono in crossed:
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
    initial = []
    for u in problem.unknowns:
        terms = [tt_rank_one(_param_vectors(term, params, bases), term.coef) for term in u.initial.terms]
        for joint in u.initial.joints:
            train = JointTrain(joint, tname, params, {p: bases[p].nodes for p in params}, delta,
                               where=f"{where}: unknowns.{u.name}.initial: ", reports=separations, max_rank=cap)
            terms.append(_JointPart(joint.term.coef, None, _param_vectors(joint.term, params, bases), train).at(0.0))
        if not terms:
            terms = [tt_rank_one([np.zeros(bases[p].nodes.size) for p in params])]
        initial.append(tt_round(tt_sum(terms), 1e-15))
    return NonlinearSystem(unknowns, params, bases, bases[tname], rhs, initial, general)


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
    return round_terms(per_unknown, delta, hints, max_rank, rng, stats)


def round_terms(per_unknown: list[list[tuple[float, TT, TT]]], delta: float, hints: list[int], max_rank: int,
                rng: np.random.Generator | None, stats: dict | None = None) -> list[TT]:
    """Sum and round ``sum_m w_m A_m * B_m`` for every unknown (absolute Frobenius bound ``delta``).

    Small implicit ranks: explicit sums rounded together (batched QR/SVD across
    unknowns, the fast path for small problems). Large ones: each unknown by
    the randomized sum-of-products rounding, sized from the unknown's current
    rank, which never forms a product of rank r^2.
    """
    d = per_unknown[0][0][1].order

    def implicit(terms):
        if d == 1:
            return 1
        return sum(max(a.cores[k].shape[2] * b.cores[k].shape[2] for k in range(d - 1)) for _, a, b in terms)

    if all(implicit(terms) <= EXACT_RANK_LIMIT for terms in per_unknown):
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


@dataclass
class MarchResult:
    """States at the time nodes and what the march did."""

    states: list[list[TT]]  # [time node][unknown]
    steps: int
    rejected: int
    error_estimate: float
    ranks: list[list[tuple[int, ...]]]  # [time node][unknown]
    step_sizes: list[float] = field(default_factory=list)
    times: np.ndarray | None = None  # the time nodes the states are at
    breakpoints: np.ndarray | None = None  # slab boundaries (automatic slabs only)
    roundings: dict = field(default_factory=dict)  # {"exact", "sketched", "redone"}: counts


def _lift(train: TT) -> TT:
    """The train with a leading mode of size 1 (a run of one time node)."""
    return TT([np.ones((1, 1, 1))] + list(train.cores))


def _frobenius_of_sum(terms: list[TT], weights) -> float:
    nz = [(w, t) for w, t in zip(weights, terms) if w != 0.0]
    if not nz:
        return 0.0
    return tt_sum([t for _, t in nz], [w for w, _ in nz]).norm()


def _dense_weights(x: float, h: float, D: np.ndarray) -> np.ndarray:
    """DOP853 dense output at ``t_old + x h`` as weights of ``[y_old, y_new, K_0..K_15]``.

    The same nested polynomial as scipy's ``Dop853DenseOutput``, applied to
    coefficient vectors instead of states, so the value is one linear
    combination of tensor trains.
    """
    nk = D.shape[1]
    size = 2 + nk
    y_old, y_new = np.eye(size)[0], np.eye(size)[1]
    K = np.eye(size)[2:]
    delta = y_new - y_old
    F = [delta, h * K[0] - delta, 2 * delta - h * (K[12] + K[0])] + [h * (D[i] @ K) for i in range(D.shape[0])]
    y = np.zeros(size)
    for i, f in enumerate(reversed(F)):
        y = y + f
        y = y * (x if i % 2 == 0 else 1.0 - x)
    return y + y_old


def march(system: NonlinearSystem, tolerance: float, *, max_rank: int = 400, max_steps: int = 20000,
          callback=None, slab_nodes: int | None = None) -> MarchResult:
    """Advance the separated state over the time domain with DOP853 and dense output.

    Steps are chosen by the embedded error estimate (not by the time nodes);
    the state at every time node inside a step comes from the scheme's
    order-7 dense output (three extra stages per step that contains nodes).

    Parameters
    ----------
    system : NonlinearSystem
    tolerance : float
        Error target: root mean square over the nodes of the parameter grid, per
        unknown, of the local errors added up over the march.
    max_rank, max_steps : int
        Caps; exceeding them raises :class:`MarchFailure`.
    callback : callable, optional
        Called after every accepted step with ``{"time", "end", "ranks", "steps"}``.
    slab_nodes : int, optional
        Automatic time slabs: every accepted step is a slab and the state is
        stored at its ``slab_nodes`` Chebyshev-Lobatto nodes (from 8 on, the
        dense output, a polynomial of degree 7, is reproduced exactly by the
        codebook's interpolation). Without it, the nodes of the time basis.

    Raises
    ------
    MarchFailure
        With the time where the march stopped.
    """
    from scipy.integrate import DOP853

    A, B, C, E3, E5 = DOP853.A, DOP853.B, DOP853.C, DOP853.E3, DOP853.E5
    A_extra, C_extra, D = DOP853.A_EXTRA, DOP853.C_EXTRA, DOP853.D
    n_stages = DOP853.n_stages
    nodes = system.time_basis.nodes
    t_final = float(nodes[-1])
    q = len(system.unknowns)
    # tolerance is a root-mean-square error over the parameter grid; the tensor
    # arithmetic works with Frobenius norms, sqrt(grid size) times larger
    frobenius = tolerance * np.sqrt(float(np.prod(system.shape)))
    local_tol = LOCAL_FRACTION * frobenius
    state_delta = STATE_FRACTION * frobenius
    stage_delta = STAGE_FRACTION * frobenius

    rng = np.random.default_rng(20240607)  # the randomized roundings: same spec, same codebook
    stats = {"exact": 0, "sketched": 0, "redone": 0}  # roundings, for the report
    ones = tt_ones(system.shape)

    def rhs(t, state):
        return evaluate_rhs(system, t, state, stage_delta, max_rank, rng, stats)

    def combine(y, ks, weights, delta, base_weight=1.0):
        """``base_weight * y + sum_j w_j k_j`` per unknown, rounded."""
        per_unknown = []
        for i in range(q):
            terms = [(base_weight, y[i], ones)] + [(float(w), k[i], ones) for k, w in zip(ks, weights) if w != 0.0]
            per_unknown.append([tm for tm in terms if tm[0] != 0.0])
        return round_terms(per_unknown, delta, [max(u.ranks, default=1) for u in y], max_rank, rng, stats)

    y = tt_round_many(system.initial, absolute=state_delta, max_rank=max_rank)
    t = float(nodes[0])
    span = t_final - t
    scale0 = max(1.0, max(u.norm() for u in y))
    f = rhs(t, y)
    states: list[list[TT]] = [y]
    times = [t]
    breakpoints = [t]
    next_node = 1
    h = min(t_final - t, 0.1 * (t_final - t))
    steps = rejected = 0
    error_estimate = 0.0
    sizes = []
    just_rejected = False
    watch = _BlowupWatch(system, y, t_final)
    last_rejection = None  # (t, h, ratio) of the last rejected trial step
    stats["stage_tightenings"] = 0
    while t < t_final:
        if steps + rejected >= max_steps:
            raise MarchFailure(f"max_steps={max_steps} reached", t, y)
        h = min(h, t_final - t)
        if h < MIN_STEP * span:
            raise MarchFailure("step size underflow (the solution blows up or is stiff" + underflow_hint(system.general, stats)
                               + ")", t, y)
        err = np.inf
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                K = [f]
                for s in range(1, n_stages):
                    stage = combine(y, K, h * A[s, :s], stage_delta)
                    K.append(rhs(t + C[s] * h, stage))
                # the state's rounding budget is per unit step too: it adds up to STATE_FRACTION * tolerance
                y_new = combine(y, K, h * B, state_delta * h / span)
                norm_new = max(u.norm() for u in y_new)
                if np.isfinite(norm_new):
                    f_new = rhs(t + h, y_new)
                    K.append(f_new)
                    err = 0.0
                    for i in range(q):
                        col = [K[j][i] for j in range(n_stages + 1)]
                        e5 = _frobenius_of_sum(col, E5)
                        e3 = _frobenius_of_sum(col, E3)
                        if e5 > 0.0 or e3 > 0.0:
                            err = max(err, h * e5 * e5 / np.sqrt(e5 * e5 + 0.01 * e3 * e3))
        except np.linalg.LinAlgError:  # a factorization met the non-finite values of an overflow
            err = np.inf
        # error per unit step: the local errors of all steps add up to <= LOCAL_FRACTION * tolerance
        ratio = err / (local_tol * h / span) if np.isfinite(err) else np.inf
        if ratio > 1.0:
            rejected += 1
            just_rejected = True
            if (np.isfinite(ratio) and last_rejection is not None and last_rejection[0] == t
                    and h <= 0.7 * last_rejection[1] and ratio >= 0.5 * last_rejection[2]
                    and stats["stage_tightenings"] < MAX_STAGE_TIGHTENINGS):
                # a shorter step did not lower the estimate, as an order-8 error would (h^7 per unit
                # step): it is the stage roundings' noise, amplified by a stiff Jacobian (dK = J dY).
                # Round the stages tighter and retry the same step.
                stage_delta /= 10.0
                stats["stage_tightenings"] += 1
                last_rejection = None
                continue
            last_rejection = (t, h, ratio)
            # an overflowed trial step (ratio inf) was far too long for a stiff or fast problem:
            # shrink it as much as allowed (a blow-up shows in the accepted steps, _BlowupWatch)
            h *= max(0.2, SAFETY * ratio ** (-1.0 / 7.0))
            continue
        if max(max(u.ranks, default=0) for u in y_new) >= max_rank:
            # a capped rounding breaks the error bound: say so rather than report a wrong estimate
            raise MarchFailure(f"a tensor-train rank reached solver.max_rank={max_rank} (raise it, or loosen "
                               f"the tolerance)", t, y)
        if norm_new > MAX_GROWTH_OF_NORM * scale0:
            raise MarchFailure("the solution blows up", t, y)
        t_new = t_final if abs(t + h - t_final) <= 1e-14 * max(1.0, abs(t_final)) else t + h
        if slab_nodes:  # the step is a slab: its Chebyshev-Lobatto nodes, the last one t_new
            outs = list(t + h * (chebyshev_unit_nodes(slab_nodes)[1:] + 1.0) / 2.0)
            outs[-1] = t_new
            breakpoints.append(t_new)
        else:
            outs = []
            while next_node < nodes.size and nodes[next_node] <= t_new:
                outs.append(float(nodes[next_node]))
                next_node += 1
        if any(tn < t_new for tn in outs):
            for s, (a, c) in enumerate(zip(A_extra, C_extra), start=n_stages + 1):
                stage = combine(y, K, h * a[:s], stage_delta)
                K.append(rhs(t + c * h, stage))
        # the dense output at the step's interior nodes, one combination of y, y_new and K each
        # (measured faster on coupled.yaml, 324 vs 358 ms, than joining the 18 trains along a
        # combination mode and rounding once, or than rounding all nodes in one padded batch)
        for tn in outs:
            if tn >= t_new:
                states.append(y_new)
            else:
                w = _dense_weights((tn - t) / h, h, D)
                states.append(combine(y, [y_new] + K, w[1:], state_delta, base_weight=w[0]))
        times.extend(outs)
        t, y, f = t_new, y_new, f_new
        steps += 1
        sizes.append(h)
        error_estimate += err + state_delta * h / span
        # growth capped (a rejected step costs 12 stages) and none right after a rejection
        if not just_rejected or ratio < 0.5:
            h *= MAX_GROWTH if ratio == 0.0 else min(MAX_GROWTH, max(0.2, SAFETY * ratio ** (-1.0 / 7.0)))
        just_rejected = False
        if callback is not None:
            callback({"time": t, "end": t_final, "ranks": [u.ranks for u in y], "steps": steps})
        if t < t_final:
            blowup = watch(t, sizes, y)
            if blowup is not None:
                raise MarchFailure("the solution blows up", t, y, blowup)
    ranks = [[u.ranks for u in st] for st in states]
    error_estimate += state_delta  # the rounding of the values at the time nodes (once)
    rms = error_estimate / np.sqrt(float(np.prod(system.shape)))
    return MarchResult(states, steps, rejected, rms, ranks, sizes, np.array(times),
                       np.array(breakpoints) if slab_nodes else None, stats)


def join_and_round(groups: list[list[TT]], delta: float, rng: np.random.Generator | None = None,
                   fan_in: int = 8, batched: bool = True,
                   stats: dict | None = None) -> list[TT]:
    """Each group's trains joined along a new leading mode (``X[n, ...] = group[n][...]``), rounded
    to Frobenius error ``delta``: the codebook's space-time train from the states at the time nodes.

    Joined ranks are the sums of the members' ranks, so the join is built as a
    tree: up to ``fan_in`` members at a time are concatenated along the leading
    mode and rounded (exactly and batched across groups while the sums stay
    small, else by the randomized sum-of-products rounding, which never forms
    them), then the rounded pieces are joined the same way. The last level, which
    sets the final ranks, gets 0.7 of ``delta`` and the earlier ones share the
    rest; within a level the pieces are orthogonal blocks of the leading mode, so
    their errors add in quadrature.
    """
    levels = max(1, int(np.ceil(np.log(max(len(g) for g in groups)) / np.log(fan_in))))
    # the last level sets the final ranks: it gets most of the budget, the others share the rest
    budgets = [0.7 * delta] if levels == 1 else [0.3 * delta / (levels - 1)] * (levels - 1) + [0.7 * delta]
    budgets[-1] = delta - sum(budgets[:-1])
    pieces = [[_lift(t) for t in g] for g in groups]
    for level in range(levels + 1):
        chunks = [[g[i:i + fan_in] for i in range(0, len(g), fan_in)] for g in pieces]
        flat = [chunk for g in chunks for chunk in g]
        # the error budget of a level is shared by its chunks (orthogonal blocks)
        chunk_delta = budgets[min(level, levels - 1)] / np.sqrt(max(len(g) for g in chunks))
        rounded = _round_concatenations(flat, chunk_delta, rng, batched, stats)
        it = iter(rounded)
        pieces = [[next(it) for _ in g] for g in chunks]
        if all(len(g) == 1 for g in pieces):
            return [g[0] for g in pieces]
    raise AssertionError("the join tree did not close")  # pragma: no cover


def _round_concatenations(chunks: list[list[TT]], delta: float, rng, batched: bool = True,
                          stats: dict | None = None) -> list[TT]:
    """Round ``tt_concatenate(chunk)`` for every chunk: exactly when small, else sketched.

    ``batched`` rounds equal-shape chunks together (fast; each keeps the largest rank of its
    batch), otherwise one by one (each gets its own smallest ranks: the codebook's final join).
    """
    sums = [sum(max(t.ranks, default=1) for t in chunk) for chunk in chunks]
    if max(sums) <= EXACT_RANK_LIMIT:
        joined = [tt_concatenate(chunk) for chunk in chunks]
        if stats is not None:
            stats["exact"] = stats.get("exact", 0) + len(joined)
        by_shape: dict = {}
        for i, j in enumerate(joined):
            by_shape.setdefault(j.shape, []).append(i)
        out: list = [None] * len(joined)
        for idx in by_shape.values():  # tt_round_many needs one shape per batch
            batches = [idx] if batched else [[i] for i in idx]
            for batch in batches:
                for i, r in zip(batch, tt_round_many([joined[i] for i in batch], absolute=delta)):
                    out[i] = r
        return out
    out = []
    for chunk in chunks:
        lead = [t.shape[0] for t in chunk]
        total = sum(lead)
        terms, offset = [], 0
        for t, n in zip(chunk, lead):
            selector = np.zeros(total)
            selector[offset:offset + n] = 1.0
            padded = np.zeros((1, total, t.cores[0].shape[2]))
            padded[0, offset:offset + n] = t.cores[0][0]
            terms.append((1.0, tt_rank_one([selector] + [np.ones(m) for m in t.shape[1:]]),
                          TT([padded] + list(t.cores[1:]))))
            offset += n
        # a join spans the members' union: start the sketch at twice the largest member rank
        hint = 2 * max(max(t.ranks, default=1) for t in chunk)
        out.append(tt_round_sum_of_products(terms, absolute=delta, rank_hint=hint, rng=rng, stats=stats))
    return out


def _blowup_region(system: NonlinearSystem, state: list[TT]) -> str:
    """Where the last good state is largest, as 'a=0, b=1, c=1' (nodes of the parameter grid)."""
    if system.params == [SINGLE_POINT]:
        return ""
    _, idx = _largest(system, state)
    parts = [f"{p}={system.bases[p].nodes[i]:.4g}" for p, i in zip(system.params, idx)]
    return ", ".join(parts)


def solve_march(problem, tolerance: float, callback=None):
    """Solve a (nonlinear) problem by the separated time march; see :func:`pgdcli.driver.solve`.

    Returns
    -------
    pgdcli.driver.SolveResult
        ``converged`` is False, with a message naming the time (and the
        region of the domain) where the march failed, when it could not reach
        the end of the time domain.
    """
    from ..codebook.codebook import Codebook, CoordinateInfo, FieldTT
    from .result import SolveResult
    from .. import __version__

    opts = problem.solver
    started = _time.perf_counter()
    separations: list = []
    system = compile_system(problem, tolerance, separations)
    last: dict = {}

    def progress(info):
        last["state"] = info
        if callback is not None:
            callback(info)

    failure = None
    try:
        auto = getattr(opts, "time_slabs", "auto") == "auto"
        tcoord = problem.time_coordinate
        if auto and tcoord.discretization != "chebyshev":
            auto = False  # linear time elements: the nodes are the slabs already
        result = march(system, tolerance, max_rank=opts.max_rank, max_steps=opts.max_steps, callback=progress,
                       slab_nodes=tcoord.nodes if auto else None)
    except MarchFailure as exc:
        failure = exc
    wall = _time.perf_counter() - started
    coords = coordinate_infos(problem, march=True)
    names = [c.name for c in problem.coordinates]
    single = system.params == [SINGLE_POINT]
    order = tuple(names.index(n) for n in [problem.time] + ([] if single else system.params))
    if failure is not None:
        state = getattr(failure, "state", None)
        region = _blowup_region(system, state) if state is not None else ""
        where = f" near {region}" if region else ""
        if failure.blowup_time is not None:
            message = (f"not converged: {failure} at t ~ {failure.blowup_time:.4g}{where} (predicted: the march "
                       f"stopped at t = {failure.time:.6g}, its steps shrinking while 1/max|u| falls to zero "
                       f"there)")
        else:
            message = f"not converged: {failure} at t = {failure.time:.6g}{where}"
        report = {"converged": False, "status": 3, "message": message, "method": "march", "tolerance": tolerance,
                  "wall_time": wall, "failed_time": failure.time, "steps": int(last.get("state", {}).get("steps", 0)),
                  "pgdcli_version": __version__}
        if failure.blowup_time is not None:
            report["blowup_time"] = float(failure.blowup_time)
        fields = {u: FieldTT(tuple(np.zeros((1, c.nodes, 1)) for c in [coords[j] for j in order]), order)
                  for u in system.unknowns}
        cb = Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                      description=problem.description)
        return SolveResult(cb, False, 3, message, np.array([np.inf]), np.zeros(0, dtype=int), wall)
    if result.breakpoints is not None:  # automatic slabs: the accepted steps
        t = problem.time_coordinate
        bp = result.breakpoints.copy()
        bp[0], bp[-1] = t.domain
        k = names.index(t.name)
        coords[k] = CoordinateInfo(t.name, tuple(t.domain), len(result.states), t.discretization, t.role,
                                   tuple(float(v) for v in bp))
        # the codebook's basis puts the nodes where the march stored the states
        assert np.allclose(coords[k].basis().nodes, result.times, rtol=0, atol=1e-12 * max(1.0, abs(bp[-1])))
    fields = {}
    st_delta = SPACE_TIME_FRACTION * tolerance * np.sqrt(float(np.prod(system.shape)))
    # one unknown at a time: batching would give every unknown the largest ranks of all
    stats = result.roundings
    trains = join_and_round([[st[i] for st in result.states] for i in range(len(system.unknowns))], st_delta,
                            np.random.default_rng(7), batched=False,
                            stats=stats)
    for u, train in zip(system.unknowns, trains):
        cores = train.cores
        if single:  # fold the virtual one-node mode into the time core
            cores = (np.tensordot(cores[0], cores[1][:, 0, :], axes=(2, 0)),)
        fields[u] = FieldTT(cores, order)
    estimate = result.error_estimate + SPACE_TIME_FRACTION * tolerance  # + the space-time rounding
    message = (f"converged: reached t = {system.time_basis.nodes[-1]:.6g} in {result.steps} steps "
               f"({result.rejected} rejected), error estimate {estimate:.3g} (tolerance {tolerance:.3g})")
    ranks = np.array([[list(r) for r in node] for node in result.ranks], dtype=int)
    report = {
        "converged": True,
        "status": 0,
        "message": message,
        "method": "march",
        "modes": int(max(f.rank for f in fields.values())),
        "residual": float(estimate),
        "error_estimate": float(estimate),
        "tolerance": float(tolerance),
        "steps": int(result.steps),
        "rejected_steps": int(result.rejected),
        "step_sizes": np.array(result.step_sizes),
        "node_ranks": ranks,  # (time nodes, unknowns, bonds)
        # tensor-train roundings: exact (QR + SVD of the explicit sum), randomized (sketched), and the
        # sketches redone with twice the size because the rounded rank came too close to the sketch's
        "roundings_exact": int(stats.get("exact", 0)),
        "roundings_sketched": int(stats.get("sketched", 0)),
        "roundings_redone": int(stats.get("redone", 0)),
        # stage roundings made 10x tighter because their noise, not the step, set the error estimate
        "stage_tightenings": int(stats.get("stage_tightenings", 0)),
        "max_rank": int(opts.max_rank),
        "wall_time": wall,
        "pgdcli_version": __version__,
        **report_entries(stats),
    }
    if separations:  # how many terms each non-separable coefficient needed
        report["separated_coefficients"] = separation_report_text(separations)
    cb = Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                  description=problem.description)
    return SolveResult(cb, True, 0, message, np.array([estimate]), np.zeros(0, dtype=int), wall)

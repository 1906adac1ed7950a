"""PGD solver for linear parametric initial-value problems (the seed paper's Algorithm 1).

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

Algorithm (free functions below):

1. :func:`enrich` finds a rank-one term by an alternating-directions fixed
   point, solving for one mode with the others frozen. ``minres`` minimizes the
   residual norm (always a descent, never stalls); ``galerkin`` is the paper's
   Galerkin condition (eq. 12).
2. :func:`project_alphas` recomputes every weight (eq. 15 for Galerkin, a
   least-squares problem for minres, solved through an orthogonal sweep).
3. :func:`update_mode` optionally re-solves all modes of one coordinate jointly,
   which keeps the rank low. With updates (minres), every coordinate is updated
   after each enrichment and the residual checked once (:func:`_update_all`): the
   first update re-fits all weights, which does step 2's job. Should the residual
   not have fallen, the careful path is taken: step 2, then updates kept one by
   one only if they lower the residual, each checked with one more step of the
   projection's sweep (:func:`_update_sweep`).
4. The relative residual (eq. 16) is computed in separated form by orthogonal
   sweeps (:func:`pgdcli.tensors.cp.separated_norm`), accurate to rounding.
"""

from __future__ import annotations

import math
import time as _time
import warnings
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Callable

import numpy as np
import scipy.linalg

from .discretization.basis import Basis1D
from .errors import PgdError, SolverError
from .problem.general import has_general
from .discretization.coefficients import SEPARATION_FRACTION, nodal_terms, separation_report_text
from .discretization.separate import MAX_SEPARATION_RANK
from .tensors.cp import CPTensor, SeparatedOperator, khatri_rao_rows, separated_norm, sweep_order, sweep_step

if TYPE_CHECKING:  # annotations only
    from .checks.check import CheckResult

__all__ = ["SolveResult", "Discretization", "discretize", "solve", "enrich", "project_alphas", "residual_norm"]

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


def coordinate_infos(problem, *, march: bool):
    """The codebook coordinates of a problem, the time coordinate's slabs resolved.

    ``solver.time_slabs``: an integer N splits a Chebyshev time coordinate into N equal
    slabs of ``nodes`` nodes each; ``auto`` is one slab for the enrichment solver, and for
    the march one slab per accepted step (the provisional single slab returned here is
    replaced once the steps are known).
    """
    from .codebook.codebook import CoordinateInfo

    slabs = getattr(problem.solver, "time_slabs", 1)
    out = []
    for c in problem.coordinates:
        info = CoordinateInfo(c.name, tuple(c.domain), c.nodes, c.discretization, c.role)
        if len(c.breakpoints) > 2:  # elements: c.nodes per element
            elements = len(c.breakpoints) - 1
            info = CoordinateInfo(c.name, tuple(c.domain), elements * (c.nodes - 1) + 1, c.discretization, c.role,
                                  tuple(c.breakpoints))
        if c.name == problem.time and isinstance(slabs, int) and slabs > 1:
            if c.discretization != "chebyshev":
                raise SolverError(f"{problem.source}: solver.time_slabs: slabs need a chebyshev time coordinate, "
                                  f"{c.name!r} is {c.discretization}")
            breakpoints = tuple(np.linspace(c.domain[0], c.domain[1], slabs + 1))
            info = CoordinateInfo(c.name, tuple(c.domain), slabs * (c.nodes - 1) + 1, c.discretization, c.role,
                                  breakpoints)
        out.append(info)
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


class _CoordinateOps:
    """The 1D pieces of one non-time coordinate: test/trial nodes, matrices, left preconditioner.

    Parameters are collocated (diagonal matrices). Space coordinates are in weak form with
    the basis's quadrature: mass ``W``, stiffness ``K`` (Chebyshev ``D^T W D``; linear
    elements the exact tridiagonal one), advection ``int f phi_i phi_j'`` (Chebyshev: exact
    Gauss-Legendre; linear elements: f at the element midpoints); a Dirichlet
    end drops its node from the trial and test functions (the lift carries the value), a
    gradient (Neumann) end enters as a boundary flux. Every matrix is returned already
    multiplied by the left preconditioner: ``1/sqrt(w)`` for parameters, and
    ``sqrt(W) (M + tau K)^-1`` for space, which keeps the stiff operator bounded in the
    minimal-residual normal equations (their conditioning is squared).
    """

    def __init__(self, name: str, basis: Basis1D, role: str, ends: tuple[str, str] | None, tau: float):
        self.name, self.basis = name, basis
        n = basis.nodes.size
        w = basis.weights
        self.space = role == "space"
        keep = np.ones(n, dtype=bool)
        if self.space and ends is not None:
            keep[0] = ends[0] != "value"
            keep[-1] = ends[1] != "value"
        self.test = self.trial = np.flatnonzero(keep)
        self.w = w
        self.interp = None
        if not self.space:
            self.left = np.diag(1.0 / np.sqrt(w))
            return
        if basis.kind == "chebyshev":
            # exact Galerkin integrals: Gauss-Legendre with n + 1 points integrates the products
            # of two degree n - 1 polynomials exactly (Clenshaw-Curtis at the nodes would alias
            # and converge only algebraically, measured)
            xg, wg = np.polynomial.legendre.leggauss(n + 1)
            low, high = basis.domain
            self.quad_w = wg * (high - low) / 2.0
            self.interp = basis.interpolation_matrix(low + (xg + 1.0) * (high - low) / 2.0)  # (n + 1, n)
            self.interp_d = self.interp @ basis.derivative
            self.derivative = basis.derivative
            self.stiffness = self.interp_d.T @ (self.quad_w[:, None] * self.interp_d)
            mass = self.interp.T @ (self.quad_w[:, None] * self.interp)
        else:
            h = np.diff(basis.nodes)
            k = np.zeros((n, n))
            for e, he in enumerate(h):
                k[e:e + 2, e:e + 2] += np.array([[1.0, -1.0], [-1.0, 1.0]]) / he
            self.derivative = None
            self.interp = None
            self.stiffness = k
            self.h = h
            mass = np.diag(w)  # lumped: second order, like the elements themselves
        t = self.test
        self.left = np.sqrt(w[t])[:, None] * np.linalg.inv(mass[np.ix_(t, t)] + tau * self.stiffness[np.ix_(t, t)])

    def _rows(self, full: np.ndarray) -> np.ndarray:
        return self.left @ full[self.test]

    def _weighted(self, f: np.ndarray) -> np.ndarray:
        """Quadrature weights times ``f`` at the quadrature points (f interpolated from the nodes)."""
        return self.quad_w * (self.interp @ f)

    def mass(self, f: np.ndarray) -> np.ndarray:
        """``f u`` tested: (test, all nodes)."""
        if not self.space or self.interp is None:
            return self._rows(np.diag(self.w * f))
        return self._rows(self.interp.T @ (self._weighted(f)[:, None] * self.interp))

    def first(self, f: np.ndarray) -> np.ndarray:
        """``f du/dx`` tested: (test, all nodes)."""
        if self.derivative is not None:
            return self._rows(self.interp.T @ (self._weighted(f)[:, None] * self.interp_d))
        # hat functions: on element e, phi_j' = -+1/h and int phi_i = h/2, with f at the midpoint
        n = self.basis.nodes.size
        mid = 0.5 * (f[:-1] + f[1:])
        a = np.zeros((n, n))
        for e, fe in enumerate(mid):
            a[e:e + 2, e:e + 2] += 0.5 * fe * np.array([[-1.0, 1.0], [-1.0, 1.0]])
        return self._rows(a)

    def second(self, f: np.ndarray) -> np.ndarray:
        """``f d2u/dx2`` tested (weak form, boundary fluxes apart): (test, all nodes).

        ``int f u'' phi = [f u' phi] - int f u' phi' - int f' u' phi``: a stiffness weighted by
        ``f`` and an advection by ``f'`` (Chebyshev: the derivative of f's interpolant, both
        integrals by the Gauss rule; linear elements: f at the element midpoints, f' the slope
        of f on each element, second order).
        """
        if self.derivative is not None:
            stiffness = self.interp_d.T @ (self._weighted(f)[:, None] * self.interp_d)
            return self._rows(-stiffness) - self.first(self.derivative @ f)
        n = self.basis.nodes.size
        k = np.zeros((n, n))
        a = np.zeros((n, n))
        for e, he in enumerate(self.h):
            k[e:e + 2, e:e + 2] += 0.5 * (f[e] + f[e + 1]) * np.array([[1.0, -1.0], [-1.0, 1.0]]) / he
            a[e:e + 2, e:e + 2] += 0.5 * (f[e + 1] - f[e]) / he * np.array([[-1.0, 1.0], [-1.0, 1.0]])
        return self._rows(-k - a)

    def load(self, f: np.ndarray) -> np.ndarray:
        """A source ``f`` tested: (test,)."""
        if not self.space or self.interp is None:
            return self.left @ (self.w * f)[self.test]
        return self.left @ (self.interp.T @ self._weighted(f))[self.test]

    def flux(self, side: int) -> np.ndarray:
        """``[du/dx phi]`` at one end: +phi(high), -phi(low), tested: (test,)."""
        e = np.zeros(self.basis.nodes.size)
        e[0 if side == 0 else -1] = -1.0 if side == 0 else 1.0
        return self.left @ e[self.test]


def _boundary_kinds(problem, coord: str) -> tuple[str, str] | None:
    kinds = {tuple(b.kind for b in u.boundary[coord]) for u in problem.unknowns if coord in u.boundary}
    if len(kinds) > 1:
        raise SolverError(f"{problem.source}: unknowns: every unknown needs the same kinds of boundary conditions "
                          f"on {coord!r} (value or gradient at each end), found {sorted(kinds)}")
    return kinds.pop() if kinds else None


def _check_compatible_initial_values(problem, bases) -> None:
    """A Dirichlet value must equal the initial value there: the lift u0 carries it for all times."""
    rng = np.random.default_rng(0)
    for u in problem.unknowns:
        for coord, ends in u.boundary.items():
            for side, bc in enumerate(ends):
                if bc.kind != "value":
                    continue
                others = {c.name: rng.uniform(*c.domain, 16) for c in problem.coordinates
                          if c.name not in (coord, problem.time)}
                at = {**others, coord: np.full(16, problem.coordinate(coord).domain[side])}
                initial = np.broadcast_to(u.initial.evaluate(**at), (16,)) if u.initial.terms else np.zeros(16)
                value = np.broadcast_to(bc.value.evaluate(**others), (16,)) if bc.value.terms else np.zeros(16)
                scale = max(1.0, float(np.max(np.abs(value))))
                if np.max(np.abs(initial - value)) > 1e-9 * scale:
                    end = ("low", "high")[side]
                    raise SolverError(
                        f"{problem.source}: unknowns.{u.name}: the initial value '{u.initial_text}' does not satisfy "
                        f"the boundary condition {coord} {end} = '{bc.text}' (they must agree at t = "
                        f"{problem.time_coordinate.domain[0]:g})")


class _TimeOps:
    """The time direction of the state mode: free nodes, the d/dt and mass rows, preconditioned.

    The rows are multiplied by ``sqrt(weights) (d/dt)^-1``, so the residual is the L2 norm of
    the time-integrated equation (see the module docstring).
    """

    def __init__(self, basis: Basis1D):
        self.basis = basis
        nt = basis.nodes.size
        self.size = nt - 1  # v(t0) = 0: the first node is not free
        integrate = np.linalg.inv(basis.time_stiffness(np.ones(nt))[:, 1:])
        self.left = np.sqrt(basis.time_weights())[:, None] * integrate

    def operator(self, values: np.ndarray, is_der: bool) -> np.ndarray:
        """``c(t) du/dt`` or ``c(t) u`` on the free nodes: (size, size)."""
        full = self.basis.time_stiffness(values) if is_der else self.basis.time_mass(values)
        return self.left @ full[:, 1:]

    def load(self, values: np.ndarray) -> np.ndarray:
        """A source ``f(t)``: (size,)."""
        return self.left @ self.basis.time_load(values)

    def constant(self, values: np.ndarray) -> np.ndarray:
        """``c(t) w`` for a ``w`` constant in time (the lift): (size,)."""
        return self.left @ (self.basis.time_mass(values) @ np.ones(self.basis.nodes.size))


class _SteadyOps:
    """The time direction of a steady problem: none (one entry per unknown, no weight)."""

    size = 1

    def operator(self, values, is_der: bool) -> np.ndarray:
        return np.ones((1, 1))

    def load(self, values) -> np.ndarray:
        return np.ones(1)

    constant = load


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


def discretize(problem, *, tolerance: float | None = None) -> Discretization:
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

    Returns
    -------
    Discretization
    """
    coords = list(problem.coordinates)
    tname = problem.time
    unknowns = [u.name for u in problem.unknowns]
    q = len(unknowns)
    index = {name: s for s, name in enumerate(unknowns)}
    bases = {info.name: info.basis() for info in coordinate_infos(problem, march=False)}
    nodes = {c: b.nodes for c, b in bases.items()}
    delta = SEPARATION_FRACTION * (problem.solver.tolerance if tolerance is None else tolerance)
    separations: list = []
    cap = min(MAX_SEPARATION_RANK, problem.solver.max_rank)
    params = [c.name for c in coords if c.name != tname]
    names = [STATE] + params
    if tname is None:
        time = _SteadyOps()
        # tau = L^2 makes (M + tau K)^-1 K bounded above and below in each space coordinate,
        # so the residual tracks the error (there is no time integration to do it)
        tau = {c.name: (c.domain[1] - c.domain[0]) ** 2 for c in coords}
        lifts = {u.name: _dirichlet_lift(u, bases) for u in problem.unknowns}
    else:
        time = _TimeOps(bases[tname])
        span = float(bases[tname].nodes[-1] - bases[tname].nodes[0])
        tau = {c.name: span * TAU_FRACTION for c in coords}
        _check_compatible_initial_values(problem, bases)
        lifts = {u.name: _initial_lift(u, bases, delta, separations, problem.source) for u in problem.unknowns}
    ops = {c: _CoordinateOps(c, bases[c], problem.coordinate(c).role, _boundary_kinds(problem, c), tau[c])
           for c in params}

    def unit(r: int) -> np.ndarray:
        e = np.zeros(q)
        e[r] = 1.0
        return e

    def time_values(vals: dict[str, np.ndarray]):
        return None if tname is None else vals[tname]

    op_terms: list[tuple[np.ndarray, ...]] = []
    src_w: list[float] = []
    src_f: list[list[np.ndarray]] = []

    def add_source(r: int, coef: float, time_vec: np.ndarray, vectors: dict[str, np.ndarray]):
        src_w.append(coef)
        src_f.append([np.kron(unit(r), time_vec)] + [vectors[c] for c in params])

    def tested_values(vals: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
        return {c: ops[c].load(vals[c]) for c in params}

    for eq in problem.equations:
        r = eq.index
        for monomial, sep in eq.polynomial.items():
            terms = nodal_terms(sep, nodes, delta, where=f"{problem.source}: equations[{r}]: ", reports=separations,
                                max_rank=cap)
            if len(monomial) == 0:
                for coef, vals in terms:
                    add_source(r, -coef, time.load(time_values(vals)), tested_values(vals))
                continue
            if len(monomial) != 1:
                raise SolverError(f"equations[{r}]: nonlinear term; the linear solver needs equations linear in the unknowns")
            atom = monomial[0]
            s = index[atom.unknown]
            is_der = atom.order == 1 and atom.coordinate == tname
            space_der = atom.order > 0 and atom.coordinate != tname
            for term_coef, vals in terms:
                coupling = np.zeros((q, q))
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
                op_terms.append((np.kron(coupling, time.operator(time_values(vals), is_der)),)
                                + tuple(full[c][:, ops[c].trial] for c in params))
                if not is_der:
                    # the lift (constant in time) moves to the right-hand side
                    for coef, lvals in lifts[atom.unknown]:
                        add_source(r, -term_coef * coef, time.constant(time_values(vals)),
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
                            add_source(r, -term_coef * g.coef, time.constant(time_values(vals)), vectors)

    if not op_terms:
        raise SolverError("the equations have no term in the unknowns")
    op_terms = _merge_terms(op_terms)
    sizes = [m.shape[0] for m in op_terms[0]]
    source = CPTensor(np.array(src_w), [np.column_stack([f[j] for f in src_f]) if src_f else np.zeros((sizes[j], 0))
                                        for j in range(len(names))])
    lift = {}
    for u in unknowns:
        ws = [coef for coef, _ in lifts[u]]
        lift[u] = CPTensor(
            np.array(ws), [np.column_stack([vals[c.name] for _, vals in lifts[u]]) if ws
                           else np.zeros((bases[c.name].nodes.size, 0)) for c in coords])
    trial = {c: ops[c].trial for c in params if ops[c].trial.size != bases[c].nodes.size}
    return Discretization(names, bases, SeparatedOperator(tuple(op_terms)), source, lift, unknowns,
                          [c.name for c in coords], tname, trial, separations)


# ----------------------------------------------------------------------------------------------
# the algorithm
# ----------------------------------------------------------------------------------------------
@dataclass
class _State:
    """Current approximation ``U = sum_i alpha_i (x)_j U_j[:, i]`` and its images ``A_k U``."""

    op: SeparatedOperator
    source: CPTensor
    alphas: np.ndarray
    factors: list[np.ndarray]
    images: list[np.ndarray]  # images[j]: (K, m_j, n) = A_kj @ U_j
    # mode -> (images^T images, images^T source factors), until that mode changes (update_mode
    # needs them for every other mode, d - 1 times per update sweep)
    _products: dict = field(default_factory=dict, repr=False)
    # mode -> its update's block-Jacobi inverses, kept from one update sweep to the next
    preconditioners: dict = field(default_factory=dict, repr=False)

    @classmethod
    def empty(cls, op: SeparatedOperator, source: CPTensor) -> "_State":
        sizes = [op.terms[0][j].shape for j in range(op.order)]
        return cls(
            op,
            source,
            np.zeros(0),
            [np.zeros((n, 0)) for _, n in sizes],
            [np.zeros((op.n_terms, m, 0)) for m, _ in sizes],
        )

    @property
    def rank(self) -> int:
        return self.alphas.size

    def append(self, columns: list[np.ndarray], alpha: float) -> None:
        self._products.clear()
        self.alphas = np.append(self.alphas, alpha)
        for j, col in enumerate(columns):
            self.factors[j] = np.column_stack([self.factors[j], col])
            stack = self.op.mode_stack(j)
            image = (stack.reshape(-1, stack.shape[2]) @ col).reshape(stack.shape[0], -1)
            self.images[j] = np.concatenate([self.images[j], image[:, :, None]], axis=2)

    def set_mode(self, j: int, factor: np.ndarray, image: np.ndarray | None = None) -> None:
        """Replace the factors of mode ``j`` (and their images, computed unless given)."""
        self._products.pop(j, None)
        self.factors[j] = factor
        if image is not None:
            self.images[j] = image
            return
        stack = self.op.mode_stack(j)
        self.images[j] = (stack.reshape(-1, stack.shape[2]) @ factor).reshape(stack.shape[0], stack.shape[1], -1)

    def residual_weights(self) -> np.ndarray:
        """Weights of ``F - A U``, shape (nF + K n,): the source's, then ``-alphas`` per operator term."""
        return np.concatenate([self.source.weights, -np.tile(self.alphas, self.op.n_terms)])

    def residual_columns(self, j: int) -> np.ndarray:
        """Mode ``j`` factors of ``F - A U``, shape (m_j, nF + K n): source columns, then images term-major."""
        image = self.images[j]
        return np.hstack([self.source.factors[j], image.transpose(1, 0, 2).reshape(image.shape[1], -1)])

    def residual(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """``F - A U`` as weights (C,) and factors (m_j, C); source columns first."""
        return self.residual_weights(), [self.residual_columns(j) for j in range(self.op.order)]

    def residual_norm(self) -> float:
        """``||F - A U||`` by an orthogonal sweep, accurate to rounding."""
        return separated_norm(*self.residual())

    def snapshot(self) -> tuple:
        """A copy of the weights, factors and images, for :meth:`restore`."""
        return self.alphas.copy(), [f.copy() for f in self.factors], [m.copy() for m in self.images]

    def restore(self, snapshot: tuple) -> None:
        self._products.clear()
        alphas, factors, images = snapshot
        self.alphas, self.factors, self.images = alphas, factors, images

    def image_products(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Gram matrix of mode ``m``'s images, shape (K n, K n), and their products with the
        source's factors, shape (K n, nF); rows and columns term-major."""
        if m not in self._products:
            img = self.images[m].transpose(1, 0, 2).reshape(self.images[m].shape[1], -1)  # (m_m, K n)
            self._products[m] = (img.T @ img, img.T @ self.source.factors[m])
        return self._products[m]


def enrich(
    op: SeparatedOperator,
    res_w: np.ndarray,
    res_f: list[np.ndarray],
    *,
    formulation: str = "minres",
    tolerance: float = 1e-8,
    max_iterations: int = 30,
    start: list[np.ndarray] | None = None,
) -> tuple[list[np.ndarray], int]:
    """Rank-one correction ``R_1 (x) ... (x) R_d`` of the residual by alternating directions.

    Parameters
    ----------
    op : SeparatedOperator
        ``K`` terms, ``d`` modes.
    res_w : ndarray, shape (C,)
    res_f : list of ndarray, each shape (m_j, C)
        The current residual ``r`` in separated form.
    formulation : {'minres', 'galerkin'}
        ``minres`` minimizes ``||A R - r||`` over each factor in turn;
        ``galerkin`` imposes ``<A R - r, R*> = 0`` (the paper's eq. 12).
    tolerance : float
        Stop when the relative change of the rank-one tensor is below this.
    max_iterations : int
    start : list of ndarray, optional
        Initial factors.

    Returns
    -------
    factors : list of ndarray, each shape (n_j,)
    iterations : int
    """
    d, K, C = op.order, op.n_terms, res_w.size
    stacks = [op.mode_stack(j) for j in range(d)]
    # the factors are views into one vector: the fixed point's change is then a few array operations
    offsets = np.cumsum([0] + [s.shape[2] for s in stacks[:-1]])
    flat = np.concatenate([(np.ones(s.shape[2]) if start is None else np.asarray(start[j], dtype=float))
                           for j, s in enumerate(stacks)])
    R = np.split(flat, offsets[1:])
    for r in R:
        r /= np.linalg.norm(r)
    if formulation == "minres":
        # flattened once so that each step is a few matrix products (the systems are tiny and
        # solved thousands of times per build: einsum's per-call cost would dominate)
        rows = [s.reshape(-1, s.shape[2]) for s in stacks]  # (K m_j, n_j): the A_kj stacked
        gram_ops = [op.mode_gram(j).reshape(K * K, -1) for j in range(d)]  # A_kj^T A_lj, (K K, n_j n_j)
        # A_kj^T applied to every residual column, rows (k, c): H_j = <A_kj R_j, res_c> is Y_j R_j
        Y = [(s.transpose(0, 2, 1) @ f).transpose(0, 2, 1).reshape(-1, s.shape[2]) for s, f in zip(stacks, res_f)]
        V = [(rows[j] @ R[j]).reshape(K, -1) for j in range(d)]
        # G[j] = (A_kj R_j . A_lj R_j), H[j] = (A_kj R_j . res_c); stacked with one more slot
        # (ones, the residual's weights) so that the products over the modes after j are one
        # cumulative product per pass
        G, H = np.empty((d + 1, K, K)), np.empty((d + 1, K, C))
        for j in range(d):
            G[j], H[j] = V[j] @ V[j].T, (Y[j] @ R[j]).reshape(K, -1)
    else:
        # G[j] = (R_j . A_kj R_j), H[j] = (R_j . res_c), stacked likewise
        G, H = np.empty((d + 1, K)), np.empty((d + 1, C))
        for j in range(d):
            G[j], H[j] = np.einsum("a,kab,b->k", R[j], stacks[j], R[j]), R[j] @ res_f[j]
    G[d], H[d] = 1.0, res_w

    iterations = 0
    for iterations in range(1, max_iterations + 1):
        previous = flat.copy()
        # products over the other modes: the modes before j (already updated in this pass)
        # times the modes after j (from the previous pass; the residual's weights included)
        after_G = np.cumprod(G[::-1], axis=0)[::-1]
        after_H = np.cumprod(H[::-1], axis=0)[::-1]
        before_G = before_H = 1.0
        for j in range(d):
            c = before_G * after_G[j + 1]  # (K, K) or (K,)
            h = before_H * after_H[j + 1]  # (K, C) or (C,)
            if formulation == "minres":
                n_j = R[j].size
                M = (c.reshape(-1) @ gram_ops[j]).reshape(n_j, n_j)
                R[j][:] = _solve_small(M, h.reshape(-1) @ Y[j], symmetric=True)
                V[j] = (rows[j] @ R[j]).reshape(K, -1)
                G[j], H[j] = V[j] @ V[j].T, (Y[j] @ R[j]).reshape(K, -1)
            else:
                M = np.einsum("k,kab->ab", c, stacks[j])
                R[j][:] = _solve_small(M, res_f[j] @ h, symmetric=False)
                G[j], H[j] = np.einsum("a,kab,b->k", R[j], stacks[j], R[j]), R[j] @ res_f[j]
            before_G = before_G * G[j]
            before_H = before_H * H[j]
        if _relative_change(previous, flat, offsets) < tolerance:
            break
    return R, iterations


_POSV, _GESV = scipy.linalg.get_lapack_funcs(("posv", "gesv"), dtype=np.float64)


def _solve_small(M: np.ndarray, b: np.ndarray, *, symmetric: bool) -> np.ndarray:
    """Solve ``M x = b``, shape (n, n) and (n,): Cholesky if ``symmetric``, else LU; least squares on failure.

    LAPACK is called directly: these systems are tiny and solved thousands of
    times per build, where ``scipy.linalg.solve``'s checks and condition
    estimate cost ten times the factorization. Normal equations of nearly
    dependent modes are ill-conditioned by nature (the caller checks that the
    residual decreases); only a failed factorization (not positive definite,
    exactly singular) falls back to least squares.
    """
    if symmetric:
        _, x, info = _POSV(M, b)
    else:
        _, _, x, info = _GESV(M, b)
    if info == 0:
        return x
    return np.linalg.lstsq(M, b, rcond=None)[0]


def _relative_change(old: np.ndarray, new: np.ndarray, offsets: np.ndarray) -> float:
    """``||x_old - x_new|| / ||x_new||`` for rank-one tensors, from their factors.

    ``old`` and ``new`` hold the factors end to end, mode ``j`` from ``offsets[j]``.
    """
    n_old = math.prod(np.add.reduceat(old * old, offsets).tolist())
    n_new = math.prod(np.add.reduceat(new * new, offsets).tolist())
    cross = math.prod(np.add.reduceat(old * new, offsets).tolist())
    if n_new == 0.0:
        return 0.0 if n_old == 0.0 else np.inf
    return math.sqrt(max(n_old + n_new - 2.0 * cross, 0.0) / n_new)


def project_alphas(state: _State, formulation: str = "minres") -> tuple[np.ndarray, float, float]:
    """Recompute all weights (the projection step) and the residual norm.

    Returns
    -------
    alphas : ndarray, shape (n,)
    residual : float
        ``||F - A U||`` with the new weights.
    source_norm : float
        ``||F||``.
    """
    alphas, residual, source_norm, _ = _project(state, formulation)
    return alphas, residual, source_norm


def _update_order(state: _State) -> list[int]:
    """Modes in the order the update sweep visits them: smallest first.

    The projection's sweep runs the other way (largest first, the cheap order
    of :func:`~pgdcli.tensors.cp.sweep_order`), so its partial results are the
    suffixes the update sweep needs (:func:`_suffix_sweeps`).
    """
    return sweep_order([state.images[j].shape[1] for j in range(state.op.order)])[::-1]


def _suffix_sweeps(columns: list[np.ndarray], order: list[int]) -> list[np.ndarray | None]:
    """Orthogonal sweeps over the trailing modes of ``order``.

    Parameters
    ----------
    columns : list of ndarray, each shape (m_j, C)
        Factor matrices of the residual terms.
    order : list of int
        A permutation of the modes.

    Returns
    -------
    list of length d + 1
        Entry ``i`` is the sweep over the modes ``order[i:]`` (shape (r_i, C),
        visiting ``order[-1]`` first); entry 0 covers every mode, entry d is None.
        They do not depend on the weights.
    """
    out: list[np.ndarray | None] = [None] * (len(order) + 1)
    for i in range(len(order) - 1, -1, -1):
        out[i] = sweep_step(out[i + 1], columns[order[i]])
    return out


def _project(state: _State, formulation: str) -> tuple[np.ndarray, float, float, list]:
    """:func:`project_alphas`, also returning the suffix sweeps of :func:`_update_order`."""
    K, n, nF = state.op.n_terms, state.rank, state.source.rank
    suffixes = _suffix_sweeps([state.residual_columns(j) for j in range(state.op.order)], _update_order(state))
    Z = suffixes[0]
    zF = Z[:, :nF] @ state.source.weights
    phi = Z[:, nF:].reshape(Z.shape[0], K, n).sum(axis=1)
    if formulation == "minres":
        alphas = np.linalg.lstsq(phi, zF, rcond=None)[0]
    else:
        alphas = _galerkin_alphas(state)
    return alphas, float(np.linalg.norm(zF - phi @ alphas)), float(np.linalg.norm(zF)), suffixes


def _galerkin_alphas(state: _State) -> np.ndarray:
    """Paper's eq. (15): ``B alpha = H`` with ``B_il = <U_i, A U_l>``, ``H_i = <U_i, F>``."""
    d = state.op.order
    B = None
    Hv = None
    for j in range(d):
        u = state.factors[j]
        bj = np.einsum("ai,kal->kil", u, state.images[j])
        hj = u.T @ state.source.factors[j]
        B = bj if B is None else B * bj
        Hv = hj if Hv is None else Hv * hj
    return _solve_small(B.sum(axis=0), Hv @ state.source.weights, symmetric=False)


def residual_norm(op: SeparatedOperator, source: CPTensor, approx: CPTensor) -> float:
    """``||F - A U||`` in separated form (orthogonal sweep), never forming a full tensor."""
    return (source + op.apply(approx).scaled(-1.0)).norm()


# The update's conjugate gradients stop after CG_ITERATIONS steps, or once the preconditioned
# residual has fallen by CG_RTOL: the fixed point repeats the update after every enrichment, so
# inexact solves suffice. Measured on the shipped problems (heat2d, spring, relaxation,
# heat2d_source): 40 steps and rtol 0 give the same modes and residuals (within one or two modes)
# for up to 1.4x the build time.
CG_ITERATIONS = 10
CG_RTOL = 1e-4


def update_mode(state: _State, j: int, *, cg_iterations: int = CG_ITERATIONS, cg_rtol: float = CG_RTOL) -> None:
    """Re-solve all factors of mode ``j`` jointly (minres), the others frozen.

    Minimizes ``||F - sum_i alpha_i A (x)_m U_im||`` over ``U_j`` (``n_j * n``
    unknowns) through its normal equations; the new columns are normalized
    into the weights. Called after an enrichment, it lets earlier modes adapt
    to later ones, which keeps the rank low. When every operator matrix of
    the mode is diagonal (parameter coordinates) the normal equations split
    into ``n_j`` independent ``n x n`` systems, one per node, solved exactly.
    Otherwise (the state mode, dense in time) the ``n n_j`` normal equations
    are a sum of ``K^2`` Kronecker products: a direct solve would cost
    ``(n n_j)^3``, so a few block-Jacobi preconditioned conjugate-gradient
    steps are taken from the current factors instead (at most ``cg_iterations``,
    fewer once the preconditioned residual has fallen by ``cg_rtol``). CG
    decreases the least-squares objective monotonically, so every step is an
    improvement.
    """
    op, K, n = state.op, state.op.n_terms, state.rank
    stack = op.mode_stack(j)
    a = state.alphas
    T = np.ones((K, n, K, n))
    rhs_c = np.ones((K, n, state.source.rank))
    for m in range(op.order):
        if m == j:
            continue
        gram, cross = state.image_products(m)
        T *= gram.reshape(K, n, K, n)
        rhs_c *= cross.reshape(K, n, -1)
    T *= a[None, :, None, None] * a[None, None, None, :]
    # (einsum contractions written as matrix products: these run thousands of times per build)
    W = ((rhs_c * state.source.weights).reshape(K * n, -1) @ state.source.factors[j].T).reshape(K, n, -1)  # (K, n, m_j)
    if op.mode_is_diagonal(j):
        diag = np.einsum("kaa->ka", stack)  # (K, n_j)
        pairs = (diag[:, None, :] * diag[None, :, :]).reshape(K * K, -1)  # [(k, l), a]
        N = (pairs.T @ T.transpose(0, 2, 1, 3).reshape(K * K, n * n)).reshape(-1, n, n)  # (n_j, n, n)
        rhs = np.einsum("ka,kia->ai", diag, W) * a[None, :]
        X = _solve_batched(N, rhs)  # (n_j, n)
    else:
        gram = op.mode_gram(j)
        rhs = (W.transpose(1, 0, 2).reshape(n, -1) @ stack.reshape(-1, stack.shape[2])) * a[:, None]  # (n, n_j)
        invert = state.preconditioners.setdefault(j, _KeptBlockInverses())
        X = _kronecker_pcg(T, gram, rhs, state.factors[j].T, iterations=cg_iterations,
                           rtol=cg_rtol, invert=invert).T  # (n_j, n)
    norms = np.linalg.norm(X, axis=0)
    keep = norms > 0
    X[:, keep] /= norms[keep]
    state.alphas = np.where(keep, a * norms, 0.0)
    state.set_mode(j, X)


def _kronecker_pcg(T: np.ndarray, G: np.ndarray, B: np.ndarray, X: np.ndarray, *, iterations: int,
                   rtol: float = 0.0, invert: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Approximately solve ``sum_kl T_kl X G_kl^T = B`` for X, shape (n, m), by PCG.

    ``T`` has shape (K, n, K, n) (``T_kl = T[k, :, l, :]``), ``G`` shape (K, K, m, m);
    the operator is SPD (normal equations). Block-Jacobi preconditioner: one
    ``m x m`` block per row of X, inverted by ``invert`` (blocks (n, m, m) ->
    inverses; default :func:`_inverse_spd_blocks`). Stops after ``iterations``
    steps, or once the preconditioned residual norm has fallen by ``rtol``.
    """
    K, n, m = T.shape[0], T.shape[1], G.shape[2]
    # the operator as two matrix products (einsum would loop in C without BLAS)
    T_rows = T.transpose(1, 0, 2, 3).reshape(n, K * K * n)  # [i, (k, l, p)]
    G_t = np.ascontiguousarray(G.transpose(0, 1, 3, 2))  # [k, l, b, a]

    def apply(Y):
        return T_rows @ np.matmul(Y, G_t).reshape(K * K * n, m)

    diag_T = np.einsum("kili->kli", T).reshape(K * K, n)
    blocks = (diag_T.T @ G.reshape(K * K, m * m)).reshape(n, m, m)
    inv_blocks = (invert or _inverse_spd_blocks)(blocks)

    def precond(R):
        return np.matmul(inv_blocks, R[:, :, None])[:, :, 0]

    X = X.copy()
    R = B - apply(X)
    Zr = precond(R)
    Pd = Zr.copy()
    rz = np.vdot(R, Zr)
    stop = rtol**2 * rz
    for _ in range(iterations):
        if rz <= stop or rz <= 0.0:
            break
        Q = apply(Pd)
        pq = np.vdot(Pd, Q)
        if pq <= 0.0:
            break
        step = rz / pq
        X += step * Pd
        R -= step * Q
        Zr = precond(R)
        rz_new = np.vdot(R, Zr)
        Pd = Zr + (rz_new / rz) * Pd
        rz = rz_new
    return X


class _KeptBlockInverses:
    """Block-Jacobi inverses of one mode's update, kept from one update sweep to the next.

    Block ``i`` is ``alpha_i^2`` times a matrix that changes little between sweeps once
    term ``i`` has settled: a kept inverse is rescaled by the ratio of the blocks' traces,
    and only the blocks of new terms are inverted (all of them every ``REFRESH`` calls).
    Measured on heat2d, spring and relaxation: the same modes, the inverses' cost (about
    a tenth of a build) mostly gone. It is only a preconditioner: PCG stays exact.
    """

    REFRESH = 8

    def __init__(self):
        self.inverses: np.ndarray | None = None  # (n, m, m)
        self.traces: np.ndarray | None = None  # (n,): traces of the blocks they invert
        self.age = 0

    def __call__(self, blocks: np.ndarray) -> np.ndarray:
        traces = np.einsum("iaa->i", blocks)
        kept = self.inverses
        if (kept is None or kept.shape[0] > blocks.shape[0] or kept.shape[1:] != blocks.shape[1:]
                or self.age >= self.REFRESH):
            inverses, self.age = _inverse_spd_blocks(blocks), 0
        else:
            k = kept.shape[0]
            ratio = np.divide(self.traces, traces[:k], out=np.zeros(k), where=traces[:k] > 0.0)
            inverses = np.empty_like(blocks)
            inverses[:k] = kept * ratio[:, None, None]
            if k < blocks.shape[0]:
                inverses[k:] = _inverse_spd_blocks(blocks[k:])
            self.age += 1
        self.inverses, self.traces = inverses, traces
        return inverses


def _inverse_spd_blocks(blocks: np.ndarray) -> np.ndarray:
    """Inverses of symmetric positive semi-definite matrices, shape (n, m, m).

    Cholesky-based (half the cost of numpy's LU-based batched inverse); a singular
    block (not positive definite) gets a pseudo-inverse. An ill-conditioned one is
    inverted as it is: this is a preconditioner.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        try:
            return scipy.linalg.inv(blocks, assume_a="pos", check_finite=False)
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError, ValueError):
            return np.linalg.pinv(blocks, hermitian=True)


def _solve_batched(N: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``N[a] x[a] = rhs[a]`` for SPD (possibly singular) ``N[a]``, shape (m, n, n) and (m, n).

    A Cholesky factorization decides whether every ``N[a]`` is positive definite (else
    least squares, one system at a time); the solve itself is numpy's batched LU, which
    is faster than two batched "general" solves with the triangular factors.
    """
    try:
        np.linalg.cholesky(N)
        return np.linalg.solve(N, rhs[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        return np.stack([np.linalg.lstsq(N[a], rhs[a], rcond=None)[0] for a in range(N.shape[0])])


# ----------------------------------------------------------------------------------------------
# driver
# ----------------------------------------------------------------------------------------------
@dataclass
class SolveResult:
    """Outcome of :func:`solve`.

    Attributes
    ----------
    codebook : pgdcli.codebook.codebook.Codebook
    converged : bool
        True when the solver converged and the measured error meets the tolerance.
    status : int
        0 converged, 1 ``max_modes`` reached, 2 stagnated, 3 the march failed,
        4 the measured error exceeds the tolerance (:data:`pgdcli.adapt.INACCURATE`).
    message : str
    residuals : ndarray, shape (n_modes + 1,)
        Relative residual before the first mode and after each enrichment.
    iterations : ndarray, shape (n_modes,)
        Fixed-point iterations of each enrichment.
    wall_time : float
        Seconds.
    warnings : list of str
        Findings that do not stop the solve, e.g. a reference that could not
        check the codebook.
    check : pgdcli.checks.check.CheckResult or None
        The error measured against the independent reference (None when the
        solver did not converge).
    accurate : bool or None
        The measured error meets the tolerance (None: it could not be measured).
    """

    codebook: object
    converged: bool
    status: int
    message: str
    residuals: np.ndarray
    iterations: np.ndarray
    wall_time: float
    warnings: list = field(default_factory=list)
    check: "CheckResult | None" = None
    accurate: bool | None = None

    @property
    def residual(self) -> float:
        return float(self.residuals[-1])

    @property
    def n_modes(self) -> int:
        return int(self.iterations.size)


STAGNATION_WINDOW = 8


def _blas_single_thread():
    # Small dense products here run several times faster on one BLAS thread.
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a declared dependency
        import contextlib

        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def solve(problem, *, tolerance: float | None = None, relative_tolerance: float | None = None,
          max_modes: int | None = None, callback: Callable[[dict], None] | None = None) -> SolveResult:
    """Compute the PGD codebook of a problem, its error measured against an independent reference.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem or str or path
        A validated problem, or the path of a YAML spec.
    tolerance, relative_tolerance, max_modes : optional
        Override ``problem.solver``: the codebook must satisfy
        ``|u - u_exact| <= tolerance + relative_tolerance * |u_exact|`` everywhere.
    callback : callable, optional
        Called after each enrichment with a dict ``{"mode", "residual", "iterations"}``
        (march: after each step, ``{"time", "end", "steps", "ranks"}``).

    Returns
    -------
    SolveResult
        ``converged`` is True only when the solver converged *and* the measured
        error meets the tolerance (or could not be measured: ``accurate`` None,
        with a warning); a codebook that misses its tolerance has ``status``
        :data:`pgdcli.adapt.INACCURATE` and a message saying where and why.
    """
    from .adapt import solve_to_tolerance
    from .problem.spec import Problem, load_spec

    if not isinstance(problem, Problem):
        problem = load_spec(problem)
    opts = problem.solver
    tol = opts.tolerance if tolerance is None else float(tolerance)
    rtol = opts.relative_tolerance if relative_tolerance is None else float(relative_tolerance)
    nmax = opts.max_modes if max_modes is None else int(max_modes)
    if not (0.0 < tol < 1.0):
        raise SolverError(f"tolerance must be in (0, 1), got {tol}")
    if not (0.0 <= rtol < 1.0):
        raise SolverError(f"relative_tolerance must be in [0, 1), got {rtol}")
    if nmax < 1:
        raise SolverError(f"max_modes must be at least 1, got {nmax}")
    march = _use_march(problem)
    # the solver's own target (RMS of the march, residual of the enrichment) that met the tolerance at
    # the nodes is carried from one round of the automatic resolution to the next: the error at the
    # nodes hardly depends on how many nodes there are, so each round need not find it again
    learned: dict = {}
    if march:
        once = partial(_checked_march, tolerance=tol, relative_tolerance=rtol, callback=callback, learned=learned)
    else:
        once = partial(_checked_enrichment, tolerance=tol, relative_tolerance=rtol, max_modes=nmax,
                       callback=callback, learned=learned)
    with _blas_single_thread():
        result = solve_to_tolerance(problem, once, march=march)
    rates = [(u.name, u.rate_of) for u in problem.unknowns if u.rate_of]
    if rates:  # the rate unknowns of der(x, t, 2) (pgdcli.problem.second_order), named in pgd info
        result.codebook.report["rates"] = ",".join(f"{rate}={x}" for rate, x in rates)
    return result


def _enrich(problem, residual_tolerance: float, nmax: int, callback, tolerance: float | None = None) -> SolveResult:
    """One enrichment solve to a relative residual (the solver's internal stopping signal)."""
    opts = problem.solver
    tol = residual_tolerance
    started = _time.perf_counter()
    disc = discretize(problem, tolerance=tolerance)
    state, history, iterations, status = _run(disc, opts, tol, nmax, callback)
    wall = _time.perf_counter() - started
    converged = status == 0
    residual = history[-1]
    if converged:
        message = f"converged: relative residual {residual:.3g} with {state.rank} modes"
    elif status == 1:
        message = (f"not converged: relative residual {residual:.3g} > {tol:.3g} after max_modes={nmax} modes "
                   f"(raise solver.max_modes)")
    else:
        message = (f"not converged: relative residual stagnated at {residual:.3g} (asked {tol:.3g}) "
                   f"after {state.rank} modes")
    from .codebook.codebook import codebook_from_solution

    report = {
        "converged": converged,
        "status": status,
        "message": message,
        "modes": state.rank,
        "residual": residual,
        "residual_tolerance": tol,
        "residual_history": np.array(history),
        "iterations": np.array(iterations, dtype=int),
        "wall_time": wall,
        "max_modes": nmax,
        "formulation": opts.formulation,
        "update": bool(opts.update),
    }
    if disc.separations:  # how many terms each non-separable coefficient needed
        report["separated_coefficients"] = separation_report_text(disc.separations)
    codebook = codebook_from_solution(problem, disc, state.alphas, state.factors, report)
    return SolveResult(codebook, converged, status, message, np.array(history), np.array(iterations, dtype=int), wall)


# The enrichment's residual is relative; the tolerance is an absolute error. The first solve asks
# for a relative residual equal to the tolerance (right for solutions of size ~1, as the shipped
# ones); when the error measured at the nodes is larger, the residual asked is scaled down by
# CHECK_SAFETY * tolerance / error and the enrichment runs again, at most CHECK_ATTEMPTS times. An
# error that does not fall with the residual is discretization error: more nodes (pgdcli.adapt).
RESIDUAL_FLOOR = 1e-13


def _checked_enrichment(problem, *, tolerance: float, relative_tolerance: float, max_modes: int,
                        callback=None, learned: dict | None = None) -> SolveResult:
    """Enrich, measure the error against the reference, tighten the residual if the nodes need it.

    ``learned`` (updated) carries the residual that met the tolerance at the nodes to the next call.
    """
    learned = {} if learned is None else learned
    target = learned.get("residual", tolerance)
    kept = None
    attempts = []
    for _ in range(CHECK_ATTEMPTS):
        # non-separable coefficients are separated to a share of the tolerance, tightened with the
        # residual when the error at the nodes asks for another enrichment (as the march's target is)
        result = _enrich(problem, target, max_modes, callback, min(tolerance, target))
        if not result.converged:
            if kept is None:
                result.codebook.report["tolerance"] = float(tolerance)
                return result
            break
        result.check = _measure(problem, result, tolerance, relative_tolerance)
        previous = kept
        kept = result
        attempts.append((target, result.check.node_ratio))
        ratio = result.check.node_ratio
        if not np.isfinite(ratio) or ratio <= 1.0 or target <= RESIDUAL_FLOOR:
            break
        if previous is not None and ratio > 0.5 * attempts[-2][1]:
            break  # a smaller residual did not help: discretization error
        # a residual is cheap to lower and the error follows it only roughly: at least a decade below
        # the residual reached (heat1d: 4.3e-10 with 7 modes, error 1.05e-8; 8 modes: 3.6e-10)
        target = max(RESIDUAL_FLOOR, min(target, result.residual) * min(0.1, CHECK_SAFETY / ratio))
    if kept.check.node_ratio <= 1.0:
        learned["residual"] = attempts[-1][0]
    rep = kept.codebook.report
    if kept.check.node_ratio > 1.0:  # the residual cannot (or did not) bring it down: more time or space nodes
        rep["discretization_limited"] = 1
    rep["tolerance"] = float(tolerance)
    rep["enrichment_attempts"] = np.array(attempts, dtype=float)  # (solves, 2): residual asked, node ratio
    rep["solver_message"] = (f"relative residual {kept.residual:.3g} with {kept.n_modes} modes"
                             + (f", {len(attempts)} enrichments" if len(attempts) > 1 else ""))
    return _with_resolution(kept, tolerance)


def _measure(problem, result, tolerance: float, relative_tolerance: float):
    """The codebook's error against the independent reference; unchecked (with a warning) if it cannot run."""
    from .checks.check import check_codebook, check_codebook_pde, unchecked

    space = any(c.role == "space" for c in problem.coordinates)
    try:
        measure = check_codebook_pde if space or problem.time is None else check_codebook
        check = measure(problem, result.codebook, tolerance=tolerance, relative_tolerance=relative_tolerance)
    except PgdError as exc:  # the reference cannot integrate this problem: say so, keep the solve
        reason = " ".join(str(exc).split())
        result.warnings.append(f"the codebook's error could not be checked against scipy: {reason}")
        return unchecked(reason, tolerance, relative_tolerance)
    if check.failed and not check.points:
        result.warnings.append(f"the reference integration failed at all {check.failed} check points: "
                               f"the error is not measured")
    elif check.failed:
        result.warnings.append(f"the reference integration failed at {check.failed} of "
                               f"{check.failed + check.points} check points; they are not in the measured error")
    return check


# The march's tolerance is checked (pgdcli.checks.check): if the measured error at grid nodes exceeds
# it, the march is repeated with its RMS target scaled by CHECK_SAFETY * tolerance / error, at most
# CHECK_ATTEMPTS marches in all. DOP853 is of order 8, so a tighter target costs few more steps;
# mostly it raises the ranks.
# The first march aims at CHECK_FIRST * tolerance: on the shipped problems the measured max error
# was 0.76-1.26x the RMS target (0.1x on logistic), so a target at the tolerance needed a second
# march half the time (rigid body at 1e-5: 9 s + 16 s; at 0.7e-5 one march of 15 s, 4.7e-6).
CHECK_FIRST = 0.7
CHECK_ATTEMPTS = 3
CHECK_SAFETY = 0.5


def _checked_march(problem, *, tolerance: float, relative_tolerance: float = 0.0, callback=None,
                   learned: dict | None = None) -> "SolveResult":
    """March, measure the error against scipy at the check sample, tighten the march if the nodes need it.

    The march controls an RMS over the parameter grid; the user's tolerance is read
    as a bound on the max abs error, and this is where it is made one (see
    :mod:`pgdcli.checks.check`). Errors between the parameter nodes (interpolation) do not
    fall with a tighter march: they are for :mod:`pgdcli.adapt` (more nodes).
    ``learned`` (updated) carries the target that met the tolerance at the nodes to the next call.
    """
    from .algorithms.march import solve_march

    learned = {} if learned is None else learned
    target = learned.get("march_target", CHECK_FIRST * tolerance)
    kept = None
    attempts = []
    notes = []
    for _ in range(CHECK_ATTEMPTS):
        result = solve_march(problem, target, callback=callback)
        if not result.converged:
            if kept is None:
                # the report speaks of the user's tolerance; the march's own target beside it
                result.codebook.report.update(tolerance=float(tolerance), march_tolerance=float(target))
                return result
            notes.append(f"the march with the tighter target {target:.2g} failed ({result.message}); "
                         f"kept the one with target {attempts[-1][0]:.2g}")
            break
        result.check = _measure(problem, result, tolerance, relative_tolerance)
        kept = result
        check = result.check
        attempts.append((target, check.error))
        if not np.isfinite(check.node_ratio) or check.node_ratio <= 1.0:
            break
        target *= CHECK_SAFETY / check.node_ratio
    if kept.check.node_ratio <= 1.0:
        learned["march_target"] = attempts[-1][0]
    rep = kept.codebook.report
    rep["tolerance"] = float(tolerance)
    rep["march_tolerance"] = float(attempts[-1][0])
    rep["march_attempts"] = np.array(attempts, dtype=float)  # (marches, 2): RMS target, measured max error
    end = kept.codebook.coordinate(problem.time).domain[1]
    steps = f"reached {problem.time} = {end:.6g} in {rep['steps']} steps ({rep['rejected_steps']} rejected)"
    if len(attempts) > 1:
        steps += f", {len(attempts)} marches"
    rep["solver_message"] = steps
    kept.warnings.extend(notes)
    return _with_resolution(kept, tolerance)


def _with_resolution(result: "SolveResult", tolerance: float | None) -> "SolveResult":
    """Add the Chebyshev tails per unknown and coordinate to the report.

    The tails estimate the interpolation error between nodes. The measured error
    decides (:mod:`pgdcli.adapt`); the tails are reported, and they give warnings
    only when the error could not be measured.
    """
    from .checks.resolution import resolution_tails

    if not result.converged:
        return result
    cb = result.codebook
    tails = resolution_tails(cb)
    names = cb.coordinate_names
    cb.report["resolution"] = np.array([[tails[u][c] for c in names] for u in cb.unknown_names])
    cb.report["resolution_coordinates"] = ",".join(names)
    if result.check is not None and result.check.checked:
        return result
    for u in cb.unknown_names:
        for c in names:
            tail = tails[u][c]
            if np.isfinite(tail) and tail > tolerance:
                result.warnings.append(
                    f"coordinate {c!r} may be under-resolved for {u!r}: Chebyshev tail {tail:.2g} > {tolerance:.2g}; "
                    f"add nodes to {c!r}")
    return result


def _use_march(problem) -> bool:
    """``method: auto`` marches nonlinear problems and enriches linear ones."""
    nonlinear = any(eq.polynomial.degree >= 2 or has_general(eq.polynomial) for eq in problem.equations)
    method = getattr(problem.solver, "method", "auto")
    if method == "pgd" and nonlinear:
        raise SolverError(f"{problem.source}: solver.method: 'pgd' solves equations linear in the unknowns only; "
                          f"use 'march' or 'auto' for this problem")
    march = method == "march" or (method == "auto" and nonlinear)
    if march and problem.time is None:
        raise SolverError(f"{problem.source}: equations: a steady problem (no time coordinate) needs equations linear "
                          f"in the unknowns and solver.method 'auto' or 'pgd' (the march steps in time)")
    space = [c.name for c in problem.coordinates if c.role == "space"]
    if march and space:
        raise SolverError(f"{problem.source}: equations: the separated time march handles ODEs only; "
                          f"{', '.join(space)} {'is a space coordinate' if len(space) == 1 else 'are space coordinates'}"
                          f" (nonlinear PDEs are not supported yet)")
    return march


def _run(disc: Discretization, opts, tol: float, nmax: int, callback):
    state = _State.empty(disc.operator, disc.source)
    source_norm = disc.source.norm()
    history = [1.0 if source_norm > 0 else 0.0]
    iterations: list[int] = []
    if source_norm == 0.0:
        return state, history, iterations, 0
    status = 1
    for _ in range(nmax):
        res_w, res_f = state.residual()
        factors, its = None, 0
        starts = (make(res_f) for make in (partial(_dominant_term, res_w), partial(_random_start, seed=state.rank)))
        for start in starts:  # the random start only if the first gives a zero factor
            factors, its = enrich(
                disc.operator, res_w, res_f,
                formulation=opts.formulation,
                tolerance=opts.fixed_point_tolerance,
                max_iterations=opts.max_fixed_point_iterations,
                start=start,
            )
            norms = [np.linalg.norm(f) for f in factors]
            if min(norms) > 0.0 and np.all(np.isfinite(norms)):
                break
        else:
            status = 2
            break
        state.append([f / nf for f, nf in zip(factors, norms)], float(np.prod(norms)))
        if opts.update and opts.formulation == "minres":
            res = _update_all(state, history[-1] * source_norm)
        else:
            state.alphas, res, _ = project_alphas(state, opts.formulation)
        rel = res / source_norm
        history.append(rel)
        iterations.append(its)
        if callback is not None:
            callback({"mode": state.rank, "residual": rel, "iterations": its})
        if rel <= tol:
            status = 0
            break
        if len(history) > STAGNATION_WINDOW and history[-1] > 0.99 * history[-1 - STAGNATION_WINDOW]:
            status = 2
            break
    return state, history, iterations, status


def _dominant_term(res_w: np.ndarray, res_f: list[np.ndarray]) -> list[np.ndarray]:
    """Factors of the residual's largest rank-one term: a start that is never orthogonal to it."""
    size = np.abs(res_w) * np.prod([np.linalg.norm(f, axis=0) for f in res_f], axis=0)
    c = int(np.argmax(size))
    return [f[:, c] + 0.0 for f in res_f]


def _random_start(res_f: list[np.ndarray], seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)  # deterministic: the same spec gives the same codebook
    return [rng.standard_normal(f.shape[0]) for f in res_f]


def _update_all(state: _State, previous: float) -> float:
    """Update every mode once after an enrichment, checking the residual once, at the end.

    The first update re-solves all factors of one mode, weights included, so it
    also does the projection's job: measured on the shipped problems, this
    gives the same modes and residuals as projecting first and checking every
    mode's update, for one orthogonal sweep per enrichment instead of two.
    Should the residual not have fallen below ``previous`` (the residual before
    the enrichment; rounding in the normal equations near the tolerance can do
    that), the updates are undone and the careful path is taken: projection,
    then mode by mode updates kept only if they lower the residual
    (:func:`_update_sweep`).

    Returns
    -------
    float
        ``||F - A U||`` after the update.
    """
    saved = state.snapshot()
    for j in _update_order(state):
        update_mode(state, j)
    res = state.residual_norm()
    if res < previous:
        return res
    state.restore(saved)
    state.alphas, res, _, suffixes = _project(state, "minres")
    return _update_sweep(state, res, suffixes)


def _update_sweep(state: _State, res: float, suffixes: list) -> float:
    """One update of every coordinate mode; keeps a mode's update only if it lowers the residual.

    The modes are visited in :func:`_update_order`. Each candidate's residual
    norm needs at most one new sweep step: the modes before it (already final)
    are swept into ``prefix`` as the loop goes, the modes after it are
    unchanged since the projection, whose suffix sweeps ``suffixes`` (from
    :func:`_project`, same factors) cover them.
    """
    prefix = None
    order = _update_order(state)
    for i, j in enumerate(order):
        saved = (state.alphas.copy(), state.factors[j].copy(), state.images[j].copy())
        update_mode(state, j)
        extended, new_res = _extend_and_norm(prefix, state, j, suffixes[i + 1])
        if new_res <= res:
            res = new_res
        else:
            state.alphas = saved[0]
            state.set_mode(j, saved[1], saved[2])
            if extended is not None:
                extended, _ = _extend_and_norm(prefix, state, j, suffixes[i + 1])
        prefix = extended
    return res


def _extend_and_norm(prefix: np.ndarray | None, state: _State, j: int,
                     suffix: np.ndarray | None) -> tuple[np.ndarray | None, float]:
    """Sweep mode ``j`` into ``prefix`` and return it with the residual norm ``||F - A U||``.

    ``prefix`` (r_p, C) and ``suffix`` (r_s, C) are orthogonal-sweep results
    (coefficients in orthonormal bases) over the modes before and after ``j``,
    None for no mode. The norm is then that of the (r_p', r_s) matrix
    ``prefix' diag(w) suffix^T``, and its rounding error that of the last
    step of a full sweep (a weighted sum of the terms). With no suffix (the
    last mode) the norm needs no QR at all, and no extended prefix is returned.
    """
    columns, weights = state.residual_columns(j), state.residual_weights()
    if suffix is None:
        k = columns if prefix is None else khatri_rao_rows(prefix, columns)
        return None, float(np.linalg.norm(k @ weights))
    extended = sweep_step(prefix, columns)
    return extended, float(np.linalg.norm((extended * weights) @ suffix.T))

"""Independent reference solutions of a problem with scipy's ``solve_ivp``.

This module exists to check codebooks (``pgd verify``, plots): it must not
share a code path with the PGD solver beyond the parsed spec, so that a bug in
operator assembly cannot cancel out. It therefore never imports
``solver``, ``basis`` or ``separated``: the equations are evaluated pointwise
from the parsed :class:`~pgdcli.problem.expressions.Polynomial` of each equation. Non-separable
coefficients and sources (``sin(w*t)``, ``exp(-k*x*t)``) are evaluated from their expression
trees at the samples (and space grid) at every call, never from the solvers' numerical
separation, so the error gate and ``pgd verify`` check that separation too.

Equation ``r`` reads (lhs - rhs = 0)

    sum_s A_rs(t, p) u_s'  +  g_r(t, p, u)  =  0

where ``A_rs`` is the coefficient of ``der(u_s)`` and ``g_r`` is a polynomial
in the unknown values with separated coefficients (``u``, ``u*v``, ``u**2``
... are all supported; ``der(u)`` may only appear linearly). At every
right-hand-side call the small system ``A u' = -g`` is solved per sample
(a division when every equation holds one ``der`` of its own unknown).

Samples are integrated together: one ``solve_ivp`` call advances a chunk of
``S`` parameter points at once (state of size ``q*S``, sample-major), which is
orders of magnitude faster than a Python loop over samples. The step size of
such a call is set by the worst sample, and a failure at one sample (blow-up,
singular ``A``, too many steps) fails the whole call: the chunk is then split
in halves recursively until the failing samples are isolated, so a failure is
reported for exactly the samples that fail on their own.

Chunks can be spread over worker processes (``jobs``); workers receive the
spec text (picklable) and parse it again.

Problems with space coordinates (:func:`solve_reference_pde`; :func:`solve_reference`
dispatches to it) are solved by the method of lines, independently of the PGD solver's
weak-form discretization: strong-form Chebyshev-Gauss-Lobatto collocation per space
coordinate (nodes, differentiation matrices and barycentric interpolation written here),
tensor-product grids with Kronecker-product operators, the collocated equation replaced by
the boundary condition at the boundary nodes (value ``u = g``, gradient ``du/dx = g``) and
the boundary values eliminated, which leaves an ODE system in the interior values for
``solve_ivp`` (BDF or Radau with the exact Jacobian). Equations must be linear there.
"""

from __future__ import annotations

import contextlib
import functools
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from ..errors import SolverError
from ..problem.general import evaluate as general_tree_values, is_general, tree_of

__all__ = [
    "METHODS",
    "solve_reference_vectorized",
    "PDE_METHODS",
    "ReferenceResult",
    "PdeReferenceResult",
    "solve_reference",
    "solve_reference_pde",
    "ReferenceBudgetExceeded",
    "DEFAULT_MAX_EVALUATIONS",
    "DEFAULT_SPACE_NODES",
    "chebyshev_points",
    "chebyshev_weights",
    "chebyshev_differentiation",
    "barycentric_matrix",
]

#: Integration methods of ``scipy.integrate.solve_ivp`` that may be used.
METHODS = ("DOP853", "RK45", "Radau", "BDF", "LSODA")

#: Right-hand-side evaluations one integration may spend before it is given up
#: (a stiff problem under an explicit method would otherwise run for hours).
DEFAULT_MAX_EVALUATIONS = 500_000

#: Collocation nodes per space coordinate of the method-of-lines reference.
DEFAULT_SPACE_NODES = 40
#: ``solve_ivp`` methods the method-of-lines reference may use (its system is stiff).
PDE_METHODS = ("BDF", "Radau")
#: Default tolerances of the method-of-lines reference.
PDE_RTOL = 1e-10
PDE_ATOL = 1e-12


@dataclass
class ReferenceResult:
    """Reference values of every unknown at parameter samples and times.

    Attributes
    ----------
    values : dict of str to ndarray, shape (S, T)
        Unknown name -> values at sample ``i`` (row) and the ``j``-th given
        time (column), in the order the times were given; shape (S,) for a
        steady problem. NaN where the sample failed.
    success : ndarray of bool, shape (S,)
    messages : list of str
        Per sample: ``''`` when fine, else why the integration failed.
    method, rtol, atol
        The settings used.
    """

    values: dict[str, np.ndarray]
    success: np.ndarray
    messages: list[str]
    method: str = "DOP853"
    rtol: float = 1e-12
    atol: float = 1e-12
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_failed(self) -> int:
        return int(np.count_nonzero(~self.success))


class ReferenceBudgetExceeded(Exception):
    """Raised inside an integration that spent its evaluation budget."""


# ----------------------------------------------------------------------------------------------
# compiled right-hand side
# ----------------------------------------------------------------------------------------------
class _Coefficient:
    """A Separable coefficient at S parameter samples: ``static(p) + sum_i w_i(p) f_i(t) + sum_j g_j(t, p)``.

    The non-separable parts ``g_j`` (joints) are evaluated from their expression trees
    directly, at the samples and the time of each call: never from the solvers' separation.
    """

    __slots__ = ("static", "timed", "is_static", "joints", "params", "time", "S")

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

    def at(self, t: float) -> np.ndarray:
        if self.is_static:
            return self.static
        out = self.static
        for func, weight in self.timed:
            out = out + weight * float(func(t))
        if self.joints:
            values = {**self.params, self.time: np.asarray(float(t))}
            for joint in self.joints:
                out = out + np.broadcast_to(joint.evaluate(**values), (self.S,))
        return out


class _System:
    """``u' = F(t, u)`` for S samples at once, from the problem's polynomials."""

    def __init__(self, problem, params: Mapping[str, np.ndarray], S: int, max_evaluations: int) -> None:
        time = problem.time
        names = list(problem.unknown_names)
        index = {name: i for i, name in enumerate(names)}
        self.q = q = len(names)
        self.S = S
        self.max_evaluations = max_evaluations
        self.evaluations = 0
        der: list[list[tuple[int, _Coefficient]]] = [[] for _ in range(q)]
        rest: list[list[tuple[tuple[int, ...], _Coefficient]]] = [[] for _ in range(q)]
        for r, equation in enumerate(problem.equations):
            for monomial, sep in equation.polynomial.items():
                derivatives = [a for a in monomial if a.order > 0]
                for atom in derivatives:
                    if atom.order != 1 or atom.coordinate != time:
                        raise SolverError(
                            f"{problem.source}: equations[{r}]: the reference integrator supports first-order "
                            f"time derivatives only, got '{atom.text(time)}'"
                        )
                coef = _Coefficient(sep, time, params, S)
                if derivatives:
                    if len(monomial) != 1:
                        from ..problem.expressions import format_monomial

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
        self.evaluations += 1
        self.last_y = y
        if self.evaluations > self.max_evaluations:
            raise ReferenceBudgetExceeded
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


# ----------------------------------------------------------------------------------------------
# integration of one group of samples, with failure isolation
# ----------------------------------------------------------------------------------------------
def _subset(params: Mapping[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    return {name: values[rows] for name, values in params.items()}


def _integrate(problem, params, S, t0, times, method, rtol, atol, max_evaluations):
    """One vectorized solve_ivp call.

    Returns (values (S, q, T) or None, failed, message): ``failed`` is a bool mask of the samples known
    to fail, or, when the whole call failed, a float score per sample (the magnitude of its state at the
    last right-hand-side call: blow-ups score highest).
    """
    from scipy.integrate import solve_ivp

    with np.errstate(all="ignore"):  # a coefficient may be infinite at some sample (1/k at k = 0)
        system = _System(problem, params, S, max_evaluations)
        y0 = system.initial(problem, params)
    q = system.q
    if system.bad.any():
        return None, system.bad, system.bad_reason
    if not np.isfinite(y0).all():
        return None, ~np.isfinite(y0).all(axis=1), "the initial value is not finite at this point"
    T = times.size
    out = np.empty((S, q, T))
    late = times > t0
    out[:, :, ~late] = y0[:, :, None]  # times at t0
    if not late.any():
        return out, np.zeros(S, dtype=bool), ""
    options: dict = {}
    if method in ("Radau", "BDF"):
        from scipy.sparse import block_diag

        options["jac_sparsity"] = block_diag([np.ones((q, q))] * S, format="csc")
        options["vectorized"] = True
    elif method == "LSODA":
        options["lband"] = options["uband"] = q - 1
    # Integrate from output time to output time, so that every reported value is the end of a real
    # step: dense output (t_eval) of DOP853 is an order lower and was measured 30x less accurate.
    y = y0.reshape(-1)
    t_prev, step = t0, None
    try:
        with np.errstate(all="ignore"):
            for j in np.flatnonzero(late):
                t_next = float(times[j])
                first = None if step is None else min(step, t_next - t_prev)
                sol = solve_ivp(system, (t_prev, t_next), y, method=method, rtol=rtol, atol=atol,
                                first_step=first, **options)
                if sol.status != 0:
                    where = f" at {problem.time} = {sol.t[-1]:.6g}" if sol.t.size else ""
                    return None, _scores(system, S), f"integration failed{where}: {sol.message}"
                y = sol.y[:, -1]
                values = y.reshape(S, q)
                finite = np.isfinite(values).all(axis=1)
                if not finite.all():
                    return None, ~finite, f"the solution is not finite at {problem.time} = {t_next:.6g} (blow-up)"
                out[:, :, j] = values
                steps = np.diff(sol.t)  # the last step is cut short by t_next: seed the next segment
                if steps.size >= 2:  # with the one before it
                    step = float(steps[-2])
                elif step is None and steps.size:
                    step = float(steps[-1])
                t_prev = t_next
    except ReferenceBudgetExceeded:
        return None, _scores(system, S), (
            f"gave up after {max_evaluations} right-hand side evaluations (stiff? try --method Radau or BDF)"
        )
    except (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError) as exc:
        return None, _scores(system, S), f"integration failed: {' '.join(str(exc).split()) or type(exc).__name__}"
    return out, np.zeros(S, dtype=bool), ""


def _scores(system: _System, S: int) -> np.ndarray:
    if system.last_y is None:
        return np.zeros(S)
    with np.errstate(all="ignore"):
        y = np.abs(np.asarray(system.last_y, dtype=float).reshape(S, -1))
        y[~np.isfinite(y)] = np.inf
        return y.max(axis=1)


def _solve_group(problem, params, S, t0, times, method, rtol, atol, max_evaluations):
    """Integrate S samples; on failure split the group until the failing samples are isolated.

    Returns (values (S, q, T) with NaN where failed, success (S,), messages).
    """
    q = len(problem.unknowns)
    out, bad, message = _integrate(problem, params, S, t0, times, method, rtol, atol, max_evaluations)
    if out is not None:
        return out, np.ones(S, dtype=bool), [""] * S
    if S == 1:
        return np.full((1, q, times.size), np.nan), np.zeros(1, dtype=bool), [message]
    values = np.full((S, q, times.size), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if bad.dtype != bool:
        # the whole call failed: split it until the samples that fail on their own are found, putting the
        # samples with the largest states (blow-ups) apart from the rest when they stand out
        score = bad
        top = float(np.max(score))
        middle = float(np.median(score))
        suspects = score >= math.sqrt(top * middle) if np.isfinite(top) and middle > 0 else score == top
        if suspects.all() or not suspects.any():
            order = np.argsort(-score, kind="stable")
            suspects = np.zeros(S, dtype=bool)
            suspects[order[: S // 2]] = True
        groups = [np.flatnonzero(suspects), np.flatnonzero(~suspects)]
    else:
        # the failure is pinned to some samples (singular der() coefficients, non-finite values):
        # those fail, the others are integrated without them
        for i in np.flatnonzero(bad):
            messages[i] = message
        groups = [np.flatnonzero(~bad)]
    for rows in groups:
        v, ok, msgs = _solve_group(problem, _subset(params, rows), rows.size, t0, times, method, rtol, atol,
                                   max_evaluations)
        values[rows] = v
        success[rows] = ok
        for i, m in zip(rows, msgs):
            messages[i] = m
    return values, success, messages


@functools.lru_cache(maxsize=8)
def _parse(text: str, source: str):
    from ..problem.spec import parse_spec

    try:
        return parse_spec(text, source=source, allow_nonlinear=True)
    except TypeError:  # pragma: no cover - a parse_spec without allow_nonlinear
        return parse_spec(text, source=source)


def _chunk_worker(spec_text, source, params, S, t0, times, method, rtol, atol, max_evaluations):
    """Worker-process entry point: parse the spec again, integrate one chunk."""
    problem = _parse(spec_text, source)
    return _solve_group(problem, params, S, t0, times, method, rtol, atol, max_evaluations)


def _pool_context():
    """fork on Linux when this process runs no other thread (fast, no ``__main__`` guard needed in
    user scripts), else forkserver/spawn (forking a process that runs threads can deadlock)."""
    import multiprocessing
    import sys
    import threading

    methods = multiprocessing.get_all_start_methods()
    if sys.platform.startswith("linux") and "fork" in methods and threading.active_count() == 1:
        return multiprocessing.get_context("fork")
    return multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------

def _run_in_chunks(n_samples: int, chunk_size: int, jobs: int, progress, values: np.ndarray, success: np.ndarray,
                   messages: list, solve_here: Callable, submit: Callable | None) -> None:
    """Solve the samples chunk by chunk, here or in worker processes, storing every result.

    ``solve_here(rows)`` and the future of ``submit(pool, rows)`` return ``(values, success,
    messages)`` for the sample indices ``rows``; they are written into the given arrays, and
    ``progress`` (if any) is told the number of samples finished.
    """
    bounds = list(range(0, n_samples, max(1, int(chunk_size)))) + [n_samples]
    chunks = [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    done = 0

    def store(rows, result):
        nonlocal done
        v, ok, msgs = result
        values[rows] = v
        success[rows] = ok
        for i, msg in zip(rows, msgs):
            messages[i] = msg
        done += rows.size
        if progress is not None:
            progress(done)

    workers = min(max(1, int(jobs)), len(chunks))
    if workers <= 1 or submit is None:
        for rows in chunks:
            store(rows, solve_here(rows))
        return
    from concurrent.futures import ProcessPoolExecutor, as_completed

    with ProcessPoolExecutor(max_workers=workers, mp_context=_pool_context()) as pool:
        futures = {submit(pool, rows): rows for rows in chunks}
        try:
            for future in as_completed(futures):
                store(futures[future], future.result())
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            raise

def solve_reference(
    problem,
    params: Mapping[str, np.ndarray],
    times: np.ndarray | None,
    *,
    method: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    jobs: int = 1,
    chunk_size: int | None = None,
    progress: Callable[[int], None] | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    space_nodes: int | Mapping[str, int] = DEFAULT_SPACE_NODES,
) -> ReferenceResult:
    """Integrate the problem's ODEs at parameter samples with ``scipy.integrate.solve_ivp``.

    A problem with space coordinates is solved by the method of lines of
    :func:`solve_reference_pde` at every distinct point of the other
    coordinates, and each sample reads its own space point off that solution.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        Parsed spec (linear or, with ``allow_nonlinear=True``, polynomial in
        the unknowns; linear when it has space coordinates).
    params : dict of str to array_like, shape (S,)
        A value per sample for every non-time coordinate, space coordinates
        included (``{}`` for a problem without parameters: one sample).
    times : array_like, shape (T,), or None
        Times at which to report the solution, each at or after the start
        of the time domain (where the initial values hold); any order,
        repeats allowed. None for a steady problem (no time coordinate),
        whose values then have shape (S,).
    method : str, optional
        One of :data:`METHODS` (default DOP853); with space coordinates one
        of :data:`PDE_METHODS` (default BDF).
    rtol, atol : float, optional
        Tolerances of ``solve_ivp`` (default 1e-12 and 1e-12; with space
        coordinates :data:`PDE_RTOL` and :data:`PDE_ATOL`).
    jobs : int
        Worker processes (1: in this process, no pool).
    chunk_size : int, optional
        Samples per vectorized ``solve_ivp`` call (default: a quarter of the
        samples per job, at least 64 and at most 1024; a vectorized call costs
        little more than a single sample).
    progress : callable, optional
        Called with the number of samples finished so far, after each chunk.
    max_evaluations : int
        Right-hand-side evaluations one integration may spend.
    space_nodes : int or dict of str to int
        Collocation points per space coordinate (problems with space
        coordinates only).

    Returns
    -------
    ReferenceResult

    Raises
    ------
    PgdError
        Missing or extra coordinates, mismatched shapes, times before the
        start, an unknown method or invalid tolerances.
    """
    if space_coordinates(problem):
        return _solve_reference_space(problem, params, times, method=method or "BDF",
                                      rtol=PDE_RTOL if rtol is None else rtol,
                                      atol=PDE_ATOL if atol is None else atol, jobs=jobs, chunk_size=chunk_size,
                                      progress=progress, max_evaluations=max_evaluations, space_nodes=space_nodes)
    method = "DOP853" if method is None else method
    rtol = 1e-12 if rtol is None else rtol
    atol = 1e-12 if atol is None else atol
    if method not in METHODS:
        raise SolverError(f"unknown integration method {method!r}; expected one of {', '.join(METHODS)}")
    for label, value in (("rtol", rtol), ("atol", atol)):
        if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value) and 0 < value < 1):
            raise SolverError(f"{label} must be a number in (0, 1), got {value!r}")
    if int(jobs) < 1:
        raise SolverError(f"jobs must be at least 1, got {jobs}")
    time = problem.time
    t0 = float(problem.time_coordinate.domain[0])
    names = [c.name for c in problem.parameter_coordinates]
    for key in params:
        if key not in names:
            what = "the time coordinate (give it as times)" if key == time else "not a parameter coordinate"
            raise SolverError(f"params: {key!r} is {what}; the parameters are {', '.join(names) or 'none'}")
    missing = [n for n in names if n not in params]
    if missing:
        raise SolverError(f"params: missing coordinate(s) {', '.join(missing)}")
    arrays = {n: np.atleast_1d(np.asarray(params[n], dtype=float)) for n in names}
    sizes = {a.shape for a in arrays.values()}
    if any(a.ndim != 1 for a in arrays.values()) or len(sizes) > 1:
        raise SolverError(f"params: expected 1-D arrays of one length, got shapes {sorted(sizes)}")
    S = next(iter(arrays.values())).size if arrays else 1
    if any(not np.isfinite(a).all() for a in arrays.values()):
        raise SolverError("params: values must be finite")
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if times.ndim != 1 or times.size == 0:
        raise SolverError(f"times: expected a non-empty 1-D array, got shape {times.shape}")
    if not np.isfinite(times).all():
        raise SolverError("times: values must be finite")
    if (times < t0).any():
        raise SolverError(f"times: {float(times.min())!r} is before the start {time} = {t0:g} of the time domain")
    unique, inverse = np.unique(times, return_inverse=True)

    values = np.full((S, len(problem.unknowns), unique.size), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if S:
        jobs = max(1, int(jobs))
        if chunk_size is None:
            chunk_size = min(1024, max(64, math.ceil(S / (4 * jobs))))
        settings = (t0, unique, method, float(rtol), float(atol), int(max_evaluations))
        _run_in_chunks(
            S, chunk_size, jobs, progress, values, success, messages,
            lambda rows: _solve_group(problem, _subset(arrays, rows), rows.size, *settings),
            lambda pool, rows: pool.submit(_chunk_worker, problem.source_text, problem.source,
                                           _subset(arrays, rows), rows.size, *settings),
        )
    return ReferenceResult(
        values={u.name: values[:, i, inverse] for i, u in enumerate(problem.unknowns)},
        success=success,
        messages=messages,
        method=method,
        rtol=float(rtol),
        atol=float(atol),
        times=times,
    )


# ----------------------------------------------------------------------------------------------
# method of lines: problems with space coordinates
# ----------------------------------------------------------------------------------------------
# Strong-form Chebyshev-Gauss-Lobatto collocation, written here from scratch (nodes,
# differentiation matrices, barycentric interpolation) so that it shares nothing with the PGD
# solver's weak-form discretization in pgdcli.discretization.basis / pgdcli.driver.

# unknowns per vectorized solve_ivp call (samples integrated together as one block-diagonal system);
# the error norm of solve_ivp is an RMS over the state, so few samples share one call
_PDE_CHUNK_STATES = 1024
_PDE_MAX_CHUNK = 8
# The exact Jacobian goes to solve_ivp as a dense array up to this many unknowns per call, as a sparse
# matrix beyond. Collocation couples every node of a grid line, so the LU of a 2D operator fills in
# almost completely: LAPACK's dense LU was measured 4x faster than SuperLU's at 38 x 38 interior nodes
# (0.04 s vs 0.17 s per factorization; 1.9 s vs 6.3 s per sample of the 2D heat example).
_DENSE_JACOBIAN_LIMIT = 4096


def solve_reference_vectorized(problem, params: Mapping[str, np.ndarray], S: int, times: np.ndarray, *,
                               rtol: float = 1e-13, atol: float = 1e-13,
                               max_evaluations: int = 200_000) -> dict[str, np.ndarray] | None:
    """All samples of an ODE problem in one DOP853 call with output at ``times``, or None.

    The fast path of :func:`solve_reference`: no failure isolation, so None when any
    sample fails (a blow-up, a singular ``der()`` coefficient, the evaluation budget);
    the caller then falls back to :func:`solve_reference`.

    Returns
    -------
    dict of str to ndarray, shape (S, T), or None
    """
    from scipy.integrate import solve_ivp

    names = list(problem.unknown_names)
    try:
        with np.errstate(all="ignore"):
            system = _System(problem, params, S, max_evaluations=max_evaluations)
            y0 = system.initial(problem, params)
            if system.bad.any() or not np.isfinite(y0).all():
                return None
            sol = solve_ivp(system, (float(times[0]), float(times[-1])), y0.reshape(-1), method="DOP853",
                            rtol=rtol, atol=atol, t_eval=times)
    except (ReferenceBudgetExceeded, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError):
        return None
    if sol.status != 0 or sol.y.shape[1] != times.size or not np.isfinite(sol.y).all():
        return None
    values = sol.y.reshape(S, len(names), times.size)
    return {u: values[:, i, :] for i, u in enumerate(names)}


def chebyshev_points(n: int, domain: tuple[float, float] = (-1.0, 1.0)) -> np.ndarray:
    """The ``n`` Chebyshev-Gauss-Lobatto points of ``domain``, ascending, ends exact.

    ``x_j = low + (1 + s_j) (high - low) / 2`` with ``s_j = -cos(pi j / (n - 1))``
    (computed as a sine, so that the points are symmetric to rounding).
    """
    if n < 2:
        raise ValueError(f"need at least 2 Chebyshev points, got {n}")
    low, high = map(float, domain)
    j = np.arange(n)
    s = np.sin(np.pi * (2 * j - (n - 1)) / (2 * (n - 1)))
    x = low + (1.0 + s) * (0.5 * (high - low))
    x[0], x[-1] = low, high
    return x


def chebyshev_weights(n: int) -> np.ndarray:
    """Barycentric weights of the Chebyshev-Gauss-Lobatto points (ascending order)."""
    w = (-1.0) ** np.arange(n)
    w[0] *= 0.5
    w[-1] *= 0.5
    return w


def chebyshev_differentiation(n: int, domain: tuple[float, float] = (-1.0, 1.0)) -> np.ndarray:
    """First-derivative collocation matrix ``D`` on :func:`chebyshev_points` (``(D u)_i = u'(x_i)``
    for polynomials of degree < n).

    Off-diagonal ``D_ij = (w_j / w_i) / (x_i - x_j)`` with the barycentric weights, the node
    differences from trigonometric identities (no cancellation near the ends), and the diagonal
    from the negative sum of its row (exact derivative of constants).
    """
    low, high = map(float, domain)
    theta = np.pi * np.arange(n) / (n - 1)  # x = low + (1 - cos theta) (high - low) / 2
    ti, tj = theta[:, None], theta[None, :]
    diff = (high - low) * np.sin(0.5 * (ti + tj)) * np.sin(0.5 * (ti - tj))  # x_i - x_j
    w = chebyshev_weights(n)
    with np.errstate(divide="ignore"):
        D = (w[None, :] / w[:, None]) / diff
    np.fill_diagonal(D, 0.0)
    np.fill_diagonal(D, -D.sum(axis=1))
    return D


def barycentric_matrix(nodes: np.ndarray, weights: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Interpolation matrix ``W`` (P, n): ``W @ f(nodes)`` interpolates at ``points``
    (barycentric formula of the second kind; a point on a node takes that node's value)."""
    nodes = np.asarray(nodes, dtype=float)
    points = np.atleast_1d(np.asarray(points, dtype=float))
    diff = points[:, None] - nodes[None, :]
    scale = max(1.0, float(np.max(np.abs(nodes))))
    hit = np.abs(diff) <= 1e-15 * scale
    with np.errstate(divide="ignore", invalid="ignore"):
        r = weights[None, :] / diff
        W = r / r.sum(axis=1, keepdims=True)
    rows = hit.any(axis=1)
    if rows.any():
        W[rows] = 0.0
        W[rows, np.argmax(hit[rows], axis=1)] = 1.0
    return W


def space_coordinates(problem) -> tuple:
    """The coordinates of the problem with role ``'space'`` (spec order)."""
    return tuple(c for c in problem.coordinates if getattr(c, "role", "parameter") == "space")


def sampled_coordinates(problem) -> tuple:
    """The coordinates sampled by a reference: neither time nor space."""
    return tuple(c for c in problem.coordinates if c.name != problem.time and getattr(c, "role", "") != "space")


class _SpaceGrid:
    """Tensor-product Chebyshev-Gauss-Lobatto grid over the space coordinates (C order, spec order)."""

    def __init__(self, coordinates, nodes: Mapping[str, int]) -> None:
        import scipy.sparse as sp

        self.names = [c.name for c in coordinates]
        self.domains = {c.name: tuple(map(float, c.domain)) for c in coordinates}
        self.points = {c.name: chebyshev_points(nodes[c.name], c.domain) for c in coordinates}
        self.weights = {n: chebyshev_weights(x.size) for n, x in self.points.items()}
        self.shape = tuple(self.points[n].size for n in self.names)
        self.n = int(np.prod(self.shape))
        self.index = {n: ix.reshape(-1) for n, ix in zip(self.names, np.indices(self.shape))}
        self.values = {n: self.points[n][self.index[n]] for n in self.names}
        self._ops: dict = {}
        self._sp = sp

    def derivative(self, name: str, order: int):
        """Sparse (n, n) matrix of ``d^order/dx^order`` along one coordinate on the full grid."""
        key = (name, order)
        if key not in self._ops:
            sp = self._sp
            D = chebyshev_differentiation(self.points[name].size, self.domains[name])
            if order == 2:
                D = D @ D
            k = self.names.index(name)
            before = int(np.prod(self.shape[:k]))
            after = int(np.prod(self.shape[k + 1:]))
            self._ops[key] = sp.kron(sp.kron(sp.identity(before), sp.csr_matrix(D)), sp.identity(after),
                                     format="csr")
        return self._ops[key]


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


class _PdeModel:
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
        grid = _SpaceGrid(coords, nodes)
        self.grid = grid
        n = grid.n
        names = list(problem.unknown_names)
        index = {u: i for i, u in enumerate(names)}
        q = self.q = len(names)

        # -- the unknown each equation belongs to (its rows at boundary points are replaced) -------
        owners = []
        for equation in problem.equations:
            ders = {a.unknown for m in equation.polynomial for a in m if a.order == 1 and a.coordinate == time}
            owners.append(index[next(iter(ders))] if len(ders) == 1 else None)
        if None in owners or len(set(owners)) != q:
            owners = list(range(q))  # equations in unknown order
        self.owners = owners

        # -- boundary points, conditions and the elimination u = Z y + h ----------------------------
        interior_cols, z_blocks, self.boundary = [], [], []
        offsets = np.zeros(q + 1, dtype=int)
        for s, unknown in enumerate(problem.unknowns):
            conds = {c: ends for c, ends in unknown.boundary.items() if c in self.space}
            on_end = np.zeros(n, dtype=bool)
            for c in conds:
                ix = grid.index[c]
                on_end |= (ix == 0) | (ix == grid.shape[grid.names.index(c)] - 1)
            B = np.flatnonzero(on_end)
            Iidx = np.flatnonzero(~on_end)
            choice = []  # (point, coordinate, side, Boundary)
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
                    raise SolverError(f"{problem.source}: unknowns.{unknown.name}.boundary: the boundary conditions "
                                      "do not determine the boundary values of the method-of-lines reference "
                                      f"(condition number {cond:.3g})")
                lu = sla.lu_factor(CBB)
                E = -sla.lu_solve(lu, CBI)
                E[np.abs(E) <= 1e-15 * max(1.0, float(np.max(np.abs(E))))] = 0.0
            self.boundary.append((B, Iidx, choice, lu))
            # Z_s: (n, |I|) with identity rows at I and E rows at B
            Zs = sp.lil_matrix((n, Iidx.size))
            Zs[Iidx, np.arange(Iidx.size)] = 1.0
            if B.size:
                Zs[B, :] = E
            z_blocks.append(Zs.tocsr())
            interior_cols.append(Iidx)
            offsets[s + 1] = offsets[s] + Iidx.size
        self.interior = interior_cols
        self.offsets = offsets
        self.m = int(offsets[-1])
        self.Z = sp.block_diag(z_blocks, format="csr")
        rows = np.concatenate([r * n + interior_cols[owners[r]] for r in range(q)])
        self.rows = rows  # kept rows of the full (q n) system, in the order of the interior unknowns

        # -- operator and source terms ---------------------------------------------------------
        def place(r: int, s: int, block):
            blocks = [[None] * q for _ in range(q)]
            blocks[r][s] = block
            for i in range(q):  # bmat needs every block row and column sized
                if blocks[i][i] is None:
                    blocks[i][i] = sp.csr_matrix((n, n))
            return sp.bmat(blocks, format="csr")

        self.ops = []  # (kind 'mass'|'op', time key, time func, param factors, coef, R A Z, R A (for h))
        self.sources = []  # (time key, time func, param factors, coef, R-rows vector)
        self.joint_sources = []  # (equation row, Joint): non-separable sources, evaluated from their trees
        self.joint_ops = []  # (equation row, unknown, derivative or None, Joint): non-separable coefficients
        for r, equation in enumerate(problem.equations):
            for monomial, sep in equation.polynomial.items():
                if len(monomial) > 1:
                    from ..problem.expressions import format_monomial

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
                    self.joint_ops += [(r, index[atom.unknown], L, joint) for joint in sep.joints]
                elif sep.joints:
                    self.joint_sources += [(r, joint) for joint in sep.joints]
                for term in sep.terms:
                    coef, tfunc, pf, sf = _term_parts(term, time, self.space)
                    values = np.ones(n)
                    for name, func in sf:
                        values = values * np.broadcast_to(func(grid.values[name]), (n,))
                    key = None if tfunc is None else tfunc.tree
                    if not monomial:
                        full = np.zeros(q * n)
                        full[r * n:(r + 1) * n] = values
                        self.sources.append((key, tfunc, pf, coef, full[rows]))
                        continue
                    atom = monomial[0]
                    s = index[atom.unknown]
                    if atom.order == 1 and atom.coordinate == time:
                        kind, L = "mass", None
                    elif atom.order == 0:
                        kind, L = "op", None
                    else:
                        kind, L = "op", grid.derivative(atom.coordinate, atom.order)
                    block = sp.diags(values) if L is None else sp.diags(values) @ L
                    A = place(r, s, sp.csr_matrix(block))[rows]
                    self.ops.append((kind, key, tfunc, pf, coef, (A @ self.Z).tocsr(), A))
        self.time_funcs = {}
        for entry in self.ops:
            if entry[1] is not None:
                self.time_funcs[entry[1]] = entry[2]
        for entry in self.sources:
            if entry[0] is not None:
                self.time_funcs[entry[0]] = entry[1]
        self.static_mass = all(key is None for kind, key, *_ in self.ops if kind == "mass")

    # -- per-sample data ---------------------------------------------------------------------------
    @staticmethod
    def _weights(pf, coef: float, params: Mapping[str, np.ndarray], S: int) -> np.ndarray:
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

    def _joint_values(self, joint, params: Mapping[str, np.ndarray], S: int, t: float | None) -> np.ndarray:
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
            full[:, r * n:(r + 1) * n] += self._joint_values(joint, params, S, t)
        return full[:, self.rows].reshape(-1)

    def joint_operators(self, entries, params: Mapping[str, np.ndarray], S: int, t: float | None) -> list:
        """Per sample, the rows ``R (c L)`` of non-separable coefficients ``c`` of unknowns: (m, q n) each."""
        import scipy.sparse as sp

        n, q = self.grid.n, self.q
        out = [sp.csr_matrix((self.rows.size, q * n)) for _ in range(S)]
        for r, s, L, joint in entries:
            values = self._joint_values(joint, params, S, t)
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


class _PdeSystem:
    """``y' = -(M(t)^-1) (A(t) y + b(t))`` for a chunk of samples, block-diagonal over samples."""

    def __init__(self, model: _PdeModel, params: Mapping[str, np.ndarray], S: int, max_evaluations: int) -> None:
        import scipy.sparse as sp

        self.model = model
        self.S = S
        self.max_evaluations = max_evaluations
        self.evaluations = 0
        self.last_y = None
        m = model.m
        h = model.boundary_lift(params, S)  # (S, q n)
        self.h = h
        mass: dict = {}
        ops: dict = {}
        src: dict = {}
        for kind, key, _, pf, coef, AZ, A in model.ops:
            w = model._weights(pf, coef, params, S)
            target = mass if kind == "mass" else ops
            target[key] = [w[i] * AZ if j is None else j + w[i] * AZ for i, j in enumerate(target.get(key, [None] * S))]
            if kind == "op":  # the known boundary part h of the state (constant in time: no mass term)
                src[key] = src.get(key, 0.0) + np.concatenate([w[i] * (A @ h[i]) for i in range(S)])
        for key, _, pf, coef, vec in model.sources:
            w = model._weights(pf, coef, params, S)
            src[key] = src.get(key, 0.0) + np.concatenate([w[i] * vec for i in range(S)])
        self.params = params
        self.timed_joints = [(r, j) for r, j in model.joint_sources if model.time in j.coordinates]
        fixed = [(r, j) for r, j in model.joint_sources if model.time not in j.coordinates]
        if fixed:
            src[None] = src.get(None, 0.0) + model.joint_source(fixed, params, S, None)
        self.timed_ops = [(e, *self._factors(e, h)) for e in model.joint_ops if model.time in e[3].coordinates]
        fixed = [e for e in model.joint_ops if model.time not in e[3].coordinates]
        if fixed:  # constant in time: with the other operators, once
            A = model.joint_operators(fixed, params, S, None)
            ops[None] = [a @ model.Z if j is None else j + a @ model.Z for a, j in zip(A, ops.get(None, [None] * S))]
            src[None] = src.get(None, 0.0) + np.concatenate([a @ h[i] for i, a in enumerate(A)])
        self.mass_solve = None  # M^-1 applied to the timed sources when the operators are premultiplied
        self.bad = np.zeros(S, dtype=bool)
        self.bad_reason = ""
        self.keys = sorted(set(ops) | set(src), key=lambda k: (k is not None, repr(k)))
        self.funcs = model.time_funcs
        zero = sp.csr_matrix((S * m, S * m))
        self.A = {k: sp.block_diag(ops[k], format="csr") if k in ops else zero for k in self.keys}
        self.b = {k: np.asarray(src[k]) if k in src else np.zeros(S * m) for k in self.keys}
        self.M = {k: sp.block_diag(mass[k], format="csr") for k in mass}
        self.static = model.static_mass
        if model.time is None:  # steady: no der(), nothing to invert
            self.diagonal = self.constant = True
            return
        self.diagonal = all((M - sp.diags(M.diagonal())).count_nonzero() == 0 for M in self.M.values())
        if self.static:
            M = self.M.get(None, zero)
            self._mass_check(M)
            if self.bad.any():
                return
            if self.diagonal:
                inv = sp.diags(1.0 / M.diagonal())
                self.A = {k: (inv @ A).tocsr() for k, A in self.A.items()}
                self.b = {k: inv @ b for k, b in self.b.items()}
                self.mass_solve = inv.__matmul__
            else:
                from scipy.sparse.linalg import splu

                lu = splu(M.tocsc())
                self.A = {k: sp.csr_matrix(lu.solve(A.toarray())) for k, A in self.A.items()}
                self.b = {k: lu.solve(b) for k, b in self.b.items()}
                self.mass_solve = lu.solve
        self.constant = self.static and self.keys in ([], [None]) and not self.timed_joints and not self.timed_ops

    def _mass_check(self, M) -> None:
        m, S = self.model.m, self.S
        if self.diagonal:
            d = M.diagonal().reshape(S, m)
            bad = ~np.isfinite(d).all(axis=1) | (d == 0).any(axis=1)
            reason = "a coefficient of der() vanishes or is not finite at this point"
        else:
            bad = np.zeros(S, dtype=bool)
            dense = M.toarray()
            for i in range(S):
                block = dense[i * m:(i + 1) * m, i * m:(i + 1) * m]
                bad[i] = not (np.isfinite(block).all() and np.linalg.cond(block) < 1e14)
            reason = "the matrix of der() coefficients is singular at this point (not an ODE system there)"
        self.bad, self.bad_reason = bad, reason

    def _weight(self, key, t: float) -> float:
        return 1.0 if key is None else float(self.funcs[key](t))

    def matrix(self, t: float):
        import scipy.sparse as sp

        A = sp.csr_matrix((self.S * self.model.m,) * 2)
        for k in self.keys:
            A = A + (self.A[k] if k is None else self._weight(k, t) * self.A[k])
        for (_, _, _, joint), left, right, _ in self.timed_ops:
            c = self.model._joint_values(joint, self.params, self.S, t).reshape(-1)
            part = left @ sp.diags(c) @ right
            A = A + (part if self.mass_solve is None else sp.csr_matrix(self.mass_solve(part.toarray())))
        return A

    def _factors(self, entry, h: np.ndarray):
        """``R (c L) Z = left diag(c) right`` over all samples (block-diagonal), and ``L h`` of the unknown: (S n,)."""
        import scipy.sparse as sp

        model = self.model
        r, s, L, _ = entry
        n, S = model.grid.n, self.S
        select = sp.kron(sp.csr_matrix(([1.0], ([r], [0])), shape=(model.q, 1)), sp.identity(n), format="csr")
        left = select[model.rows]  # (m, n): the equation rows kept from the block of equation r
        right = model.Z[s * n:(s + 1) * n]  # (n, m)
        block = h[:, s * n:(s + 1) * n]
        if L is not None:
            right = L @ right
            block = (L @ block.T).T
        return (sp.block_diag([left] * S, format="csr"), sp.block_diag([right] * S, format="csr"),
                np.asarray(block).reshape(-1))

    def _mass_at(self, t: float):
        M = None
        for k, Mk in self.M.items():
            term = Mk if k is None else self._weight(k, t) * Mk
            M = term if M is None else M + term
        return M

    def __call__(self, t: float, y: np.ndarray) -> np.ndarray:
        self.evaluations += 1
        self.last_y = y
        if self.evaluations > self.max_evaluations:
            raise ReferenceBudgetExceeded
        out = np.zeros_like(y, dtype=float)
        for k in self.keys:
            w = self._weight(k, t)
            if w != 0.0:
                b = self.b[k] if y.ndim == 1 else self.b[k][:, None]
                out -= w * (self.A[k] @ y + b)
        if self.timed_joints:
            b = self.model.joint_source(self.timed_joints, self.params, self.S, t)
            if self.mass_solve is not None:
                b = self.mass_solve(b)
            out -= b if y.ndim == 1 else b[:, None]
        for (_, _, _, joint), left, right, hs in self.timed_ops:  # R (c L) (Z y + h), c from its tree at t
            c = self.model._joint_values(joint, self.params, self.S, t).reshape(-1)
            part = left @ (c[:, None] * (right @ y) if y.ndim == 2 else c * (right @ y)) + \
                (left @ (c * hs) if y.ndim == 1 else (left @ (c * hs))[:, None])
            out -= part if self.mass_solve is None else self.mass_solve(part)
        if self.static:
            return out
        M = self._mass_at(t)
        if self.diagonal:
            d = M.diagonal()
            return out / (d if y.ndim == 1 else d[:, None])
        from scipy.sparse.linalg import spsolve

        return spsolve(M.tocsc(), out)

    def jacobian(self, t: float, y: np.ndarray):
        import scipy.sparse as sp

        J = -self.matrix(t)
        if self.static:
            return J
        M = self._mass_at(t)
        if self.diagonal:
            return sp.diags(1.0 / M.diagonal()) @ J
        from scipy.sparse.linalg import splu

        return sp.csr_matrix(splu(M.tocsc()).solve(J.toarray()))


def _solve_steady_pde(model: _PdeModel, params, S, times):
    """Sparse LU solves of ``A y + b = 0``, one per sample, as :func:`_integrate_pde` returns them.

    A sample whose matrix is singular (a pivot below 1e-12 of the largest: pure Neumann
    conditions, say) fails rather than returning the garbage a near-zero pivot gives.
    """
    from scipy.sparse.linalg import splu

    q, n, m = model.q, model.grid.n, model.m
    with np.errstate(all="ignore"):
        system = _PdeSystem(model, params, S, 0)
        A = system.matrix(0.0).tocsr()
        b = np.asarray(sum(system.b.values()) if system.b else np.zeros(S * m), dtype=float)
        y = np.full((S, m), np.nan)
        for i in range(S):
            rows = slice(i * m, (i + 1) * m)
            try:
                lu = splu(A[rows, rows].tocsc())
            except RuntimeError:  # SuperLU: "Factor is exactly singular"
                continue
            pivots = np.abs(lu.U.diagonal())
            if np.isfinite(pivots).all() and pivots.min() > 1e-12 * pivots.max():
                y[i] = lu.solve(-b[rows])
    finite = np.isfinite(y).all(axis=1)
    if not finite.all():
        return None, ~finite, ("the steady system is singular at this point (do the boundary conditions determine "
                               "the solution?)")
    full = (model.Z @ y.T).T + system.h  # (S, q n)
    out = np.broadcast_to(full.reshape(S, q, 1, n), (S, q, times.size, n)).copy()
    return out, np.zeros(S, dtype=bool), ""


def _integrate_pde(model: _PdeModel, params, S, t0, times, method, rtol, atol, max_evaluations):
    """One solve_ivp call over S samples. Returns (full grid values (S, q, T, n) or None, failed, message).

    A steady problem (no time coordinate) is one linear solve; its values repeat over ``times``.
    """
    from scipy.integrate import solve_ivp

    if model.time is None:
        return _solve_steady_pde(model, params, S, times)
    q, n, T = model.q, model.grid.n, times.size
    with np.errstate(all="ignore"):
        system = _PdeSystem(model, params, S, max_evaluations)
        u0 = model.initial_grid(params, S)
    if system.bad.any():
        return None, system.bad, system.bad_reason
    if not np.isfinite(u0).all():
        return None, ~np.isfinite(u0).reshape(S, -1).all(axis=1), "the initial value is not finite at this point"
    out = np.empty((S, q, T, n))
    late = times > t0
    out[:, :, ~late, :] = u0[:, :, None, :]
    if not late.any():
        return out, np.zeros(S, dtype=bool), ""
    y0 = model.interior_values(u0).reshape(-1)
    dense = y0.size <= _DENSE_JACOBIAN_LIMIT
    if system.constant:
        J = system.jacobian(t0, y0)
        jac = J.toarray() if dense else J.tocsc()
    else:
        def jac(t, y):
            J = system.jacobian(t, y)
            return J.toarray() if dense else J.tocsc()
    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(system, (t0, float(times[-1])), y0, method=method, rtol=rtol, atol=atol, jac=jac,
                            t_eval=times[late])
    except ReferenceBudgetExceeded:
        return None, _scores(system, S), (
            f"gave up after {max_evaluations} right-hand side evaluations")
    except (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError, RuntimeError) as exc:
        return None, _scores(system, S), f"integration failed: {' '.join(str(exc).split()) or type(exc).__name__}"
    if sol.status != 0 or sol.y.shape[1] != int(np.count_nonzero(late)):
        where = f" at {model.time} = {sol.t[-1]:.6g}" if sol.t.size else ""
        return None, _scores(system, S), f"integration failed{where}: {sol.message}"
    y = sol.y.reshape(S, model.m, -1)  # (S, m, T_late)
    if not np.isfinite(y).all():
        finite = np.isfinite(y).reshape(S, -1).all(axis=1)
        return None, ~finite, "the solution is not finite (blow-up)"
    full = np.stack([model.Z @ y[i] for i in range(S)]) + system.h[:, :, None]  # (S, q n, T_late)
    out[:, :, late, :] = full.reshape(S, q, n, -1).transpose(0, 1, 3, 2)
    return out, np.zeros(S, dtype=bool), ""


def _solve_group_pde(model, params, S, t0, times, method, rtol, atol, max_evaluations):
    """Integrate S samples together; when the call fails, each sample on its own."""
    q, n = model.q, model.grid.n
    out, bad, message = _integrate_pde(model, params, S, t0, times, method, rtol, atol, max_evaluations)
    if out is not None:
        return out, np.ones(S, dtype=bool), [""] * S
    if S == 1:
        return np.full((1, q, times.size, n), np.nan), np.zeros(1, dtype=bool), [message]
    values = np.full((S, q, times.size, n), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if bad.dtype == bool:
        for i in np.flatnonzero(bad):
            messages[i] = message
        singles = np.flatnonzero(~bad)
    else:
        singles = np.arange(S)
    for i in singles:
        rows = np.array([i])
        v, ok, msgs = _solve_group_pde(model, _subset(params, rows), 1, t0, times, method, rtol, atol,
                                       max_evaluations)
        values[i], success[i], messages[i] = v[0], ok[0], msgs[0]
    return values, success, messages


@functools.lru_cache(maxsize=4)
def _pde_model(text: str, source: str, nodes: tuple) -> _PdeModel:
    return _PdeModel(_parse(text, source), dict(nodes))


@contextlib.contextmanager
def _one_blas_thread():
    """BLAS limited to one thread while the method of lines runs (its LU factorizations).

    Threaded LAPACK spins when another process holds a core: on 2 busy cores the LU of the
    2D heat example (1444 unknowns) took 0.27 s with 2 threads, 0.056 s with one.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


def _pde_chunk_worker(spec_text, source, nodes, params, S, t0, times, method, rtol, atol, max_evaluations):
    """Worker-process entry point: parse the spec again, build the grid, integrate one chunk."""
    model = _pde_model(spec_text, source, nodes)
    with _one_blas_thread():
        return _solve_group_pde(model, params, S, t0, times, method, rtol, atol, max_evaluations)


@dataclass
class PdeReferenceResult:
    """Method-of-lines reference values of every unknown.

    Attributes
    ----------
    values : dict of str to ndarray
        Unknown name -> values, shape ``(S, T, X_1, ..., X_d)`` on the tensor grid of the
        requested space points (``grid=True``, or the collocation nodes when no points were
        given), or ``(S, T, P)`` at ``P`` scattered space points (``grid=False``). NaN where the
        sample failed.
    success : ndarray of bool, shape (S,)
    messages : list of str
    space : list of str
        The space coordinates, in the order of the space axes.
    space_points : dict of str to ndarray
        The space points of each coordinate (as requested, or the collocation nodes).
    nodes : dict of str to int
        Collocation nodes per space coordinate.
    grid : bool
    method, rtol, atol, times
        The settings used and the times as given.
    """

    values: dict[str, np.ndarray]
    success: np.ndarray
    messages: list[str]
    space: list[str]
    space_points: dict[str, np.ndarray]
    nodes: dict[str, int]
    grid: bool = True
    method: str = "BDF"
    rtol: float = PDE_RTOL
    atol: float = PDE_ATOL
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_failed(self) -> int:
        return int(np.count_nonzero(~self.success))


def _check_tolerances(rtol, atol) -> None:
    for label, value in (("rtol", rtol), ("atol", atol)):
        if isinstance(value, bool) or not (isinstance(value, (int, float, np.floating)) and math.isfinite(value)
                                           and 0 < value < 1):
            raise SolverError(f"{label} must be a number in (0, 1), got {value!r}")


def _check_times(times, t0: float, time: str) -> np.ndarray:
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if times.ndim != 1 or times.size == 0:
        raise SolverError(f"times: expected a non-empty 1-D array, got shape {times.shape}")
    if not np.isfinite(times).all():
        raise SolverError("times: values must be finite")
    if (times < t0).any():
        raise SolverError(f"times: {float(times.min())!r} is before the start {time} = {t0:g} of the time domain")
    return times


def _check_params(params: Mapping[str, np.ndarray], names: list[str], time: str, others: list[str],
                  label: str = "params") -> tuple[dict[str, np.ndarray], int]:
    for key in params:
        if key not in names:
            if key == time:
                what = "the time coordinate (give it as times)"
            elif key in others:
                what = "a space coordinate (give it as space_points)"
            else:
                what = "not a parameter coordinate"
            raise SolverError(f"{label}: {key!r} is {what}; the parameters are {', '.join(names) or 'none'}")
    missing = [n for n in names if n not in params]
    if missing:
        raise SolverError(f"{label}: missing coordinate(s) {', '.join(missing)}")
    arrays = {n: np.atleast_1d(np.asarray(params[n], dtype=float)) for n in names}
    sizes = {a.shape for a in arrays.values()}
    if any(a.ndim != 1 for a in arrays.values()) or len(sizes) > 1:
        raise SolverError(f"{label}: expected 1-D arrays of one length, got shapes {sorted(sizes)}")
    if any(not np.isfinite(a).all() for a in arrays.values()):
        raise SolverError(f"{label}: values must be finite")
    S = next(iter(arrays.values())).size if arrays else 1
    return arrays, S


def _space_nodes(problem, space_nodes) -> dict[str, int]:
    names = [c.name for c in space_coordinates(problem)]
    if isinstance(space_nodes, Mapping):
        extra = [k for k in space_nodes if k not in names]
        if extra:
            raise SolverError(f"space_nodes: {extra[0]!r} is not a space coordinate ({', '.join(names)})")
        counts = {n: space_nodes.get(n, DEFAULT_SPACE_NODES) for n in names}
    else:
        counts = {n: space_nodes for n in names}
    for n, k in counts.items():
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 3 <= k <= 1000:
            raise SolverError(f"space_nodes: expected an integer from 3 to 1000 for {n!r}, got {k!r}")
    return {n: int(k) for n, k in counts.items()}


def _grid_states(problem, arrays, S, times, *, nodes, method, rtol, atol, jobs, chunk_size, progress,
                 max_evaluations):
    """Full-grid values (S, q, T_unique, n) at the unique sorted times, success, messages, the model."""
    t0 = _start_time(problem)
    unique, inverse = np.unique(times, return_inverse=True)
    model = _pde_model(problem.source_text, problem.source, tuple(sorted(nodes.items()))) \
        if problem.source_text else _PdeModel(problem, nodes)
    q, n = model.q, model.grid.n
    values = np.full((S, q, unique.size, n), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    jobs = max(1, int(jobs))
    if chunk_size is None:
        chunk_size = max(1, min(_PDE_MAX_CHUNK, _PDE_CHUNK_STATES // max(model.m, 1), math.ceil(S / jobs)))
    settings = (t0, unique, method, float(rtol), float(atol), int(max_evaluations))
    key = tuple(sorted(nodes.items()))

    def solve_here(rows):
        with _one_blas_thread():
            return _solve_group_pde(model, _subset(arrays, rows), rows.size, *settings)

    def submit(pool, rows):
        return pool.submit(_pde_chunk_worker, problem.source_text, problem.source, key,
                           _subset(arrays, rows), rows.size, *settings)

    # a problem without spec text cannot be rebuilt in a worker: solve it here
    _run_in_chunks(S, chunk_size, jobs, progress, values, success, messages, solve_here,
                   submit if problem.source_text else None)
    return values, success, messages, model, unique, inverse


def _start_time(problem) -> float:
    """The start of the time domain; -inf for a steady problem (every time is 'late')."""
    return -np.inf if problem.time is None else float(problem.time_coordinate.domain[0])


def _reference_times(problem, times) -> np.ndarray:
    """Validated times; a steady problem takes ``None`` and gets one placeholder time."""
    if problem.time is None:
        if times is not None:
            raise SolverError(f"{problem.source}: times: a steady problem (no time coordinate) takes times=None")
        return np.zeros(1)
    if times is None:
        raise SolverError("times: expected a non-empty 1-D array of times, got None")
    return _check_times(times, _start_time(problem), problem.time)


def _interpolation_matrices(model: _PdeModel, points: Mapping[str, np.ndarray]) -> list[np.ndarray]:
    grid = model.grid
    return [barycentric_matrix(grid.points[c], grid.weights[c], points[c]) for c in grid.names]


def _on_grid(full: np.ndarray, shape: tuple, mats: list[np.ndarray]) -> np.ndarray:
    """(..., n) nodal values -> (..., X_1, ..., X_d) on the tensor grid of the points."""
    lead = full.shape[:-1]
    V = full.reshape(lead + shape)
    for k, W in enumerate(mats):
        axis = len(lead) + k
        V = np.moveaxis(np.tensordot(V, W, axes=([axis], [1])), -1, axis)
    return V


def _at_points(full: np.ndarray, shape: tuple, mats: list[np.ndarray]) -> np.ndarray:
    """(A, n) nodal values -> (A, P) at scattered points (row p of every matrix)."""
    A = full.shape[0]
    V = full.reshape((A,) + shape)
    V = np.tensordot(V, mats[0], axes=([1], [1]))  # (A, N_2, ..., N_d, P)
    V = np.moveaxis(V, -1, 1)  # (A, P, N_2, ..., N_d)
    for W in mats[1:]:
        V = np.einsum("ap...j,pj->ap...", V, W) if V.ndim > 3 else np.einsum("apj,pj->ap", V, W)
    return V


def solve_reference_pde(
    problem,
    params: Mapping[str, np.ndarray],
    space_points: Mapping[str, np.ndarray] | None,
    times: np.ndarray | None,
    *,
    grid: bool = True,
    space_nodes: int | Mapping[str, int] = DEFAULT_SPACE_NODES,
    method: str = "BDF",
    rtol: float = PDE_RTOL,
    atol: float = PDE_ATOL,
    jobs: int = 1,
    chunk_size: int | None = None,
    progress: Callable[[int], None] | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
) -> PdeReferenceResult:
    """Method-of-lines reference of a problem with space coordinates.

    Every space coordinate is discretized by strong-form Chebyshev-Gauss-Lobatto collocation
    (``space_nodes`` points; tensor-product grid over several space coordinates, sparse
    Kronecker-product operators). At the ends of a coordinate where an unknown has boundary
    conditions, the collocated equation is replaced by the condition (value: ``u = g``; gradient:
    ``du/dx = g``, the derivative along the coordinate, at either end); the boundary values are
    eliminated (each is a linear combination of interior values plus a known part), which leaves
    an ODE system in the interior values. It is integrated by ``solve_ivp`` (BDF or Radau, with
    its exact sparse Jacobian) at each parameter sample (a few samples share one call as a
    block-diagonal system), and the nodal values are interpolated to the requested space points
    with the barycentric formula. At the start time the initial value is evaluated exactly at the
    requested points.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        A linear problem with at least one space coordinate.
    params : dict of str to array_like, shape (S,)
        A value per sample for every coordinate that is neither time nor space (``{}`` when there
        are none: one sample).
    space_points : dict of str to array_like or None
        Points per space coordinate. ``grid=True``: the tensor grid of these 1-D arrays;
        ``grid=False``: ``P`` scattered points, one array of length ``P`` per coordinate.
        None: the collocation nodes themselves (tensor grid).
    times : array_like, shape (T,), or None
        Times at or after the start of the time domain; any order, repeats allowed. None for a
        steady problem (no time coordinate), which is one sparse linear solve per sample.
    grid : bool
        See ``space_points``.
    space_nodes : int or dict of str to int
        Collocation points per space coordinate (default :data:`DEFAULT_SPACE_NODES`).
    method : {'BDF', 'Radau'}
    rtol, atol : float
        Tolerances of ``solve_ivp``.
    jobs : int
        Worker processes (1: in this process).
    chunk_size : int, optional
        Samples per ``solve_ivp`` call (default: as many as fit in about
        1024 unknowns, at most 8).
    progress : callable, optional
        Called with the number of samples finished so far.
    max_evaluations : int
        Right-hand-side evaluations one integration may spend.

    Returns
    -------
    PdeReferenceResult
        ``values[u]`` has shape ``(S, T, X_1, ..., X_d)`` (grid) or ``(S, T, P)`` (scattered);
        without the ``T`` axis for a steady problem.

    Raises
    ------
    PgdError
        No space coordinate, a nonlinear equation, boundary conditions that do not determine the
        boundary values, invalid samples, points outside the domain, times before the start, an
        unknown method or invalid tolerances.
    """
    if method not in PDE_METHODS:
        raise SolverError(f"method {method!r}: the method-of-lines reference is stiff; use one of "
                          f"{', '.join(PDE_METHODS)}")
    _check_tolerances(rtol, atol)
    if isinstance(jobs, bool) or int(jobs) < 1:
        raise SolverError(f"jobs must be at least 1, got {jobs}")
    space = [c.name for c in space_coordinates(problem)]
    if not space:
        raise SolverError(f"{problem.source}: the problem has no space coordinate; use solve_reference")
    names = [c.name for c in sampled_coordinates(problem)]
    arrays, S = _check_params(params, names, problem.time, space)
    nodes = _space_nodes(problem, space_nodes)
    t0 = _start_time(problem)
    times = _reference_times(problem, times)

    if space_points is None:
        points = None
    else:
        extra = [k for k in space_points if k not in space]
        if extra:
            raise SolverError(f"space_points: {extra[0]!r} is not a space coordinate ({', '.join(space)})")
        missing = [k for k in space if k not in space_points]
        if missing:
            raise SolverError(f"space_points: missing coordinate(s) {', '.join(missing)}")
        points = {k: np.atleast_1d(np.asarray(space_points[k], dtype=float)) for k in space}
        if any(p.ndim != 1 or p.size == 0 for p in points.values()):
            raise SolverError("space_points: expected non-empty 1-D arrays")
        if not grid and len({p.size for p in points.values()}) > 1:
            raise SolverError("space_points: scattered points (grid=False) need arrays of one length")
        for c in space_coordinates(problem):
            low, high = map(float, c.domain)
            slack = 1e-12 * max(1.0, abs(low), abs(high))
            x = points[c.name]
            if not (np.isfinite(x).all() and (x >= low - slack).all() and (x <= high + slack).all()):
                bad = x[~(np.isfinite(x) & (x >= low - slack) & (x <= high + slack))][0]
                raise SolverError(f"space_points: {c.name} = {float(bad)!r} is outside the domain "
                                  f"[{low:g}, {high:g}]")
            points[c.name] = np.clip(x, low, high)

    states, success, messages, model, unique, inverse = _grid_states(
        problem, arrays, S, times, nodes=nodes, method=method, rtol=rtol, atol=atol, jobs=jobs,
        chunk_size=chunk_size, progress=progress, max_evaluations=max_evaluations)
    shape = model.grid.shape
    out: dict[str, np.ndarray] = {}
    if points is None:
        result_points = {c: model.grid.points[c].copy() for c in space}
        for s, u in enumerate(problem.unknown_names):
            out[u] = states[:, s][:, inverse].reshape((S, times.size) + shape)
    else:
        result_points = points
        mats = _interpolation_matrices(model, points)
        at_start = unique == t0
        for s, u in enumerate(problem.unknown_names):
            full = states[:, s]  # (S, Tu, n)
            if grid:
                vals = _on_grid(full, shape, mats)
            else:
                vals = _at_points(full.reshape(-1, model.grid.n), shape, mats).reshape(S, unique.size, -1)
            if at_start.any():  # the initial value exactly at the points
                initial = problem.unknowns[s].initial
                if grid:
                    mesh = np.meshgrid(*[points[c] for c in space], indexing="ij")
                    at = {c: m[None] for c, m in zip(space, mesh)}
                    at.update({p: arrays[p].reshape((S,) + (1,) * len(space)) for p in names})
                    exact = np.broadcast_to(initial.evaluate(**at), (S,) + mesh[0].shape) if initial.terms else 0.0
                else:
                    at = {c: points[c][None, :] for c in space}
                    at.update({p: arrays[p][:, None] for p in names})
                    P = points[space[0]].size
                    exact = np.broadcast_to(initial.evaluate(**at), (S, P)) if initial.terms else 0.0
                j = int(np.flatnonzero(at_start)[0])
                ok = success
                vals[ok, j] = exact[ok] if np.ndim(exact) else 0.0
            out[u] = vals[:, inverse]
    if problem.time is None:
        out = {u: v[:, 0] for u, v in out.items()}
    return PdeReferenceResult(values=out, success=success, messages=messages, space=space,
                              space_points=result_points, nodes=nodes, grid=bool(grid or points is None),
                              method=method, rtol=float(rtol), atol=float(atol), times=times)


def _solve_reference_space(problem, params, times, *, method, rtol, atol, jobs, chunk_size, progress,
                           max_evaluations, space_nodes) -> ReferenceResult:
    """:func:`solve_reference` for a problem with space coordinates: samples over all non-time
    coordinates; one method-of-lines solve per distinct point of the sampled (non-space) ones."""
    if method not in PDE_METHODS:
        raise SolverError(f"method {method!r}: the method-of-lines reference is stiff; use one of "
                          f"{', '.join(PDE_METHODS)}")
    _check_tolerances(rtol, atol)
    if isinstance(jobs, bool) or int(jobs) < 1:
        raise SolverError(f"jobs must be at least 1, got {jobs}")
    names = [c.name for c in problem.parameter_coordinates]
    arrays, S = _check_params(params, names, problem.time, [])
    space = [c.name for c in space_coordinates(problem)]
    sampled = [c.name for c in sampled_coordinates(problem)]
    for c in space_coordinates(problem):
        low, high = map(float, c.domain)
        slack = 1e-12 * max(1.0, abs(low), abs(high))
        x = arrays[c.name]
        outside = (x < low - slack) | (x > high + slack)
        if outside.any():
            raise SolverError(f"params: {c.name} = {float(x[outside][0])!r} is outside the domain [{low:g}, {high:g}]")
        arrays[c.name] = np.clip(x, low, high)
    nodes = _space_nodes(problem, space_nodes)
    t0 = _start_time(problem)
    times = _reference_times(problem, times)
    if sampled:
        stacked = np.column_stack([arrays[n] for n in sampled])
        distinct, group = np.unique(stacked, axis=0, return_inverse=True)
        group = np.asarray(group).reshape(-1)
        unique_params = {n: distinct[:, j] for j, n in enumerate(sampled)}
    else:
        unique_params, group = {}, np.zeros(S, dtype=int)
    G = int(group.max()) + 1 if S else 0
    values = {u: np.full((S, times.size), np.nan) for u in problem.unknown_names}
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if S:
        def report(done: int) -> None:  # progress in samples, as for ODEs
            progress(S if done >= G else int(S * done / G))

        states, ok, msgs, model, unique, inverse = _grid_states(
            problem, unique_params, G, times, nodes=nodes, method=method, rtol=rtol, atol=atol, jobs=jobs,
            chunk_size=chunk_size, progress=report if progress is not None else None,
            max_evaluations=max_evaluations)
        at_start = unique == t0
        shape = model.grid.shape
        for g in range(G):
            rows = np.flatnonzero(group == g)
            success[rows] = ok[g]
            for i in rows:
                messages[i] = msgs[g]
            if not ok[g]:
                continue
            mats = _interpolation_matrices(model, {c: arrays[c][rows] for c in space})
            for s, u in enumerate(problem.unknown_names):
                v = _at_points(states[g, s], shape, mats)  # (Tu, P)
                values[u][rows] = v[inverse].T
        if at_start.any():  # the initial value exactly at the points
            columns = times == t0
            for s, unknown in enumerate(problem.unknowns):
                exact = np.broadcast_to(unknown.initial.evaluate(**arrays), (S,)) if unknown.initial.terms \
                    else np.zeros(S)
                values[unknown.name][np.ix_(success, columns)] = exact[success, None]
    if problem.time is None:
        values = {u: v[:, 0] for u, v in values.items()}
    return ReferenceResult(values=values, success=success, messages=messages, method=method, rtol=float(rtol),
                           atol=float(atol), times=times)

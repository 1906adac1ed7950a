"""Independent reference solutions of a problem with scipy's ``solve_ivp``.

This module exists to check codebooks (``pgd verify``, plots): it must not
share a code path with the PGD solver beyond the parsed spec, so that a bug in
operator assembly cannot cancel out. It therefore never imports
``solver``, ``basis`` or ``separated``: the equations are evaluated pointwise
from the parsed :class:`~pgdcli.expressions.Polynomial` of each equation.

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
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from .errors import SolverError

__all__ = ["METHODS", "ReferenceResult", "solve_reference", "ReferenceBudgetExceeded", "DEFAULT_MAX_EVALUATIONS"]

#: Integration methods of ``scipy.integrate.solve_ivp`` that may be used.
METHODS = ("DOP853", "RK45", "Radau", "BDF", "LSODA")

#: Right-hand-side evaluations one integration may spend before it is given up
#: (a stiff problem under an explicit method would otherwise run for hours).
DEFAULT_MAX_EVALUATIONS = 500_000


@dataclass
class ReferenceResult:
    """Reference values of every unknown at parameter samples and times.

    Attributes
    ----------
    values : dict of str to ndarray, shape (S, T)
        Unknown name -> values at sample ``i`` (row) and the ``j``-th given
        time (column), in the order the times were given. NaN where the
        sample failed.
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
    """A Separable coefficient at S parameter samples: ``static(p) + sum_i w_i(p) f_i(t)``."""

    __slots__ = ("static", "timed", "is_static")

    def __init__(self, sep, time: str, params: Mapping[str, np.ndarray], S: int) -> None:
        static = np.zeros(S)
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
        self.is_static = not self.timed

    def at(self, t: float) -> np.ndarray:
        if self.is_static:
            return self.static
        out = self.static
        for func, weight in self.timed:
            out = out + weight * float(func(t))
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
                        from .expressions import format_monomial

                        raise SolverError(
                            f"{problem.source}: equations[{r}]: '{format_monomial(monomial, time)}': der() may "
                            "only appear linearly (not multiplied by unknowns) for the reference integrator"
                        )
                    der[r].append((index[monomial[0].unknown], coef))
                else:
                    rest[r].append((tuple(index[a.unknown] for a in monomial), coef))
        self.der = der
        self.rest = rest
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
                    product = product * U[:, s, :]
                acc += product
        A = self._mass if self.static_mass else self._mass_at(t)
        if self.permutation is not None:
            D = np.empty_like(G)
            D[:, self.permutation, :] = -G / A[:, :, None]
        else:
            D = np.linalg.solve(A, -G)
        return D.reshape(y.shape)

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
    from .spec import parse_spec

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
def solve_reference(
    problem,
    params: Mapping[str, np.ndarray],
    times: np.ndarray,
    *,
    method: str = "DOP853",
    rtol: float = 1e-12,
    atol: float = 1e-12,
    jobs: int = 1,
    chunk_size: int | None = None,
    progress: Callable[[int], None] | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
) -> ReferenceResult:
    """Integrate the problem's ODEs at parameter samples with ``scipy.integrate.solve_ivp``.

    Parameters
    ----------
    problem : pgdcli.spec.Problem
        Parsed spec (linear or, with ``allow_nonlinear=True``, polynomial in
        the unknowns).
    params : dict of str to array_like, shape (S,)
        A value per sample for every non-time coordinate (``{}`` for a
        problem without parameters: one sample).
    times : array_like, shape (T,)
        Times at which to report the solution, each at or after the start
        of the time domain (where the initial values hold); any order,
        repeats allowed.
    method : str
        One of :data:`METHODS`.
    rtol, atol : float
        Tolerances of ``solve_ivp``.
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

    Returns
    -------
    ReferenceResult

    Raises
    ------
    PgdError
        Missing or extra coordinates, mismatched shapes, times before the
        start, an unknown method or invalid tolerances.
    """
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
        bounds = list(range(0, S, max(1, int(chunk_size)))) + [S]
        chunks = [np.arange(a, b) for a, b in zip(bounds[:-1], bounds[1:])]
        done = 0
        settings = (t0, unique, method, float(rtol), float(atol), int(max_evaluations))

        def store(rows, result):
            nonlocal done
            v, ok, msgs = result
            values[rows] = v
            success[rows] = ok
            for i, m in zip(rows, msgs):
                messages[i] = m
            done += rows.size
            if progress is not None:
                progress(done)

        workers = min(jobs, len(chunks))
        if workers <= 1:
            for rows in chunks:
                store(rows, _solve_group(problem, _subset(arrays, rows), rows.size, *settings))
        else:
            from concurrent.futures import ProcessPoolExecutor, as_completed

            with ProcessPoolExecutor(max_workers=workers, mp_context=_pool_context()) as pool:
                futures = {
                    pool.submit(_chunk_worker, problem.source_text, problem.source, _subset(arrays, rows),
                                rows.size, *settings): rows
                    for rows in chunks
                }
                try:
                    for future in as_completed(futures):
                        store(futures[future], future.result())
                except BaseException:
                    pool.shutdown(wait=False, cancel_futures=True)
                    raise
    return ReferenceResult(
        values={u.name: values[:, i, inverse] for i, u in enumerate(problem.unknowns)},
        success=success,
        messages=messages,
        method=method,
        rtol=float(rtol),
        atol=float(atol),
        times=times,
    )

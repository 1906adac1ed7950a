"""The ODE reference: equations compiled pointwise from their parsed polynomials
(:mod:`pgdcli.checks.reference_system`), samples integrated together by one vectorized ``solve_ivp``
per chunk, failures isolated by halving the chunk.
"""

from __future__ import annotations

import functools
import math
from functools import partial
from typing import Callable, Mapping

import numpy as np

from ..errors import SolverError
from ..problem.switches import switch_points
from .reference_base import (METHODS, ReferenceBudgetExceeded, ReferenceResult, check_tolerances, checked_params,
                             checked_times, chunk_executor, chunk_size_for, run_in_chunks, sample_subset)
from .reference_system import CompiledSystem

__all__ = ["solve_reference_vectorized", "implicit_options"]


# ----------------------------------------------------------------------------------------------
# integration of one group of samples, with failure isolation
# ----------------------------------------------------------------------------------------------
def _integrate(problem, params, S, t0, times, method, rtol, atol, max_evaluations):
    """One vectorized solve_ivp call.

    Returns (values (S, q, T) or None, failed, message): ``failed`` is a bool mask of the samples known
    to fail, or, when the whole call failed, a float score per sample (the magnitude of its state at the
    last right-hand-side call: blow-ups score highest).
    """
    from scipy.integrate import solve_ivp

    with np.errstate(all="ignore"):  # a coefficient may be infinite at some sample (1/k at k = 0)
        system = CompiledSystem(problem, params, S, max_evaluations)
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
    options = implicit_options(method, q, S)
    if method == "LSODA":
        options["lband"] = options["uband"] = q - 1
    # Integrate from output time to output time, so that every reported value is the end of a real
    # step: dense output (t_eval) of DOP853 is an order lower and was measured 30x less accurate.
    # A switch of time alone (step(t - 2)) also ends a segment: no step straddles its kink or jump.
    stops = _switch_gaps(problem, t0, float(times.max()))
    y = y0.reshape(-1)
    t_prev, step = t0, None
    try:
        with np.errstate(all="ignore"):
            for j in np.flatnonzero(late):
                t_next = float(times[j])
                for left, right in [(a, b) for a, b in stops if t_prev < b and a < t_next] + [(t_next, None)]:
                    if left > t_prev and not (right is None and any(a < left <= b for a, b in stops)):
                        first = None if step is None else min(step, left - t_prev)
                        sol = solve_ivp(system, (t_prev, left), y, method=method, rtol=rtol, atol=atol,
                                        first_step=first, **options)
                        if sol.status != 0:
                            where = f" at {problem.time} = {sol.t[-1]:.6g}" if sol.t.size else ""
                            return None, scores(system, S), f"integration failed{where}: {sol.message}"
                        y, t_prev, step = sol.y[:, -1], left, _next_step(sol.t, step)
                    if right is not None and right < t_next:  # across the switch: one Euler step past it
                        y, t_prev, step = y + (right - t_prev) * system(right, y), right, None
                values = y.reshape(S, q)
                finite = np.isfinite(values).all(axis=1)
                if not finite.all():
                    return None, ~finite, f"the solution is not finite at {problem.time} = {t_next:.6g} (blow-up)"
                out[:, :, j] = values
    except ReferenceBudgetExceeded:
        return None, scores(system, S), (
            f"gave up after {max_evaluations} right-hand side evaluations (stiff? try --method Radau or BDF)"
        )
    except (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError) as exc:
        return None, scores(system, S), f"integration failed: {' '.join(str(exc).split()) or type(exc).__name__}"
    return out, np.zeros(S, dtype=bool), ""


def _switch_gaps(problem, t0: float, t1: float) -> list[tuple[float, float]]:
    """``(left, right)`` around every switch of time alone in ``(t0, t1)``: a few units in the last place
    either side, so that the right-hand side is evaluated on one side of the switch in a segment."""
    if not problem.time:
        return []
    return [(s - 8 * np.spacing(s), s + 8 * np.spacing(s))
            for s in switch_points(problem.equations, problem.time, (t0, t1))]


def _next_step(t: np.ndarray, step: float | None) -> float | None:
    """The first step of the next segment: the last step is cut short by the segment's end, so the one
    before it."""
    steps = np.diff(t)
    if steps.size >= 2:
        return float(steps[-2])
    return float(steps[-1]) if step is None and steps.size else step


def scores(system: CompiledSystem, S: int) -> np.ndarray:
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
        v, ok, msgs = _solve_group(problem, sample_subset(params, rows), rows.size, t0, times, method, rtol, atol,
                                   max_evaluations)
        values[rows] = v
        success[rows] = ok
        for i, m in zip(rows, msgs):
            messages[i] = m
    return values, success, messages


@functools.lru_cache(maxsize=8)
def parse_cached(text: str, source: str):
    from ..problem.spec import parse_spec

    try:
        return parse_spec(text, source=source, allow_nonlinear=True)
    except TypeError:  # pragma: no cover - a parse_spec without allow_nonlinear
        return parse_spec(text, source=source)


def _chunk_worker(spec_text, source, settings, chunk):
    """A worker's task: parse the spec again, integrate one chunk ``(params, samples)``."""
    problem = parse_cached(spec_text, source)
    return _solve_group(problem, *chunk, *settings)


def solve_reference_ode(problem, params, times, *, method, rtol, atol, jobs, chunk_size, progress,
                        max_evaluations, executor=None) -> ReferenceResult:
    """:func:`solve_reference` for a problem without space coordinates: chunks of samples, each one
    vectorized ``solve_ivp`` call, failures isolated."""
    method = "DOP853" if method is None else method
    rtol = 1e-12 if rtol is None else rtol
    atol = 1e-12 if atol is None else atol
    if method not in METHODS:
        raise SolverError(f"unknown integration method {method!r}; expected one of {', '.join(METHODS)}")
    check_tolerances(rtol, atol)
    if int(jobs) < 1:
        raise SolverError(f"jobs must be at least 1, got {jobs}")
    t0 = float(problem.time_coordinate.domain[0])
    names = [c.name for c in problem.parameter_coordinates]
    arrays, S = checked_params(params, names, problem.time, [])
    times = checked_times(times, t0, problem.time)
    unique, inverse = np.unique(times, return_inverse=True)

    values = np.full((S, len(problem.unknowns), unique.size), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if S:
        settings = (t0, unique, method, float(rtol), float(atol), int(max_evaluations))
        task = partial(_chunk_worker, problem.source_text, problem.source, settings) if problem.source_text else None
        with chunk_executor(jobs, executor) as chunks:
            run_in_chunks(S, chunk_size or chunk_size_for(S), chunks, progress, values, success, messages, arrays,
                          lambda chunk: _solve_group(problem, *chunk, *settings), task)
    return ReferenceResult(
        values={u.name: values[:, i, inverse] for i, u in enumerate(problem.unknowns)},
        success=success,
        messages=messages,
        method=method,
        rtol=float(rtol),
        atol=float(atol),
        times=times,
    )




def solve_reference_vectorized(problem, params: Mapping[str, np.ndarray], S: int, times: np.ndarray, *,
                               rtol: float = 1e-13, atol: float = 1e-13, max_evaluations: int = 200_000,
                               progress: Callable[[float], None] | None = None,
                               method: str = "DOP853") -> dict[str, np.ndarray] | None:
    """All samples of an ODE problem in one DOP853 call (or ``method``: Radau for a stiff problem, with the
    block-diagonal sparsity of its Jacobian) with output at ``times``, or None.

    The fast path of :func:`solve_reference`: no failure isolation, so None when any
    sample fails (a blow-up, a singular ``der()`` coefficient, the evaluation budget);
    the caller then falls back to :func:`solve_reference`. A switch of time alone
    (``step(t - 1.7)``) ends a call, as in :func:`solve_reference`: no step straddles its jump,
    which an implicit method at a tight tolerance cannot cross. ``progress(t)`` is told the
    time the integration reached, every hundredth of the time domain.

    Returns
    -------
    dict of str to ndarray, shape (S, T), or None
    """
    from scipy.integrate import solve_ivp

    names = list(problem.unknown_names)
    try:
        with np.errstate(all="ignore"):
            system = CompiledSystem(problem, params, S, max_evaluations=max_evaluations)
            y0 = system.initial(problem, params)
            if system.bad.any() or not np.isfinite(y0).all():
                return None
            fun = system if progress is None else _reporting(system, float(times[0]), float(times[-1]), progress)
            y = _across_switches(problem, fun, y0.reshape(-1), times, dict(
                method=method, rtol=rtol, atol=atol, **implicit_options(method, system.q, S)))
    except (ReferenceBudgetExceeded, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError):
        return None
    if y is None or not np.isfinite(y).all():
        return None
    values = y.reshape(S, len(names), times.size)
    return {u: values[:, i, :] for i, u in enumerate(names)}


def _across_switches(problem, fun, y0: np.ndarray, times: np.ndarray, options: dict) -> np.ndarray | None:
    """``y0`` integrated with output at the sorted ``times``, one ``solve_ivp`` call per segment between
    switches of time alone; across a switch one Euler step (a time inside its gap takes the value before
    it, as :func:`_integrate` does). Returns shape ``(y0.size, T)``, or None when a call fails."""
    from scipy.integrate import solve_ivp

    out = np.empty((y0.size, times.size))
    y, start = y0, float(times[0])
    for left, right in _switch_gaps(problem, start, float(times[-1])) + [(float(times[-1]), None)]:
        inside = (times >= start) & (times <= left)
        if left > start:
            stops = np.union1d(times[inside], [start, left])
            sol = solve_ivp(fun, (start, left), y, t_eval=stops, **options)
            if sol.status != 0 or sol.y.shape[1] != stops.size:
                return None
            out[:, inside] = sol.y[:, np.searchsorted(stops, times[inside])]
            y = sol.y[:, -1]
        else:  # a switch within a few units in the last place of the start
            out[:, inside] = y[:, None]
        if right is not None:
            out[:, (times > left) & (times < right)] = y[:, None]
            y, start = y + (right - left) * fun(right, y), right
    return out


def implicit_options(method: str, q: int, S: int) -> dict:
    """solve_ivp's options of an implicit method on S independent samples of q unknowns: their Jacobian is
    block diagonal (finite differences of few columns each), and the right-hand side vectorized."""
    if method not in ("Radau", "BDF"):
        return {}
    from scipy.sparse import block_diag

    return {"jac_sparsity": block_diag([np.ones((q, q))] * S, format="csc"), "vectorized": True}


def _reporting(system, t0: float, t1: float, progress: Callable[[float], None]):
    """``system`` as a right-hand side that tells ``progress`` the time reached, every hundredth of [t0, t1]."""
    every = 0.01 * (t1 - t0)
    told = [t0]

    def fun(t, y):
        if t >= told[0] + every:
            told[0] = t
            progress(t)
        return system(t, y)

    return fun

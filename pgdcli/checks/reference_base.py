"""What the ODE and the PDE references share: settings, result types, argument checks, chunks over
an executor's workers (:mod:`pgdcli.executors`). Imports nothing of the solvers (see :mod:`pgdcli.checks.reference`).
"""

from __future__ import annotations

import math
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import partial
from typing import Callable, Mapping

import numpy as np

from .. import executors
from ..blas import one_blas_thread
from ..errors import SolverError

__all__ = ["METHODS", "PDE_METHODS", "ReferenceResult", "ReferenceBudgetExceeded", "ReferenceTimeUp", "time_budget",
           "check_deadline", "count_evaluation", "under_deadline", "DEFAULT_MAX_EVALUATIONS", "DEFAULT_SPACE_NODES", "TIME_UP"]

#: The message of a sample not integrated because the time budget ran out.
TIME_UP = "not checked: the time budget ran out"


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


class ReferenceTimeUp(Exception):
    """Raised inside an integration when the check's time budget has run out (no retries follow)."""


#: The monotonic time at which reference integrations stop (:func:`time_budget`); inf: never.
_DEADLINE = [math.inf]


def set_deadline(at: float) -> None:
    """Stop reference integrations at monotonic time ``at`` (also a worker process's initializer)."""
    _DEADLINE[0] = float(at)


def check_deadline() -> None:
    """Raise :class:`ReferenceTimeUp` once the deadline has passed (called from right-hand sides)."""
    if time.monotonic() > _DEADLINE[0]:
        raise ReferenceTimeUp


def count_evaluation(system, y) -> None:
    """Count one right-hand-side evaluation of ``system`` (its ``evaluations``, ``max_evaluations``,
    ``last_y``): ReferenceBudgetExceeded past the budget, the deadline checked every 64 calls."""
    system.evaluations += 1
    system.last_y = y
    if system.evaluations > system.max_evaluations:
        raise ReferenceBudgetExceeded
    if system.evaluations & 63 == 1:
        check_deadline()


@contextmanager
def time_budget(seconds: float | None):
    """Reference integrations inside stop after ``seconds`` (None: no budget), raising
    :class:`ReferenceTimeUp`; samples not integrated by then are reported as not checked."""
    saved = _DEADLINE[0]
    _DEADLINE[0] = math.inf if seconds is None else min(saved, time.monotonic() + float(seconds))
    try:
        yield
    finally:
        _DEADLINE[0] = saved


def sample_subset(params: Mapping[str, np.ndarray], rows: np.ndarray) -> dict[str, np.ndarray]:
    return {name: values[rows] for name, values in params.items()}



#: Chunks a reference's samples are cut into (64 to 1024 samples each) whatever runs them: one vectorized
#: ``solve_ivp`` call's steps depend on its chunk, so the same chunks give the same floats here, in a
#: pool of processes and on a cluster.
CHUNKS = 16


def chunk_size_for(n_samples: int) -> int:
    """Samples per chunk of a reference: :data:`CHUNKS` chunks of 64 to 1024 samples."""
    return min(1024, max(64, math.ceil(n_samples / CHUNKS)))


@contextmanager
def chunk_executor(jobs: int, executor=None):
    """The executor of a reference's chunks: ``executor`` if given, else a pool of ``jobs`` local processes
    (closed after the block) when ``jobs`` > 1, else the one in effect (:func:`pgdcli.executors.current`)."""
    if executor is not None:
        yield executors.as_executor(executor)
    elif int(jobs) > 1:
        with executors.ProcessExecutor(int(jobs)) as pool:
            yield pool
    else:
        yield executors.current()


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------

def run_in_chunks(n_samples: int, chunk_size: int, executor, progress, values: np.ndarray, success: np.ndarray,
                  messages: list, params: Mapping[str, np.ndarray], solve_here: Callable,
                  task: Callable | None) -> None:
    """Solve the samples chunk by chunk, here or by the executor's workers, storing every result.

    ``solve_here(chunk)`` (in this process, the problem as parsed here) and ``task(chunk)`` (picklable: a
    worker parses the spec again), where ``chunk`` is ``(params of its samples, number of samples)``,
    return ``(values, success, messages)`` of the chunk's samples; they are written into the given
    arrays, and ``progress`` (if any) is told the number of samples finished. Every chunk runs on one
    BLAS thread, wherever it runs, and under the time budget (:func:`time_budget`): the samples of a
    chunk it stopped are not checked (:data:`TIME_UP`).
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

    def time_up(rows):
        for i in rows:
            messages[i] = TIME_UP

    items = ((sample_subset(params, rows), rows.size) for rows in chunks)
    if task is None or isinstance(executor, executors.SerialExecutor) or len(chunks) == 1:
        with one_blas_thread():
            for k, (rows, item) in enumerate(zip(chunks, items)):
                try:
                    store(rows, solve_here(item))
                except ReferenceTimeUp:
                    for rest in chunks[k:]:
                        time_up(rest)
                    return
        return
    for i, future in executor.as_completed(under_deadline(task), items):
        try:
            store(chunks[i], future.result())
        except ReferenceTimeUp:
            time_up(chunks[i])


def under_deadline(task: Callable) -> Callable:
    """``task`` for a worker, which may be another process or machine, under this process's time budget."""
    return partial(_before_deadline, _wall_deadline(), task)


def _wall_deadline() -> float:
    """The deadline in this machine's wall-clock time (comparable on a worker elsewhere); inf: none."""
    left = _DEADLINE[0] - time.monotonic()
    return time.time() + left if math.isfinite(left) else math.inf


def _before_deadline(deadline: float, task: Callable, chunk):
    """A worker's chunk under the deadline (wall-clock time, see :func:`_wall_deadline`)."""
    saved = _DEADLINE[0]
    set_deadline(time.monotonic() + (deadline - time.time()) if math.isfinite(deadline) else math.inf)
    try:
        return task(chunk)
    finally:
        _DEADLINE[0] = saved


def space_coordinates(problem) -> tuple:
    """The coordinates of the problem with role ``'space'`` (spec order)."""
    return tuple(c for c in problem.coordinates if getattr(c, "role", "parameter") == "space")


def sampled_coordinates(problem) -> tuple:
    """The coordinates sampled by a reference: neither time nor space."""
    return tuple(c for c in problem.coordinates if c.name != problem.time and getattr(c, "role", "") != "space")


def check_tolerances(rtol, atol) -> None:
    for label, value in (("rtol", rtol), ("atol", atol)):
        if isinstance(value, bool) or not (isinstance(value, (int, float, np.floating)) and math.isfinite(value)
                                           and 0 < value < 1):
            raise SolverError(f"{label} must be a number in (0, 1), got {value!r}")


def checked_times(times, t0: float, time: str) -> np.ndarray:
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if times.ndim != 1 or times.size == 0:
        raise SolverError(f"times: expected a non-empty 1-D array, got shape {times.shape}")
    if not np.isfinite(times).all():
        raise SolverError("times: values must be finite")
    if (times < t0).any():
        raise SolverError(f"times: {float(times.min())!r} is before the start {time} = {t0:g} of the time domain")
    return times


def checked_params(params: Mapping[str, np.ndarray], names: list[str], time: str, others: list[str],
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


def start_time(problem) -> float:
    """The start of the time domain; -inf for a steady problem (every time is 'late')."""
    return -np.inf if problem.time is None else float(problem.time_coordinate.domain[0])


def reference_times(problem, times) -> np.ndarray:
    """Validated times; a steady problem takes ``None`` and gets one placeholder time."""
    if problem.time is None:
        if times is not None:
            raise SolverError(f"{problem.source}: times: a steady problem (no time coordinate) takes times=None")
        return np.zeros(1)
    if times is None:
        raise SolverError("times: expected a non-empty 1-D array of times, got None")
    return checked_times(times, start_time(problem), problem.time)

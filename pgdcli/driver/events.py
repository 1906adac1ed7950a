"""Events after a solve: each event's time as a field of the parameters, measured against scipy.

A codebook within its tolerance gets, for every event of its spec, the time of the event's first
crossing located on the codebook (:func:`pgdcli.algorithms.events.event_field`) and compressed over the
grid of parameter nodes; :func:`pgdcli.checks.events.check_events` then measures these times against
``solve_ivp``'s event location at the check sample. An event time that misses the tolerance makes the
solve's result inaccurate (nothing is written silently); an event that does not happen everywhere
in the box is refused with the point where it does not.
"""

from __future__ import annotations

import dataclasses
import time as _time

import numpy as np

from ..algorithms.events import event_field
from ..algorithms.outcome import Status
from ..algorithms.result import SolveResult
from ..checks.check import reference_stiffness
from ..checks.events import check_events
from ..codebook.events import EventTime
from ..errors import SolverError
from ..progress import PhaseStarted, emit
from .method import Settings

__all__ = ["record_events", "FIELD_SHARE"]

#: The event field's own (compression) error, as a share of the tolerance: the rest is the codebook's.
FIELD_SHARE = 0.05


def _refused(result: SolveResult, status: Status, message: str, accurate) -> SolveResult:
    rep = result.codebook.report
    rep.update(converged=False, status=int(status), message=message)
    if accurate is not None:
        rep["accurate"] = int(accurate)
    return dataclasses.replace(result, converged=False, status=status, message=message, accurate=accurate)


def record_events(problem, result: SolveResult, settings: Settings, callback=None) -> SolveResult:
    """The result with its codebook's events located and checked (unchanged without events or when refused).

    Returns
    -------
    SolveResult
        With ``codebook.events`` and the report's ``events``, ``event_errors`` and ``event_ratios``;
        status :attr:`Status.INACCURATE` when an event time misses the tolerance, :attr:`Status.FAILED` when
        an event cannot be stored (it does not happen at some parameter node, or jumps).
    """
    if not problem.events or not result.converged:
        return result
    started = _time.perf_counter()
    result = _record(problem, result, settings, callback)
    rep = result.codebook.report
    spent = _time.perf_counter() - started
    rep["wall_time"] = float(rep.get("wall_time", result.wall_time)) + spent
    return dataclasses.replace(result, wall_time=result.wall_time + spent)


def _record(problem, result: SolveResult, settings: Settings, callback) -> SolveResult:
    cb = result.codebook
    names = ", ".join(e.name for e in problem.events)
    emit(callback, PhaseStarted("events", f"locating the events ({names}) on the codebook"))
    events = {}
    try:
        for event in problem.events:
            coordinates, train, _ = event_field(problem, cb, event, FIELD_SHARE * settings.tolerance)
            events[event.name] = EventTime(event.text, event.direction, tuple(coordinates), train)
    except SolverError as exc:
        return _refused(result, Status.FAILED, f"not converged: {exc}", None)
    cb = cb.with_events(events)
    result = dataclasses.replace(result, codebook=cb)
    emit(callback, PhaseStarted("check", f"event times against scipy's event location ({names})"))
    stiff = reference_stiffness(problem, cb).stiff  # as the error gate decides
    checking = _time.perf_counter()
    checks = check_events(problem, cb, tolerance=settings.tolerance, relative_tolerance=settings.relative_tolerance,
                          stiff=stiff)
    rep = cb.report
    rep["gate_time"] = float(rep.get("gate_time", 0.0)) + _time.perf_counter() - checking
    rep["events"] = ",".join(c.name for c in checks)
    rep["event_errors"] = np.array([c.error for c in checks])
    rep["event_ratios"] = np.array([c.ratio for c in checks])
    unchecked = [c.name for c in checks if not c.points]
    if unchecked:
        return dataclasses.replace(result, warnings=result.warnings + [
            f"the time of event {unchecked[0]!r} could not be checked: the reference failed at every point"])
    worst = max(checks, key=lambda c: c.ratio)
    if worst.ratio > 1.0:
        where = ", ".join(f"{k}={v:.6g}" for k, v in worst.where.items())
        what = ("no event there in scipy's reference" if not np.isfinite(worst.error)
                else f"error {worst.error:.3g} ({worst.ratio:.2g} x the tolerance)")
        return _refused(result, Status.INACCURATE,
                        f"tolerance not met: the time of event {worst.name!r}: {what} at {where or 'the start'}, "
                        f"and the reference state there is off the event's surface by more than the tolerance",
                        False)
    result = dataclasses.replace(result, message=result.message + f"; event times within {worst.ratio:.2g} x the "
                                                                  f"tolerance")
    rep["message"] = result.message
    return result

"""Solving a problem whose event acts: a terminal event, or a reset (a bounce) and its phases.

A terminal event ends the motion: the codebook is the problem's own, with the event's time, and
its values after the event do not exist. A reset (``then:``) makes the solution piecewise smooth in
time with jumps at parameter-dependent times, which one separated representation over time and the
parameters would resolve badly; it is solved phase by phase (:mod:`pgdcli.codebook.phases`):

1. scipy's reference (``solve_ivp`` stopped at the event and restarted from the reset state,
   :func:`pgdcli.checks.phases.reference_motion`) at the corners, faces and random points of the box
   counts the events before the end time, ``n - 1`` at most (more than :data:`MAX_PHASES` phases: a
   Zeno motion, refused with the point); each of the ``n`` phases is solved to ``tolerance / n`` (an
   error of a phase is carried into the next one's initial state, and they add up);
2. phase 0 is the problem itself, with the event's time ``t_1(p)``; phase ``k`` is the same
   equations in the local time ``t - t_k(p)``, started from the reset of phase ``k-1``'s state at its
   event (a function of the parameters, separated on the nodes like any joint initial value), over a
   span that reaches the end time everywhere and the phase's own event everywhere (lengthened when
   it does not); each phase is solved, checked and its event located as any codebook;
3. phases are added until the next event is after the end time everywhere in the box;
4. the phased codebook is measured against the reference at times across all phases
   (:func:`pgdcli.checks.phases.check_phases`): a codebook that misses the tolerance is refused.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from ..algorithms.outcome import Status
from ..checks.phases import check_phases, phase_sample, reference_motion
from ..codebook.codebook import Codebook
from ..codebook.phases import MAX_PHASES, PhasedCodebook
from ..errors import SolverError
from ..problem.events import acting_event, reset_values
from ..problem.separable import Separable
from ..problem.tabulated import TabulatedFunction, TabulatedInitial
from ..progress import PhaseStarted, emit
from .events import record_events
from .refinement import solve_rounds

__all__ = ["solve_phased", "MAX_PHASES", "SPAN_MARGIN", "DENSE_POINTS"]

#: A phase's span is this many times the longest time to its event seen by the reference.
SPAN_MARGIN = 1.25
#: Random points at which the earliest next event time is looked for (besides corners and faces).
DENSE_POINTS = 2000


def solve_phased(problem, choice, settings, callback=None):
    """The :class:`~pgdcli.algorithms.result.SolveResult` of a problem with an acting event (or None without).

    Raises
    ------
    SolverError
        A Zeno motion: more than :data:`MAX_PHASES` events before the end time at a point (named).
    """
    event = acting_event(problem.events)
    if event is None:
        return None
    started = time.perf_counter()
    if event.terminal:
        result, _ = solve_rounds(problem, choice, settings, callback)
        result = record_events(problem, result, settings, callback)
        return _wrapped(result, event, []) if result.converged else _unwritable(result, "")
    count = _count_phases(problem)
    share = dataclasses.replace(settings, tolerance=settings.tolerance / count)
    emit(callback, PhaseStarted("solve", f"{count} phases at most ({event.name!r} resets the motion); each to "
                                         f"{share.tolerance:.3g}", 1))
    result, _ = solve_rounds(problem, choice, share, callback)
    result = record_events(problem, result, share, callback)
    books = [result.codebook]
    spans = []
    while result.converged and _earliest(problem, books) < problem.coordinate(problem.time).domain[1]:
        if len(books) >= MAX_PHASES:
            raise SolverError(f"event {event.name!r} happens more than {MAX_PHASES - 1} times before the end "
                              f"time somewhere in the box: the events pile up (a Zeno motion); shorten the time "
                              f"domain or narrow the parameters' domains")
        emit(callback, PhaseStarted("solve", f"phase {len(books)}: after event {event.name!r} "
                                             f"number {len(books)}", 1))
        phase, result = _next_phase(problem, choice, share, books, callback)
        books.append(result.codebook)
        spans.append(phase.coordinate(problem.time).domain[1])
    if not result.converged:
        return _unwritable(result, f"phase {len(books) - 1}: ")
    result = _checked(problem, _wrapped(result, event, books[1:], first=books[0]), settings, spans, callback)
    spent = time.perf_counter() - started  # every phase's solve and check
    result.codebook.report["wall_time"] = spent
    return dataclasses.replace(result, wall_time=spent)


def _unwritable(result, where: str):
    """A failed phase: its codebook is one phase's, which would be read past its event, so it is not written
    (status FAILED, accuracy not claimed, whatever --keep-inaccurate says)."""
    message = f"{where}{result.message} (a codebook whose event acts is written only whole and within its tolerance)"
    return dataclasses.replace(result, converged=False, status=Status.FAILED, accurate=None, message=message)


def _count_phases(problem) -> int:
    """Phases the reference needs at the corners, faces and random points (Zeno refused, with the point)."""
    event = acting_event(problem.events)
    t1 = problem.coordinate(problem.time).domain[1]
    points = phase_sample(problem, 16)
    S = next(iter(points.values())).size if points else 1
    most = 1
    for i in range(S):
        params = {n: v[i:i + 1] for n, v in points.items()}
        motion = reference_motion(problem, params, most=MAX_PHASES)
        count = sum(1 for e in motion.events if e <= t1) + 1
        if count > MAX_PHASES:
            where = ", ".join(f"{n}={v[0]:.6g}" for n, v in params.items()) or "the start"
            raise SolverError(f"event {event.name!r} happens more than {MAX_PHASES - 1} times before "
                              f"{problem.time}={t1:g} at {where}: the events pile up (a Zeno motion); shorten the "
                              f"time domain or narrow the parameters' domains")
        most = max(most, count)
    return most


def _event_times(books: list, params: dict) -> np.ndarray:
    """``t_k(p)``, the acting event's k-th time (k = len(books)), at points (the phases' times summed; a
    reset is its spec's only event)."""
    total = 0.0
    for book in books:
        total = total + np.asarray(book.event_times(params)[next(iter(book.events))], dtype=float)
    return total


def _dense(problem) -> dict:
    return phase_sample(problem, DENSE_POINTS, seed=3)


def _earliest(problem, books: list) -> float:
    """The smallest next event time over corners, faces and random points of the box."""
    points = _dense(problem)
    return float(np.min(_event_times(books, points))) if points else float(_event_times(books, {}))


def _reset_state(problem, books: list):
    """params (flat arrays) -> the state after the latest event, per unknown (cached for the unknowns)."""
    event = acting_event(problem.events)
    tname, last = problem.time, books[-1]
    cache = {}

    def state(params: dict) -> dict:
        key = tuple((n, v.tobytes()) for n, v in sorted(params.items()))
        if key not in cache:
            cache.clear()
            local = np.asarray(last.event_times(params, [event.name])[event.name], dtype=float)
            before = last.evaluate({**params, tname: local})
            cache[key] = reset_values(event, before, {**params, tname: _event_times(books, params)})
        return cache[key]

    return state


def _phase_problem(problem, books: list, span: float):
    """Phase ``len(books)``: the same equations on ``[0, span]``, from the state after the latest event."""
    event = acting_event(problem.events)
    state = _reset_state(problem, books)
    names = [c.name for c in problem.coordinates if c.role != "time"]
    k = len(books)
    unknowns = []
    for u in problem.unknowns:
        text = f"{u.name} after event {event.name!r} number {k}"
        if names:
            initial = TabulatedInitial(TabulatedFunction(lambda values, u=u.name: state(values)[u], names, text))
        else:
            initial = Separable.constant(float(np.asarray(state({})[u.name]).reshape(-1)[0]))
        unknowns.append(dataclasses.replace(u, initial=initial, initial_text=text))
    coordinates = tuple(dataclasses.replace(c, domain=(0.0, float(span))) if c.role == "time" else c
                        for c in problem.coordinates)
    return dataclasses.replace(problem, name=f"{problem.name}_phase{k}", coordinates=coordinates,
                               unknowns=tuple(unknowns), events=(dataclasses.replace(event, reset=()),))


def _span(problem, books: list) -> float:
    """The local span of the next phase: to the end time where its start is earliest, and to its own event
    (with :data:`SPAN_MARGIN`) where the reference's is latest."""
    t0, t1 = problem.coordinate(problem.time).domain
    points = phase_sample(problem, 16)
    k = len(books)
    longest = 0.0
    S = next(iter(points.values())).size if points else 1
    for i in range(S):
        motion = reference_motion(problem, {n: v[i:i + 1] for n, v in points.items()}, beyond=True, most=k + 1)
        if len(motion.events) > k:
            longest = max(longest, motion.events[k] - motion.events[k - 1])
    start = float(np.min(_event_times(books, _dense(problem)))) if points else float(_event_times(books, {}))
    return max(t1 - start, SPAN_MARGIN * longest, 1e-3 * (t1 - t0))


def _next_phase(problem, choice, settings, books: list, callback):
    span = _span(problem, books)
    for _ in range(4):
        phase = _phase_problem(problem, books, span)
        result, _ = solve_rounds(phase, choice, settings, callback)
        if result.converged:
            result = record_events(phase, result, settings, callback)
        if result.converged or "does not happen before" not in result.message:
            return phase, result
        span *= 1.5  # the phase's event is later than its span somewhere: a longer phase
    return phase, result


def _wrapped(result, event, phases: list, first=None):
    cb = first if first is not None else result.codebook
    phased = PhasedCodebook(cb.coordinates, cb.fields, name=cb.name, spec_text=cb.spec_text, report=cb.report,
                            description=cb.description, created=cb.created, events=cb.events, acting=event.name,
                            action="terminal" if event.terminal else "reset",
                            phases=[Codebook(p.coordinates, p.fields, name=p.name, events=p.events, report=p.report)
                                    for p in phases])
    return dataclasses.replace(result, codebook=phased)


def _checked(problem, result, settings, spans: list, callback):
    """The phased codebook against scipy's restarted reference; refused (INACCURATE) when it misses."""
    cb = result.codebook
    emit(callback, PhaseStarted("check", f"the {len(cb.phases) + 1} phases against scipy's restarted reference"))
    check = check_phases(problem, cb, tolerance=settings.tolerance, relative_tolerance=settings.relative_tolerance)
    rep = cb.report
    rep.update(tolerance=float(settings.tolerance), phases=len(cb.phases) + 1, phase_spans=np.array(spans, float),
               phase_error=check.error, phase_ratio=check.ratio, phase_points=check.points)
    if check.points == 0:
        return dataclasses.replace(result, warnings=result.warnings + [
            "the phases could not be checked: the restarted reference failed at every point"])
    if check.ratio > 1.0:
        where = ", ".join(f"{k}={v:.6g}" if k != "event" else f"event {v}" for k, v in check.where.items())
        message = (f"tolerance not met: the phases' error {check.error:.3g} ({check.ratio:.2g} x the tolerance) "
                   f"at {where} against the restarted reference")
        rep.update(converged=False, status=int(Status.INACCURATE), message=message, accurate=0)
        return dataclasses.replace(result, converged=False, status=Status.INACCURATE, message=message,
                                   accurate=False)
    message = result.message + f"; {len(cb.phases) + 1} phases within {check.ratio:.2g} x the tolerance"
    rep["message"] = message
    return dataclasses.replace(result, message=message)


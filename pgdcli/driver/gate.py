"""The error gate: measure a solve against the independent reference, and the result that says what was measured.

:func:`measure` runs the check of :mod:`pgdcli.checks.check` (scipy's DOP853 for ODE problems, Radau for stiff
ones, the method of lines for problems with space coordinates or steady ones) and turns what it could not do
into warnings; :func:`kept_result` and :func:`finish` write the report of the codebook kept, and its message.
"""

from __future__ import annotations

import dataclasses
import time as _time

import numpy as np

from ..algorithms.outcome import SolverOutcome, Status
from ..algorithms.result import SolveResult
from ..checks import check as checks
from ..checks.resolution import resolution_tails
from ..errors import PgdError
from ..progress import PhaseStarted, emit
from .method import Kept, Settings

__all__ = ["measure", "failed_result", "kept_result", "finish"]


def measure(problem, codebook, settings: Settings, callback=None, solve: int = 1) -> tuple[object, list[str]]:
    """The codebook's error against the independent reference, and warnings on what could not be measured.

    When the reference cannot integrate the problem at all, the solve stands unchecked
    (a :func:`~pgdcli.checks.check.unchecked` result) and a warning says why.

    Returns
    -------
    check : pgdcli.checks.check.CheckResult
    warnings : list of str
    """
    pde = any(c.role == "space" for c in problem.coordinates) or problem.time is None
    try:
        # stiff (a decay rate far faster than the solution varies): an explicit reference would crawl at its
        # stability limit, an implicit one takes the steps accuracy needs
        options = {} if pde else {"stiff": checks.reference_stiffness(problem, codebook)}
        stiff = not pde and options["stiff"].stiff
        what = "the method-of-lines reference" if pde else f"scipy's {checks.STIFF_METHOD if stiff else 'DOP853'}"
        emit(callback, PhaseStarted("check", f"error gate against {what}", solve))
        run = checks.check_codebook_pde if pde else checks.check_codebook
        check = run(problem, codebook, tolerance=settings.tolerance, relative_tolerance=settings.relative_tolerance,
                    progress=callback, **options)
    except PgdError as exc:  # the reference cannot integrate this problem: say so, keep the solve
        reason = " ".join(str(exc).split())
        return (checks.unchecked(reason, settings.tolerance, settings.relative_tolerance),
                [f"the codebook's error could not be checked against scipy: {reason}"])
    if check.failed and not check.points:
        return check, [f"the reference integration failed at all {check.failed} check points: the error is not "
                       f"measured"]
    if check.failed:
        return check, [f"the reference integration failed at {check.failed} of {check.failed + check.points} check "
                       f"points; they are not in the measured error"]
    return check, []


def failed_result(outcome: SolverOutcome, entries: dict) -> SolveResult:
    """The result of a solve that failed: the solver's outcome, its report completed with ``entries``."""
    outcome.codebook.report.update(entries)
    return SolveResult(outcome.codebook, False, outcome.status, outcome.message, outcome.residuals,
                       outcome.iterations, outcome.wall_time)


def kept_result(kept: Kept, entries: dict, settings: Settings) -> SolveResult:
    """The result of the try kept at one set of nodes, with the round's report ``entries`` and the Chebyshev
    tails per unknown and coordinate.

    The tails estimate the interpolation error between nodes. The measured error decides
    (:mod:`pgdcli.adapt`); the tails are reported, and they give warnings only when the error
    could not be measured.
    """
    attempt = kept.attempt
    outcome, check = attempt.outcome, attempt.check
    cb = outcome.codebook
    cb.report.update(entries)
    warnings = attempt.warnings + kept.notes
    tails = resolution_tails(cb)
    names = cb.coordinate_names
    cb.report["resolution"] = np.array([[tails[u][c] for c in names] for u in cb.unknown_names])
    cb.report["resolution_coordinates"] = ",".join(names)
    if not check.checked:
        for u in cb.unknown_names:
            for c in names:
                tail = tails[u][c]
                if np.isfinite(tail) and tail > settings.tolerance:
                    warnings.append(f"coordinate {c!r} may be under-resolved for {u!r}: Chebyshev tail {tail:.2g} > "
                                    f"{settings.tolerance:.2g}; add nodes to {c!r}")
    # a solve stopped at max_modes whose error beats the converged one's is kept: the measured error decides
    return SolveResult(cb, True, Status.CONVERGED, outcome.message, outcome.residuals, outcome.iterations,
                       outcome.wall_time, warnings, check)


def finish(result: SolveResult, solved: str, resolution, verdict, started: float,
           check_seconds: float = 0.0) -> SolveResult:
    """The result with its verdict: the report's check and resolution entries, the message, the status.

    ``solved`` is the solver's part of the message (:meth:`~pgdcli.driver.method.Method.summary`);
    ``resolution`` is the :class:`~pgdcli.adapt.Resolution` that gave ``verdict``; ``check_seconds``
    the time the error gate took over all the solves (the report's ``gate_time``).
    """
    check, cb = result.check, result.codebook
    rep = cb.report
    rep.update(check.report_entries())
    rep["accurate"] = -1 if verdict.accurate is None else int(verdict.accurate)
    rep.update(resolution.report_entries(verdict.reason))
    wall = rep["wall_time"] = _time.perf_counter() - started
    rep["gate_time"] = float(check_seconds)
    tol = _tolerance_text(check)
    if verdict.accurate is False:
        where = ", ".join(f"{k}={v:.6g}" for k, v in check.where.items())
        message = (f"tolerance not met: max abs error {check.error:.3g} ({check.ratio:.2g} x {tol}) at {where}; "
                   f"{verdict.reason}")
        rep.update(converged=False, status=int(Status.INACCURATE), message=message)
        return dataclasses.replace(result, converged=False, status=Status.INACCURATE, message=message,
                                   accurate=False, wall_time=wall)
    if verdict.accurate is None:
        measured = f"not checked against scipy ({tol}; see the warnings)"
    else:
        measured = (f"max abs error {check.error:.3g} at {checks.points_text(check.points)} against scipy "
                    f"({check.ratio:.2g} x {tol})")
    if len(resolution.rounds) > 1:
        solved += f", nodes chosen in {len(resolution.rounds)} solves"
    message = f"converged: {solved}, {measured}"
    rep["message"] = message
    return dataclasses.replace(result, message=message, accurate=verdict.accurate, wall_time=wall)


def _tolerance_text(check) -> str:
    if check.relative_tolerance:
        return f"tolerance {check.tolerance:.3g} + {check.relative_tolerance:.3g} |u|"
    return f"tolerance {check.tolerance:.3g}"

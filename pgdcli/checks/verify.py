"""Check a codebook against an independent reference (``pgd verify``).

The problem stored in the codebook (its embedded spec) is integrated again
with scipy's ``solve_ivp`` (:mod:`pgdcli.checks.reference`, which shares no code with
the PGD solver) at sample points of the parameter box, and the codebook is
compared with it at every time node of the codebook's time grid plus random
times.

Problems with space coordinates (``der(u, x)``, boundary conditions): the
space coordinates are not sampled; the reference is the method of lines of
:func:`pgdcli.checks.reference.solve_reference_pde` (Chebyshev collocation, BDF), and
at every parameter point and time both are compared on the tensor grid of, per
space coordinate, every node of that coordinate in the codebook plus
``space_points`` random points of its domain (seeded). ``where`` then names the
space coordinates too; the settings gain ``space_points`` (points per space
coordinate), ``random_space_points`` and ``space_nodes`` (collocation nodes of
the reference per space coordinate).

Sample points: ``samples`` scrambled Sobol (or Latin hypercube) points of the
parameter box (the coordinates other than time and space), plus all ``2**m``
corners of the box (at most :data:`MAX_CORNERS`; beyond that a seeded random
subset of corners), or the points of a CSV file instead.

Figures, per unknown ``u``, over every successful sample point and time:

- ``max_abs_error = max |u_codebook - u_reference|``
- ``reference_scale = max |u_reference|``
- ``max_rel_error = max_abs_error / reference_scale`` (relative to the
  unknown's magnitude, not pointwise: a pointwise ratio explodes where the
  solution crosses zero)
- ``rms_error = sqrt(mean((u_codebook - u_reference)**2))``
- ``where``: all coordinates (time included) of the largest error.
- ``tolerance_ratio = max |u_codebook - u_reference| / (tolerance + relative_tolerance |u_reference|)``
  with the codebook's own tolerance: the promise holds at the checked points when it is at most 1.

The gate: with ``max_error`` and/or ``max_rel_error`` those thresholds; without either, the
codebook's own tolerance (every ``tolerance_ratio`` at most 1). Either way, every reference
integration must succeed. The JSON schema is in the user guide (``pgd verify``).
"""

from __future__ import annotations

import math
import os
import time as _time
from types import SimpleNamespace
from typing import Callable, Mapping

import numpy as np

from .. import executors
from ..codebook.codebook import Codebook
from ..errors import CodebookError, VerifyError
from .events import check_events
from .phases import phase_values
from .compare import UnknownErrors, codebook_at_samples, codebook_on_space_grid, error_statistics
from .reference import DEFAULT_SPACE_NODES, METHODS, PDE_METHODS, solve_reference, solve_reference_pde
from .reference_base import TIME_UP, chunk_executor, time_budget
from .sampling import (DEFAULT_RANDOM_SPACE_POINTS, MAX_CORNERS, SAMPLINGS, check_times, default_samples,
                       parameter_points, sampled_coordinates, space_coordinates, space_points_grid)
from .stiffness import decide_stiffness
from .verify_report import Failure, VerifyReport
from .reference_pde_nonlinear import is_nonlinear_pde, solve_reference_nonlinear_grid

__all__ = ["verify", "VerifyReport", "UnknownErrors", "Failure", "VerifyError", "MAX_CORNERS", "SAMPLINGS"]


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _check_int(name: str, value, low: int) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise VerifyError(f"{name} must be an integer >= {low}, got {value!r}")
    return int(value)


def _check_tolerance(name: str, value) -> float | None:
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise VerifyError(f"{name} must be a number >= 0, got {value!r}") from None
    if not (math.isfinite(number) and number >= 0):
        raise VerifyError(f"{name} must be a finite number >= 0, got {value!r}")
    return number


def _parse_problem(cb, source: str):
    from ..problem.spec import parse_spec

    if not cb.spec_text.strip():
        raise CodebookError(f"{source}: the codebook holds no problem spec; it cannot be verified")
    try:
        problem = parse_spec(cb.spec_text, source=source, allow_nonlinear=True)
    except TypeError:  # pragma: no cover - a parse_spec without allow_nonlinear
        problem = parse_spec(cb.spec_text, source=source)
    spec_coords = [(c.name, tuple(map(float, c.domain))) for c in problem.coordinates]
    cb_coords = [(c.name, tuple(map(float, c.domain))) for c in cb.coordinates]
    if spec_coords != cb_coords:
        raise CodebookError(f"{source}: the embedded spec's coordinates {spec_coords} do not match the codebook's "
                            f"{cb_coords}")
    missing = [u for u in problem.unknown_names if u not in cb.fields]
    if missing:
        raise CodebookError(f"{source}: the codebook lacks the unknown(s) {', '.join(missing)} of its spec")
    return problem


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------
def verify(
    codebook,
    *,
    samples: int | None = None,
    sampling: str = "sobol",
    seed: int = 0,
    points: str | os.PathLike | Mapping[str, object] | None = None,
    times: int = 16,
    method: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    jobs: int | None = None,
    max_error: float | None = None,
    max_rel_error: float | None = None,
    max_corners: int = MAX_CORNERS,
    progress: Callable[[int, int], None] | None = None,
    space_points: int = DEFAULT_RANDOM_SPACE_POINTS,
    space_nodes: int | Mapping[str, int] | None = None,
    max_seconds: float | None = None,
    executor=None,
) -> VerifyReport:
    """Compare a codebook with an independent ``solve_ivp`` reference of its own problem.

    Parameters
    ----------
    codebook : Codebook or path
    samples : int, optional
        Random points of the parameter box (>= 1), in addition to its corners
        [default: :data:`DEFAULT_SAMPLES`; :data:`DEFAULT_SAMPLES_PDE` for a
        time-dependent problem with space coordinates].
    sampling : {'sobol', 'lhs'}
        Scrambled Sobol or Latin hypercube (``scipy.stats.qmc``).
    seed : int
        Seed of the sampling and of the random times.
    points : path or mapping, optional
        Check these parameter points instead (no random samples, no
        corners): a CSV file whose header names the non-time coordinates, or
        a mapping coordinate -> 1-D array.
    times : int
        Random times (>= 0) in addition to every node of the time coordinate.
    method : str, optional
        ``solve_ivp`` method: RK45, Radau, BDF, LSODA or DOP853 (default: DOP853, or Radau at
        rtol 1e-12, atol 1e-14 when the problem is stiff at the sample, as the error gate decides:
        :func:`pgdcli.checks.stiffness.decide_stiffness`; the settings' ``stiffness`` says why). With
        space coordinates the method-of-lines system is stiff: BDF (default)
        or Radau; any other method given is replaced by BDF (the settings
        record the method used).
    rtol, atol : float, optional
        ``solve_ivp`` tolerances (default 1e-12 and 1e-12; with space
        coordinates 1e-10 and 1e-12).
    jobs : int, optional
        Worker processes (default: ``os.cpu_count()``; 1: no pool, or the executor in effect).
    max_error, max_rel_error : float, optional
        The gate recorded in the report (see :meth:`VerifyReport.passed`); without either, the
        gate is the codebook's own tolerance.
    max_corners : int
        Most corners checked; beyond, a seeded random subset.
    progress : callable, optional
        ``progress(done, total)`` in parameter points, after each chunk.
    space_points : int
        With space coordinates: random points (>= 0) per space coordinate, in
        addition to every node of that coordinate in the codebook; the
        codebook and the reference are compared on the tensor grid of these
        points, at every parameter point and time.
    space_nodes : int or dict of str to int, optional
        With space coordinates: collocation nodes per space coordinate of the
        method-of-lines reference (default
        :data:`pgdcli.checks.reference.DEFAULT_SPACE_NODES`).
    max_seconds : float, optional
        Time budget of the reference integrations (default: none). When it runs out, the points
        not integrated yet are reported as not checked and the report does not pass.
    executor : optional
        Where the reference's chunks run instead of ``jobs`` processes: a ``distributed.Client`` or a
        :class:`pgdcli.executors.Executor` (:mod:`pgdcli.executors`). The report does not depend on it.

    Returns
    -------
    VerifyReport

    Raises
    ------
    PgdError
        Unreadable codebook, a codebook without spec, invalid options or
        points (:class:`VerifyError`).
    """
    started = _time.perf_counter()
    opts = _checked_options(samples=samples, times=times, seed=seed, max_corners=max_corners, jobs=jobs,
                            sampling=sampling, method=method, space_points=space_points, rtol=rtol, atol=atol,
                            max_error=max_error, max_rel_error=max_rel_error)
    cb, path, source = _load(codebook)
    problem = _parse_problem(cb, source)
    time = problem.time
    space = [c.name for c in space_coordinates(problem)]
    n_samples = default_samples(problem) if opts["samples"] is None else opts["samples"]
    sample_points, S, settings = parameter_points(problem, points, n_samples, opts["sampling"], opts["seed"],
                                                  opts["max_corners"])
    all_times, time_counts = check_times(cb, time, opts["seed"], opts["times"])
    stiffness = None
    if not space and time is not None and opts["method"] is None:  # the error gate's choice of method
        # with phases: along phase 0 (its motion continued past the event), for the stiffness alone
        stiffness = decide_stiffness(problem, getattr(cb, "zero", cb), sample_points, S, all_times,
                                     1e-12 if opts["rtol"] is None else opts["rtol"])
    method, rtol, atol = _reference_tolerances(bool(space), opts["method"], opts["rtol"], opts["atol"],
                                               stiff=stiffness is not None and stiffness.stiff)
    settings.update(parameter_points=int(S), **time_counts,
                    method="direct" if time is None else method,  # steady: one sparse LU solve per point
                    rtol=float(rtol), atol=float(atol), jobs=int(opts["jobs"]),
                    stiffness=None if stiffness is None else stiffness.text())

    def report_progress(done: int) -> None:
        if progress is not None:
            progress(done, S)

    report_progress(0)
    settings["max_seconds"] = max_seconds = _check_tolerance("max_seconds", max_seconds)
    with time_budget(max_seconds), chunk_executor(opts["jobs"], executor) as runner:
        if isinstance(runner, executors.DaskExecutor):
            settings.update(jobs=runner.workers, cluster=runner.address)
        result, approx, space_grid = _reference_and_codebook(cb, problem, sample_points, S, all_times, opts,
                                                             settings, method, rtol, atol, space_nodes,
                                                             report_progress, runner)
    report = _report(cb, path, problem, opts, settings, sample_points, all_times, result, approx, space_grid,
                     _time.perf_counter() - started)
    if cb.events and problem.events and report.tolerance is not None:  # the event times, at the same points
        _check_events(report, cb, problem, method, sample_points, getattr(result, "events", ()))
        report.wall_time = _time.perf_counter() - started
    return report


def _check_events(report, cb, problem, method: str, sample_points, later=()) -> None:
    """The codebook's event times against scipy's event location at the report's points, into ``report.events``
    (with ``later``: a reset's later event times, measured with the phases)."""
    checks = check_events(problem, cb, tolerance=report.tolerance, relative_tolerance=report.relative_tolerance,
                          stiff=method in ("Radau", "BDF", "LSODA"), points=sample_points)
    report.events = {c.name: c for c in [*checks, *later]}


def _reference_and_codebook(cb, problem, sample_points, S, all_times, opts, settings, method, rtol, atol,
                            space_nodes, report_progress, executor) -> tuple:
    """The reference and the codebook at the sample points and times (on the space grid, with space
    coordinates): ``(reference result, {unknown: codebook values}, space grid)``; records the space
    settings in ``settings``."""
    time = problem.time
    space = [c.name for c in space_coordinates(problem)]
    unknowns = list(problem.unknown_names)
    if space:
        space_grid = space_points_grid(cb, space, opts["seed"], opts["space_points"])
        nodes = DEFAULT_SPACE_NODES if space_nodes is None else space_nodes
        nonlinear = is_nonlinear_pde(problem)  # its own method of lines (Radau, grids refined until they agree)
        reference = solve_reference_nonlinear_grid if nonlinear else solve_reference_pde
        result = reference(problem, sample_points, space_grid, None if time is None else all_times,
                           grid=True, method=method, rtol=rtol, atol=atol, jobs=1, executor=executor,
                           progress=report_progress, space_nodes=nodes)
        if nonlinear:
            settings.update(method=f"{result.method}, nonlinear method of lines", rtol=result.rtol, atol=result.atol)
        elif time is not None and result.method != method:  # solved exactly instead of integrated
            settings.update(method=result.method)
        if time is None:  # the placeholder time axis, as the codebook values have it
            result.values = {u: v[:, None] for u, v in result.values.items()}
        approx = codebook_on_space_grid(cb, sample_points, S, time, all_times, space_grid, unknowns)
        settings.update(space_points={n: int(space_grid[n].size) for n in space},
                        random_space_points=opts["space_points"], space_nodes=dict(result.nodes))
    elif getattr(cb, "phases", None) is not None:  # an event that acts: scipy stopped at it and restarted
        space_grid = {}
        result, approx = _phased(cb, problem, sample_points, all_times, method)
        report_progress(S)
    else:
        space_grid = {}
        result = solve_reference(problem, sample_points, all_times, method=method, rtol=rtol, atol=atol,
                                 executor=executor, progress=report_progress)
        approx = codebook_at_samples(cb, sample_points, time, all_times, unknowns)
    return result, approx, space_grid


def _phased(cb, problem, sample_points, all_times, method: str):
    """The reference and the codebook of a codebook with phases; where neither has a value (after a
    terminal event) both are 0, where one alone has, the codebook's is infinite (an error)."""
    tolerance, relative = _codebook_tolerance(cb)
    got = phase_values(problem, cb, sample_points, all_times, tolerance=tolerance or 1.0, relative_tolerance=relative,
                       stiff=method in ("Radau", "BDF", "LSODA"))
    approx = {}
    for u, ref in got.reference.items():
        mine = got.codebook[u].copy()
        none = np.isnan(ref) & np.isnan(mine)
        mine[np.isnan(ref) != np.isnan(mine)] = np.inf
        mine[none] = ref[none] = 0.0
        approx[u] = mine
    return SimpleNamespace(values=got.reference, success=got.success, messages=got.messages, events=got.events), approx


def _report(cb, path, problem, opts, settings, sample_points, all_times, result, approx, space_grid,
            wall_time: float) -> VerifyReport:
    """The :class:`VerifyReport` of the compared values: error statistics per unknown, failures."""
    time = problem.time
    names = [c.name for c in sampled_coordinates(problem)]
    tolerance, relative = _codebook_tolerance(cb)
    stats = {u: error_statistics(cb.coordinate_names, time, sample_points, all_times, result.success,
                                 result.values[u], approx[u], space_grid, tolerance, relative)
             for u in problem.unknown_names}
    failures = [Failure({n: float(sample_points[n][i]) for n in names}, result.messages[i] or "integration failed")
                for i in np.flatnonzero(~result.success) if result.messages[i] != TIME_UP]
    settings["not_checked"] = sum(m == TIME_UP for m in result.messages)
    reference = result.values
    if time is None:
        all_times = np.zeros(0)
        reference = {u: v[:, 0] for u, v in reference.items()}
        approx = {u: v[:, 0] for u, v in approx.items()}
    return VerifyReport(codebook=path, problem=problem.name, time=time, coordinates=list(cb.coordinate_names),
                        unknowns=stats, failures=failures, settings=settings, max_error=opts["max_error"],
                        max_rel_error=opts["max_rel_error"], samples=sample_points, times=all_times,
                        reference=reference, codebook_values=approx, wall_time=wall_time,
                        space_points=space_grid, tolerance=tolerance, relative_tolerance=relative)


def _codebook_tolerance(cb) -> tuple[float | None, float]:
    """The codebook's ``(tolerance, relative_tolerance)`` from its report; ``(None, 0.0)`` without one."""
    tolerance = float(cb.report.get("tolerance", np.nan))
    relative = float(cb.report.get("relative_tolerance", 0.0))
    if not (math.isfinite(tolerance) and tolerance > 0):
        return None, 0.0
    return tolerance, relative if math.isfinite(relative) and relative > 0 else 0.0


def _checked_options(*, samples, times, seed, max_corners, jobs, sampling, method, space_points, rtol, atol,
                     max_error, max_rel_error) -> dict:
    """verify's options validated (one VerifyError naming the option), ``jobs`` defaulted."""
    opts = {"samples": None if samples is None else _check_int("samples", samples, 1),
            "times": _check_int("times", times, 0), "seed": _check_int("seed", seed, 0),
            "max_corners": _check_int("max_corners", max_corners, 0),
            "jobs": (os.cpu_count() or 1) if jobs is None else _check_int("jobs", jobs, 1)}
    if sampling not in SAMPLINGS:
        raise VerifyError(f"sampling must be one of {', '.join(SAMPLINGS)}, got {sampling!r}")
    if method is not None and method not in METHODS:
        raise VerifyError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    opts["space_points"] = _check_int("space_points", space_points, 0)
    for label, value in (("rtol", rtol), ("atol", atol)):
        if value is None:
            continue
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating)) \
                or not (math.isfinite(value) and 0 < value < 1):
            raise VerifyError(f"{label} must be a number in (0, 1), got {value!r}")
    opts.update(sampling=sampling, method=method, rtol=rtol, atol=atol,
                max_error=_check_tolerance("max_error", max_error),
                max_rel_error=_check_tolerance("max_rel_error", max_rel_error))
    return opts


def _load(codebook) -> tuple:
    """``(Codebook, path or None, source name for messages)`` of a Codebook or a path."""
    if isinstance(codebook, Codebook):
        return codebook, None, f"<codebook {codebook.name}>"
    return Codebook.load(codebook), str(codebook), str(codebook)


def _reference_tolerances(space: bool, method, rtol, atol, stiff: bool = False) -> tuple[str, float, float]:
    """The reference's method and tolerances: DOP853 at 1e-12, or for the (stiff) method of lines BDF/Radau
    at rtol 1e-10, or for a stiff problem (:func:`pgdcli.checks.stiffness.decide_stiffness`) Radau at rtol
    1e-12, atol 1e-14, as its error gate."""
    if space:
        method = method if method in PDE_METHODS else "BDF"
        rtol = 1e-10 if rtol is None else rtol
    elif stiff and method is None:
        method, rtol, atol = "Radau", 1e-12 if rtol is None else rtol, 1e-14 if atol is None else atol
    else:
        method = "DOP853" if method is None else method
        rtol = 1e-12 if rtol is None else rtol
    return method, rtol, 1e-12 if atol is None else atol

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
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np

from .. import executors
from ..errors import CodebookError, VerifyError
from .reference_base import TIME_UP, chunk_executor, time_budget
from .compare import UnknownErrors, codebook_at_samples, codebook_on_space_grid, error_statistics
from .sampling import (DEFAULT_RANDOM_SPACE_POINTS, MAX_CORNERS, SAMPLINGS, check_times, default_samples, parameter_points,
                       sampled_coordinates, space_coordinates, space_points_grid)

__all__ = ["verify", "VerifyReport", "UnknownErrors", "Failure", "VerifyError", "MAX_CORNERS", "SAMPLINGS"]


@dataclass
class Failure:
    """A parameter point where the reference integration failed."""

    point: dict[str, float]
    message: str

    def to_dict(self) -> dict:
        return {"point": {k: float(v) for k, v in self.point.items()}, "message": self.message}


@dataclass
class VerifyReport:
    """Outcome of :func:`verify`.

    Attributes
    ----------
    codebook : str or None
        Path of the codebook file (None for an in-memory codebook).
    problem : str
        Problem name.
    time : str or None
        Name of the time coordinate (None: a steady problem).
    coordinates : list of str
        All coordinates, codebook order.
    unknowns : dict of str to UnknownErrors
    failures : list of Failure
    settings : dict
        Sampling and integration settings (the JSON ``settings`` object).
    max_error, max_rel_error : float or None
        The gate given to :func:`verify` (used by :meth:`to_dict`); without either, the gate is the
        codebook's own tolerance.
    tolerance, relative_tolerance : float or None, float
        The codebook's tolerance (``solver.tolerance`` and ``solver.relative_tolerance`` of its spec;
        None when the codebook records none).
    samples : dict of str to ndarray, shape (S,)
        The parameter points.
    times : ndarray, shape (T,)
        The times (sorted; empty for a steady problem).
    reference, codebook_values : dict of str to ndarray, shape (S, T)
        Reference (NaN at failed points) and codebook values; with space
        coordinates shape (S, T, X_1, ..., X_d) on the tensor grid of
        ``space_points``, and (S, X_1, ..., X_d) for a steady problem.
    wall_time : float
        Seconds.
    space_points : dict of str to ndarray
        With space coordinates: the points of each (sorted); else empty.
    """

    codebook: str | None
    problem: str
    time: str | None
    coordinates: list[str]
    unknowns: dict[str, UnknownErrors]
    failures: list[Failure]
    settings: dict
    max_error: float | None = None
    max_rel_error: float | None = None
    samples: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    times: np.ndarray = field(default_factory=lambda: np.zeros(0), repr=False)
    reference: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    codebook_values: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    wall_time: float = 0.0
    space_points: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    tolerance: float | None = None
    relative_tolerance: float = 0.0

    @property
    def n_points(self) -> int:
        """Parameter points checked (including failed ones)."""
        return int(self.settings.get("parameter_points", 0))

    @property
    def not_checked(self) -> int:
        """Parameter points the time budget left unchecked (0: the report is complete)."""
        return int(self.settings.get("not_checked", 0))

    def tolerance_gate(self, max_error: float | None = None, max_rel_error: float | None = None) -> bool:
        """True when the gate is the codebook's own tolerance: no threshold given, and the codebook has one."""
        return max_error is None and max_rel_error is None and self.tolerance is not None

    def gate_text(self, max_error: float | None = None, max_rel_error: float | None = None) -> str:
        """The gate in words, e.g. ``every reference integration succeeds, max abs error <= 1e-08``."""
        gates = ["every reference integration succeeds"]
        if max_error is not None:
            gates.append(f"max abs error <= {max_error:.3g}")
        if max_rel_error is not None:
            gates.append(f"max rel error <= {max_rel_error:.3g}")
        if self.tolerance_gate(max_error, max_rel_error):
            relative = f" + {self.relative_tolerance:.3g} |u|" if self.relative_tolerance else ""
            gates.append(f"error <= the codebook's tolerance {self.tolerance:.3g}{relative}")
        return ", ".join(gates)

    def violations(self, max_error: float | None = None, max_rel_error: float | None = None) -> list[str]:
        """Reasons the check fails (empty when it passes), one line each.

        Parameters
        ----------
        max_error, max_rel_error : float, optional
            Thresholds of every unknown's max abs and max rel error. Without either, the gate is
            the codebook's own tolerance (when it records one).

        Returns
        -------
        list of str
        """
        reasons = []
        if self.not_checked:
            reasons.append(f"stopped at the time budget of {self.settings.get('max_seconds', 0):g} s with "
                           f"{self.not_checked} of {self.n_points} parameter point(s) not checked "
                           f"(raise --max-seconds)")
        if self.failures:
            first = self.failures[0]
            reasons.append(
                f"the reference integration failed at {len(self.failures)} of {self.n_points} parameter point(s)"
                f" (first: {_format_point(first.point)}: {first.message})"
            )
        for name, stats in self.unknowns.items():
            if max_error is not None and not stats.max_abs_error <= max_error:
                reasons.append(f"{name}: max abs error {stats.max_abs_error:.3e} > {max_error:.3e}"
                               f" at {_format_point(stats.where)}")
            if max_rel_error is not None and not stats.max_rel_error <= max_rel_error:
                reasons.append(f"{name}: max rel error {stats.max_rel_error:.3e} > {max_rel_error:.3e}"
                               f" at {_format_point(stats.where)}")
            if self.tolerance_gate(max_error, max_rel_error) and not stats.tolerance_ratio <= 1:
                reasons.append(f"{name}: max abs error {stats.max_abs_error:.3e} at {_format_point(stats.where)}, "
                               f"{stats.tolerance_ratio:.3g} x the codebook's tolerance {self.tolerance:.3g}")
        return reasons

    def passed(self, max_error: float | None = None, max_rel_error: float | None = None) -> bool:
        """True when every reference integration succeeded and the gate holds.

        Without either threshold, the gate is the codebook's own tolerance: every unknown's
        ``tolerance_ratio`` at most 1.

        Parameters
        ----------
        max_error : float, optional
            Largest allowed absolute error of every unknown.
        max_rel_error : float, optional
            Largest allowed relative error (``max_abs_error / reference_scale``).

        Returns
        -------
        bool
        """
        return not self.violations(max_error, max_rel_error)

    def to_dict(self) -> dict:
        """The JSON report (``pgd verify --format json``); keys in docs/verify.md."""
        return {
            "codebook": self.codebook,
            "problem": self.problem,
            "passed": self.passed(self.max_error, self.max_rel_error),
            "gate": {"max_error": self.max_error, "max_rel_error": self.max_rel_error,
                     **({"tolerance": self.tolerance, "relative_tolerance": self.relative_tolerance}
                        if self.tolerance_gate(self.max_error, self.max_rel_error)
                        else {"tolerance": None, "relative_tolerance": None})},
            "settings": dict(self.settings),
            "unknowns": {name: stats.to_dict() for name, stats in self.unknowns.items()},
            "failures": {"count": len(self.failures), "points": [f.to_dict() for f in self.failures]},
            "complete": self.not_checked == 0,
            "wall_time": float(self.wall_time),
        }


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------
def _format_point(point: Mapping[str, float]) -> str:
    return ", ".join(f"{k}={float(v):.6g}" for k, v in point.items()) or "(no parameters)"


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
        ``solve_ivp`` method: DOP853 (default), RK45, Radau, BDF or LSODA. With
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
    method, rtol, atol = _reference_tolerances(bool(space), opts["method"], opts["rtol"], opts["atol"])
    n_samples = default_samples(problem) if opts["samples"] is None else opts["samples"]
    sample_points, S, settings = parameter_points(problem, points, n_samples, opts["sampling"], opts["seed"],
                                                  opts["max_corners"])
    all_times, time_counts = check_times(cb, time, opts["seed"], opts["times"])
    settings.update(parameter_points=int(S), **time_counts,
                    method="direct" if time is None else method,  # steady: one sparse LU solve per point
                    rtol=float(rtol), atol=float(atol), jobs=int(opts["jobs"]))

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
    return _report(cb, path, problem, opts, settings, sample_points, all_times, result, approx, space_grid,
                   _time.perf_counter() - started)


def _reference_and_codebook(cb, problem, sample_points, S, all_times, opts, settings, method, rtol, atol,
                            space_nodes, report_progress, executor) -> tuple:
    """The reference and the codebook at the sample points and times (on the space grid, with space
    coordinates): ``(reference result, {unknown: codebook values}, space grid)``; records the space
    settings in ``settings``."""
    from .reference import DEFAULT_SPACE_NODES, solve_reference, solve_reference_pde
    from .reference_pde_nonlinear import is_nonlinear_pde, solve_reference_nonlinear_grid

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
        if time is None:  # the placeholder time axis, as the codebook values have it
            result.values = {u: v[:, None] for u, v in result.values.items()}
        approx = codebook_on_space_grid(cb, sample_points, S, time, all_times, space_grid, unknowns)
        settings.update(space_points={n: int(space_grid[n].size) for n in space},
                        random_space_points=opts["space_points"], space_nodes=dict(result.nodes))
    else:
        space_grid = {}
        result = solve_reference(problem, sample_points, all_times, method=method, rtol=rtol, atol=atol,
                                 executor=executor, progress=report_progress)
        approx = codebook_at_samples(cb, sample_points, time, all_times, unknowns)
    return result, approx, space_grid


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
    from .reference import METHODS

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
    from ..codebook.codebook import Codebook

    if isinstance(codebook, Codebook):
        return codebook, None, f"<codebook {codebook.name}>"
    return Codebook.load(codebook), str(codebook), str(codebook)


def _reference_tolerances(space: bool, method, rtol, atol) -> tuple[str, float, float]:
    """The reference's method and tolerances: DOP853 at 1e-12, or for the (stiff) method of lines BDF/Radau
    at rtol 1e-10."""
    from .reference import PDE_METHODS

    if space:
        method = method if method in PDE_METHODS else "BDF"
        rtol = 1e-10 if rtol is None else rtol
    else:
        method = "DOP853" if method is None else method
        rtol = 1e-12 if rtol is None else rtol
    return method, rtol, 1e-12 if atol is None else atol

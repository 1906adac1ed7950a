"""The driver: :func:`solve`, one pipeline from a problem to a checked codebook.

    validate -> choose method -> (solve -> check -> refine)* -> codebook

* validate: :func:`check_solvable` (settings in range, initial values finite and meeting the
  boundary values, a problem one of the methods takes);
* choose method: :func:`pgdcli.driver.methods.choose_method` (the PGD enrichment of linear problems,
  the time march of nonlinear ones, the PDE march of a nonlinear PDE in one space coordinate);
* solve, check, refine: :func:`pgdcli.driver.refinement.solve_rounds`, the one loop that runs the
  method, measures its codebook against the independent reference (:mod:`pgdcli.driver.gate`), and
  tightens the method's target or refines the nodes (:mod:`pgdcli.adapt`);
* codebook: the :class:`SolveResult`'s, with its report.
"""

from __future__ import annotations

from typing import Callable

from .. import executors
from ..blas import one_blas_thread
from ..algorithms.grid_march import check_forced_grid
from ..algorithms.outcome import Status
from ..algorithms.result import SolveResult
from ..checks.budget import check_budget
from ..errors import SolverError
from ..problem.compatibility import check_coefficients_finite, check_initial_finite, check_initial_meets_boundary
from ..problem.spec import Problem, load_spec
from ..progress import PhaseStarted, ProgressEvent, emit
from .events import record_events
from .method import Settings
from .methods import choose_method
from .phases import solve_phased
from .refinement import solve_rounds

__all__ = ["solve", "check_solvable", "SolveResult", "Status"]


def solve(problem, *, tolerance: float | None = None, relative_tolerance: float | None = None,
          max_modes: int | None = None, callback: Callable[[ProgressEvent], None] | None = None,
          executor=None) -> SolveResult:
    """Compute the PGD codebook of a problem, its error measured against an independent reference.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem or str or path
        A validated problem, or the path of a YAML spec.
    tolerance, relative_tolerance, max_modes : optional
        Override ``problem.solver``: the codebook must satisfy
        ``|u - u_exact| <= tolerance + relative_tolerance * |u_exact|`` everywhere.
    callback : callable, optional
        Called with every :class:`~pgdcli.progress.ProgressEvent` of the solve: the start of each
        phase (:class:`~pgdcli.progress.PhaseStarted`), each term of the enrichment
        (:class:`~pgdcli.progress.EnrichmentStep`), each step of a march
        (:class:`~pgdcli.progress.MarchStep`), each sweep of a cross
        (:class:`~pgdcli.progress.CrossSweep`), the error gate's reference
        (:class:`~pgdcli.progress.ReferenceProgress`).
    executor : optional
        Where the independent tasks of the solve run (the cross march's batches of trajectories, the
        reference's chunks): a ``distributed.Client`` or a :class:`pgdcli.executors.Executor`; default
        this process. The codebook is the same bit for bit.

    Returns
    -------
    SolveResult
        ``converged`` is True only when the solver converged *and* the measured
        error meets the tolerance (or could not be measured: ``accurate`` None,
        with a warning); a codebook that misses its tolerance has ``status``
        :attr:`Status.INACCURATE` and a message saying where and why.
    """
    if not isinstance(problem, Problem):
        problem = load_spec(problem)
    opts = problem.solver
    settings = Settings(opts.tolerance if tolerance is None else float(tolerance),
                        opts.relative_tolerance if relative_tolerance is None else float(relative_tolerance),
                        opts.max_modes if max_modes is None else int(max_modes))
    check_solvable(problem, settings.tolerance, settings.relative_tolerance, settings.max_modes)
    choice = choose_method(problem)
    emit(callback, PhaseStarted("solve", f"method {choice.methods[0].name} ({choice.reason})", 1))
    with one_blas_thread(), executors.using(executor):  # small dense products: faster on one BLAS thread
        result = solve_phased(problem, choice, settings, callback)  # an event that acts: None without
        if result is None:
            result, _ = solve_rounds(problem, choice, settings, callback)
            result = record_events(problem, result, settings, callback)
    rates = [(u.name, u.rate_of) for u in problem.unknowns if u.rate_of]
    if rates:  # the rate unknowns of der(x, t, 2) (pgdcli.problem.second_order), named in pgd info
        result.codebook.report["rates"] = ",".join(f"{rate}={x}" for rate, x in rates)
    return result


def check_solvable(problem, tolerance: float, relative_tolerance: float, max_modes: int) -> bool:
    """The checks :func:`solve` makes before any work; raises :class:`PgdError` with one line.

    Settings in range, initial values that meet the Dirichlet values, a problem one of
    the methods takes. Returns whether a time march (not the enrichment) solves it.
    The CLI calls it before showing progress, so a refusal is the only line on stderr.
    """
    if not (0.0 < tolerance < 1.0):
        raise SolverError(f"tolerance must be in (0, 1), got {tolerance}")
    if not (0.0 <= relative_tolerance < 1.0):
        raise SolverError(f"relative_tolerance must be in [0, 1), got {relative_tolerance}")
    if max_modes < 1:
        raise SolverError(f"max_modes must be at least 1, got {max_modes}")
    march = choose_method(problem).methods[0].marches
    check_budget(problem, march=march)
    check_initial_finite(problem)
    check_coefficients_finite(problem)
    check_initial_meets_boundary(problem, tolerance, relative_tolerance)
    if march:
        check_forced_grid(problem)
    return march

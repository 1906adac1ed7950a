"""The driver: :func:`solve` chooses the method, runs it under the error gate, builds the codebook.

Linear problems go to the PGD enrichment (:mod:`pgdcli.algorithms.enrichment` on the system of
:mod:`pgdcli.discretization.linear`), nonlinear ones to the tensor-train time march
(:mod:`pgdcli.algorithms.march`; a nonlinear PDE in one space coordinate to the exponential PDE
march, :mod:`pgdcli.algorithms.pde_solve`); either way the codebook is measured against the independent
reference (:mod:`pgdcli.checks.check`) and, where the spec leaves the nodes to the solver, refined
until the error meets the tolerance (:mod:`pgdcli.adapt`).
"""

from __future__ import annotations

import time as _time
from functools import partial
from typing import Callable

import numpy as np

from . import executors
from .algorithms.enrichment import run_enrichment
from .algorithms.result import SolveResult
from .blas import one_blas_thread
from .checks.budget import check_budget
from .codebook.codebook import Codebook
from .discretization.coefficients import separation_report_text
from .discretization.coordinates import coordinate_infos
from .discretization.linear import discretize
from .errors import PgdError, SolverError
from .problem.general import has_general
from .tensors.cp import CPTensor

__all__ = ["solve", "SolveResult"]


# ----------------------------------------------------------------------------------------------
# driver
# ----------------------------------------------------------------------------------------------

def solve(problem, *, tolerance: float | None = None, relative_tolerance: float | None = None,
          max_modes: int | None = None, callback: Callable[[dict], None] | None = None,
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
        Called after each enrichment with a dict ``{"mode", "residual", "iterations"}``
        (march: after each step, ``{"time", "end", "steps", "ranks"}``).
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
        :data:`pgdcli.adapt.INACCURATE` and a message saying where and why.
    """
    from .adapt import solve_to_tolerance
    from .problem.spec import Problem, load_spec

    if not isinstance(problem, Problem):
        problem = load_spec(problem)
    opts = problem.solver
    tol = opts.tolerance if tolerance is None else float(tolerance)
    rtol = opts.relative_tolerance if relative_tolerance is None else float(relative_tolerance)
    nmax = opts.max_modes if max_modes is None else int(max_modes)
    march = check_solvable(problem, tol, rtol, nmax)
    # the solver's own target (RMS of the march, residual of the enrichment) that met the tolerance at
    # the nodes is carried from one round of the automatic resolution to the next: the error at the
    # nodes hardly depends on how many nodes there are, so each round need not find it again
    learned: dict = {}
    if march:
        once = partial(_checked_march, tolerance=tol, relative_tolerance=rtol, callback=callback, learned=learned)
    else:
        once = partial(_checked_enrichment, tolerance=tol, relative_tolerance=rtol, max_modes=nmax,
                       callback=callback, learned=learned)
    with one_blas_thread(), executors.using(executor):  # small dense products: faster on one BLAS thread
        result = solve_to_tolerance(problem, once, march=march)
    rates = [(u.name, u.rate_of) for u in problem.unknowns if u.rate_of]
    if rates:  # the rate unknowns of der(x, t, 2) (pgdcli.problem.second_order), named in pgd info
        result.codebook.report["rates"] = ",".join(f"{rate}={x}" for rate, x in rates)
    return result


def check_solvable(problem, tolerance: float, relative_tolerance: float, max_modes: int) -> bool:
    """The checks :func:`solve` makes before any work; raises :class:`PgdError` with one line.

    Settings in range, initial values that meet the Dirichlet values, a problem one of
    the methods takes. Returns whether the time march (not the enrichment) solves it.
    The CLI calls it before showing progress, so a refusal is the only line on stderr.
    """
    from .problem.compatibility import check_coefficients_finite, check_initial_finite, check_initial_meets_boundary

    if not (0.0 < tolerance < 1.0):
        raise SolverError(f"tolerance must be in (0, 1), got {tolerance}")
    if not (0.0 <= relative_tolerance < 1.0):
        raise SolverError(f"relative_tolerance must be in [0, 1), got {relative_tolerance}")
    if max_modes < 1:
        raise SolverError(f"max_modes must be at least 1, got {max_modes}")
    march = _use_march(problem)
    check_budget(problem, march=march)
    check_initial_finite(problem)
    check_coefficients_finite(problem)
    check_initial_meets_boundary(problem, tolerance, relative_tolerance)
    if march:
        from .algorithms.grid_march import check_forced_grid

        check_forced_grid(problem)
    return march


def _enrich(problem, residual_tolerance: float, nmax: int, callback, tolerance: float | None = None) -> SolveResult:
    """One enrichment solve to a relative residual (the solver's internal stopping signal)."""
    opts = problem.solver
    tol = residual_tolerance
    started = _time.perf_counter()
    disc = discretize(problem, tolerance=tolerance)
    state, history, iterations, status = run_enrichment(disc, opts, tol, nmax, callback)
    wall = _time.perf_counter() - started
    converged = status == 0
    residual = history[-1]
    if converged:
        message = f"converged: relative residual {residual:.3g} with {state.rank} modes"
    elif status == 1:
        message = (f"not converged: relative residual {residual:.3g} > {tol:.3g} after max_modes={nmax} modes "
                   f"(raise solver.max_modes)")
    else:
        message = (f"not converged: relative residual stagnated at {residual:.3g} (asked {tol:.3g}) "
                   f"after {state.rank} modes")

    report = {
        "converged": converged,
        "status": status,
        "message": message,
        "modes": state.rank,
        "residual": residual,
        "residual_tolerance": tol,
        "residual_history": np.array(history),
        "iterations": np.array(iterations, dtype=int),
        "wall_time": wall,
        "max_modes": nmax,
        "formulation": opts.formulation,
        "update": bool(opts.update),
    }
    if disc.separations:  # how many terms each non-separable coefficient needed
        report["separated_coefficients"] = separation_report_text(disc.separations)
    codebook = codebook_from_solution(problem, disc, state.alphas, state.factors, report)
    return SolveResult(codebook, converged, status, message, np.array(history), np.array(iterations, dtype=int), wall)


# The enrichment's residual is relative; the tolerance is an absolute error. The first solve asks
# for a relative residual equal to the tolerance (right for solutions of size ~1, as the shipped
# ones); when the error measured at the nodes is larger, the residual asked is scaled down by
# CHECK_SAFETY * tolerance / error and the enrichment runs again, at most CHECK_ATTEMPTS times. An
# error that does not fall with the residual is discretization error: more nodes (pgdcli.adapt).
RESIDUAL_FLOOR = 1e-13


def _checked_enrichment(problem, *, tolerance: float, relative_tolerance: float, max_modes: int,
                        callback=None, learned: dict | None = None) -> SolveResult:
    """Enrich, measure the error against the reference, tighten the residual if the nodes need it.

    ``learned`` (updated) carries the residual that met the tolerance at the nodes to the next call.
    """
    learned = {} if learned is None else learned
    target = learned.get("residual", tolerance)
    kept = stopped = None
    attempts = []
    for _ in range(CHECK_ATTEMPTS):
        # non-separable coefficients are separated to a share of the tolerance, tightened with the
        # residual when the error at the nodes asks for another enrichment (as the march's target is)
        result = _enrich(problem, target, max_modes, callback, min(tolerance, target))
        if not result.converged:
            if kept is None:
                result.codebook.report["tolerance"] = float(tolerance)
                return result
            stopped = result.message  # the smaller residual the nodes ask for was not reached
            if result.status == 1:  # max_modes, but the residual fell: the error decides
                kept, stopped = _at_max_modes(problem, kept, result, tolerance, relative_tolerance)
                attempts.append((target, result.check.node_ratio))  # the retry's own ratio, kept or not
            break
        result.check = _measure(problem, result, tolerance, relative_tolerance)
        previous = kept
        kept = result
        attempts.append((target, result.check.node_ratio))
        ratio = result.check.node_ratio
        if not np.isfinite(ratio) or ratio <= 1.0 or target <= RESIDUAL_FLOOR:
            break
        if previous is not None and ratio > 0.5 * attempts[-2][1]:
            break  # a smaller residual did not help: discretization error
        # a residual is cheap to lower and the error follows it only roughly: at least a decade below
        # the residual reached (heat1d: 4.3e-10 with 7 modes, error 1.05e-8; 8 modes: 3.6e-10)
        target = max(RESIDUAL_FLOOR, min(target, result.residual) * min(0.1, CHECK_SAFETY / ratio))
    if kept.check.node_ratio <= 1.0:
        learned["residual"] = attempts[-1][0]
    rep = kept.codebook.report
    if kept.check.node_ratio > 1.0 and stopped is not None:
        # the residual could not be lowered: more nodes would not help (a user's 4-coordinate heat
        # problem needed 154 modes at max_modes 100, and was refined to 129 nodes for nothing)
        rep["enrichment_stopped"] = stopped.removeprefix("not converged: ")
    elif kept.check.node_ratio > 1.0:  # the residual did not bring it down: more time or space nodes
        rep["discretization_limited"] = 1
    rep["tolerance"] = float(tolerance)
    rep["enrichment_attempts"] = np.array(attempts, dtype=float)  # (solves, 2): residual asked, node ratio
    rep["solver_message"] = (f"relative residual {kept.residual:.3g} with {kept.n_modes} modes"
                             + (f", {len(attempts)} enrichments" if len(attempts) > 1 else ""))
    return _with_resolution(kept, tolerance)


def _at_max_modes(problem, kept, result, tolerance: float, relative_tolerance: float):
    """Weigh an enrichment that stopped at max_modes below the residual asked against the one kept.

    Returns the better of the two and the reason to give when it still misses the
    tolerance: the enrichment's (its residual fell, and the error with it, but not
    far enough: more modes) or None (the residual fell tenfold and the error at the
    nodes not by half: discretization error, which more nodes reduce).
    """
    result.check = _measure(problem, result, tolerance, relative_tolerance)
    stopped = result.message
    if result.check.node_ratio >= kept.check.node_ratio:
        return kept, stopped
    if result.residual <= 0.1 * kept.residual and result.check.node_ratio > 0.5 * kept.check.node_ratio:
        stopped = None
    result.converged, result.status = True, 0  # the measured error decides, as for any enrichment
    return result, stopped


def _measure(problem, result, tolerance: float, relative_tolerance: float):
    """The codebook's error against the independent reference; unchecked (with a warning) if it cannot run."""
    from .checks.check import check_codebook, check_codebook_pde, unchecked

    space = any(c.role == "space" for c in problem.coordinates)
    try:
        measure = check_codebook_pde if space or problem.time is None else check_codebook
        check = measure(problem, result.codebook, tolerance=tolerance, relative_tolerance=relative_tolerance)
    except PgdError as exc:  # the reference cannot integrate this problem: say so, keep the solve
        reason = " ".join(str(exc).split())
        result.warnings.append(f"the codebook's error could not be checked against scipy: {reason}")
        return unchecked(reason, tolerance, relative_tolerance)
    if check.failed and not check.points:
        result.warnings.append(f"the reference integration failed at all {check.failed} check points: "
                               f"the error is not measured")
    elif check.failed:
        result.warnings.append(f"the reference integration failed at {check.failed} of "
                               f"{check.failed + check.points} check points; they are not in the measured error")
    return check


# The march's tolerance is checked (pgdcli.checks.check): if the measured error at grid nodes (at and
# between the time nodes) exceeds it, the march is repeated with its RMS target scaled by
# MARCH_SAFETY * tolerance / error, at most
# CHECK_ATTEMPTS marches in all. DOP853 is of order 8, so a tighter target costs few more steps;
# mostly it raises the ranks.
# The first march aims at CHECK_FIRST * tolerance: on the shipped problems the measured max error
# was 0.76-1.26x the RMS target (0.1x on logistic), so a target at the tolerance needed a second
# march half the time (rigid body at 1e-5: 9 s + 16 s; at 0.7e-5 one march of 15 s, 4.7e-6).
CHECK_FIRST = 0.7
CHECK_ATTEMPTS = 3
CHECK_SAFETY = 0.5
# A repeated march aims at MARCH_SAFETY / ratio of the last target: its error follows the target
# (the 10-D rigid body: 1.12 x the tolerance at 7e-6, 0.73 x at 4.9e-6); at 0.5 the cross of the
# 10-D body reached its rank cap (400) at 3.1e-6.
MARCH_SAFETY = 0.8


def _march_ratio(check, time: str | None) -> float:
    """What a tighter march brings down: the error at the grid nodes, at the time nodes and between them.

    Between time nodes a march's codebook interpolates within its accepted steps (the slabs),
    which a tighter march shortens; its error there is the march's own too (the 10-D rigid
    body's box corner: 1.12 x the tolerance between time nodes, 0.95 x at them, and 1.05 x
    a march aimed 30% tighter: no more nodes per slab changed it).
    """
    return max(check.node_ratio, check.coordinate_ratio.get(time, 0.0) if time else 0.0)


def _checked_march(problem, *, tolerance: float, relative_tolerance: float = 0.0, callback=None,
                   learned: dict | None = None) -> "SolveResult":
    """March, measure the error against scipy at the check sample, tighten the march if the nodes need it.

    The march controls an RMS over the parameter grid; the user's tolerance is read
    as a bound on the max abs error, and this is where it is made one (see
    :mod:`pgdcli.checks.check`). Errors between the parameter nodes (interpolation) do not
    fall with a tighter march: they are for :mod:`pgdcli.adapt` (more nodes).
    ``learned`` (updated) carries the target that met the tolerance at the nodes to the next call, and
    whether a cross march was abandoned (:func:`pgdcli.algorithms.march.solve_march`).
    """
    from .algorithms.march import solve_march
    from .algorithms.pde_solve import solve_pde_march

    # a nonlinear PDE in one space coordinate (checked by _use_march): the exponential PDE march
    marcher = solve_pde_march if any(c.role == "space" for c in problem.coordinates) else solve_march
    learned = {} if learned is None else learned
    target = learned.get("march_target", CHECK_FIRST * tolerance)
    kept = None
    attempts = []
    notes = []
    for _ in range(CHECK_ATTEMPTS):
        result = marcher(problem, target, callback=callback, learned=learned)
        if not result.converged:
            if kept is None:
                # the report speaks of the user's tolerance; the march's own target beside it
                result.codebook.report.update(tolerance=float(tolerance), march_tolerance=float(target))
                return result
            notes.append(f"the march with the tighter target {target:.2g} failed ({result.message}); "
                         f"kept the one with target {attempts[-1][0]:.2g}")
            break
        result.check = _measure(problem, result, tolerance, relative_tolerance)
        kept = result
        check = result.check
        attempts.append((target, check.error))
        ratio = _march_ratio(check, problem.time)
        if not np.isfinite(ratio) or ratio <= 1.0 or _space_limited(marcher, attempts):
            break
        target *= MARCH_SAFETY / ratio
    if _march_ratio(kept.check, problem.time) <= 1.0:
        learned["march_target"] = attempts[-1][0]
    rep = kept.codebook.report
    if _space_limited(marcher, attempts) and _march_ratio(kept.check, problem.time) > 1.0:
        rep["discretization_limited"] = 1  # pgdcli.adapt refines the space coordinates
    rep["tolerance"] = float(tolerance)
    rep["march_tolerance"] = float(attempts[-1][0])
    rep["march_attempts"] = np.array(attempts, dtype=float)  # (marches, 2): RMS target, measured max error
    end = kept.codebook.coordinate(problem.time).domain[1]
    steps = f"reached {problem.time} = {end:.6g} in {rep['steps']} steps ({rep['rejected_steps']} rejected)"
    if len(attempts) > 1:
        steps += f", {len(attempts)} marches"
    rep["solver_message"] = steps
    kept.warnings.extend(notes)
    return _with_resolution(kept, tolerance)


def _space_limited(marcher, attempts: list) -> bool:
    """A PDE march aimed tighter whose error did not halve: the space nodes limit it, not the steps (the
    Chebyshev tail of a coarse solution can understate that error: 2-D Allen-Cahn on 17 x 17 nodes, error
    5.1x the tolerance at two march targets 6x apart, tail 0.37x)."""
    from .algorithms.pde_solve import solve_pde_march

    return marcher is solve_pde_march and len(attempts) > 1 and attempts[-1][1] > 0.5 * attempts[-2][1]


def _with_resolution(result: "SolveResult", tolerance: float | None) -> "SolveResult":
    """Add the Chebyshev tails per unknown and coordinate to the report.

    The tails estimate the interpolation error between nodes. The measured error
    decides (:mod:`pgdcli.adapt`); the tails are reported, and they give warnings
    only when the error could not be measured.
    """
    from .checks.resolution import resolution_tails

    if not result.converged:
        return result
    cb = result.codebook
    tails = resolution_tails(cb)
    names = cb.coordinate_names
    cb.report["resolution"] = np.array([[tails[u][c] for c in names] for u in cb.unknown_names])
    cb.report["resolution_coordinates"] = ",".join(names)
    if result.check is not None and result.check.checked:
        return result
    for u in cb.unknown_names:
        for c in names:
            tail = tails[u][c]
            if np.isfinite(tail) and tail > tolerance:
                result.warnings.append(
                    f"coordinate {c!r} may be under-resolved for {u!r}: Chebyshev tail {tail:.2g} > {tolerance:.2g}; "
                    f"add nodes to {c!r}")
    return result


def _use_march(problem) -> bool:
    """``method: auto`` marches nonlinear problems and enriches linear ones."""
    nonlinear = any(eq.polynomial.degree >= 2 or has_general(eq.polynomial) for eq in problem.equations)
    method = getattr(problem.solver, "method", "auto")
    if method == "pgd" and nonlinear:
        raise SolverError(f"{problem.source}: solver.method: 'pgd' solves equations linear in the unknowns only; "
                          f"use 'march' or 'auto' for this problem")
    march = method == "march" or (method == "auto" and nonlinear)
    if march and problem.time is None:
        raise SolverError(f"{problem.source}: equations: a steady problem (no time coordinate) needs equations linear "
                          f"in the unknowns and solver.method 'auto' or 'pgd' (the march steps in time)")
    if march and any(c.role == "space" for c in problem.coordinates):
        from .algorithms.pde_system import pde_refusal

        reason = pde_refusal(problem)  # a nonlinear PDE in one space coordinate goes to the PDE march
        if reason:
            raise SolverError(reason)
    return march


def codebook_from_solution(problem, disc, alphas: np.ndarray, factors: list[np.ndarray], report: dict) -> Codebook:
    """Assemble the codebook of a solved problem: lift terms + PGD terms per unknown."""
    from . import __version__

    coords = coordinate_infos(problem, march=False)
    nodal = disc.nodal_factors(factors)
    fields = {}
    for u in disc.unknowns:
        lift = disc.lift[u]
        modes = nodal[u]
        # a term whose time function (steady: its weight, in the first modes) vanishes for this
        # unknown carries nothing for it
        j = 0 if disc.time is None else [c.name for c in coords].index(disc.time)
        keep = np.any(modes[j] != 0.0, axis=0) & (alphas != 0.0)
        fields[u] = CPTensor(
            np.concatenate([lift.weights, alphas[keep]]),
            tuple(np.hstack([lf, nf[:, keep]]) for lf, nf in zip(lift.factors, modes)),
        )
    report = dict(report)
    report["pgdcli_version"] = __version__
    return Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                    description=problem.description)

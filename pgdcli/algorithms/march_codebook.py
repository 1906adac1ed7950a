"""The outcome of a march, converged or not: its codebook (coordinates, fields, report) and message.

Shared by the three marches of nonlinear ODE problems (:mod:`pgdcli.algorithms.march`: the tensor train,
the grid array, the cross of trajectories): each hands over its space-time trains (or where it failed)
and its own report entries; the PDE march (:mod:`pgdcli.algorithms.pde_solve`) shares its time coordinate.
"""

from __future__ import annotations

import numpy as np

from .. import __version__
from ..codebook.codebook import Codebook
from ..discretization.coefficients import separation_report_text
from ..discretization.coordinates import CoordinateInfo, coordinate_infos
from ..tensors.tt import TT
from .outcome import SolverOutcome, Status
from .polynomial_rhs import SINGLE_POINT, NonlinearSystem

__all__ = ["SPACE_TIME_FRACTION", "field_order", "failed_result", "converged_result", "march_coordinates",
           "steps_text"]

# Share of the tolerance for rounding the joined space-time train of the codebook: it sets
# the codebook's ranks (size, query cost) and is added to the error estimate once.
SPACE_TIME_FRACTION = 0.1


def field_order(problem, system: NonlinearSystem) -> tuple[int, ...]:
    """The coordinates of a field's cores (time first, then the train's modes) as spec indices."""
    names = [c.name for c in problem.coordinates]
    single = system.params == [SINGLE_POINT]
    return tuple(names.index(n) for n in [problem.time] + ([] if single else system.params))


def failed_result(problem, system: NonlinearSystem, failure, region: str, tolerance: float, steps: int,
                  wall: float) -> SolverOutcome:
    """A not-converged outcome whose message names where (time, region) the march stopped."""
    coords = coordinate_infos(problem, march=True)
    order = field_order(problem, system)
    where = f" near {region}" if region else ""
    if failure.blowup_time is not None:
        message = (f"not converged: {failure} at t ~ {failure.blowup_time:.4g}{where} (predicted: the march "
                   f"stopped at t = {failure.time:.6g}, its steps shrinking while 1/max|u| falls to zero "
                   f"there)")
    else:
        message = f"not converged: {failure} at t = {failure.time:.6g}{where}"
    report = {"converged": False, "status": int(Status.FAILED), "message": message, "method": "march",
              "tolerance": tolerance, "wall_time": wall, "failed_time": failure.time, "steps": steps,
              "pgdcli_version": __version__}
    if failure.blowup_time is not None:
        report["blowup_time"] = float(failure.blowup_time)
    fields = {u: TT(tuple(np.zeros((1, c.nodes, 1)) for c in [coords[j] for j in order]), order)
              for u in system.unknowns}
    cb = Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                  description=problem.description)
    return SolverOutcome(cb, Status.FAILED, message, tolerance, residuals=np.array([np.inf]), wall_time=wall)


def converged_result(problem, system: NonlinearSystem, result, trains: list[TT], report: dict, tolerance: float,
                     separations: list, wall: float) -> SolverOutcome:
    """The codebook of a march that reached the end from the space-time train of every unknown.

    ``result`` is a :class:`MarchResult` or a grid march's result (``steps``, ``rejected``,
    ``step_sizes``, ``times``, ``breakpoints``, ``error_estimate``); ``report`` holds the entries
    of that march (``pgdcli.algorithms.march``'s report of the tensor-train march, or the grid and
    cross marches' entries).
    """
    coords = march_coordinates(problem, result)
    order = field_order(problem, system)
    fields = {}
    for u, train in zip(system.unknowns, trains):
        cores = train.cores
        if system.params == [SINGLE_POINT]:  # fold the virtual one-node mode into the time core
            cores = (np.tensordot(cores[0], cores[1][:, 0, :], axes=(2, 0)),)
        fields[u] = TT(cores, order)
    estimate = result.error_estimate + SPACE_TIME_FRACTION * tolerance  # + the space-time rounding
    message = (f"converged: reached t = {system.time_basis.nodes[-1]:.6g} in {result.steps} steps "
               f"({result.rejected} rejected), error estimate {estimate:.3g} (tolerance {tolerance:.3g})")
    report = {"converged": True, "status": int(Status.CONVERGED), "message": message, "method": "march",
              "modes": int(max(f.rank for f in fields.values())), "residual": float(estimate),
              "error_estimate": float(estimate), "tolerance": float(tolerance), "steps": int(result.steps),
              "rejected_steps": int(result.rejected), "step_sizes": np.array(result.step_sizes), **report,
              "max_rank": int(problem.solver.max_rank), "wall_time": wall, "pgdcli_version": __version__}
    if separations:  # how many terms each non-separable coefficient needed
        report["separated_coefficients"] = separation_report_text(separations)
    cb = Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                  description=problem.description)
    return SolverOutcome(cb, Status.CONVERGED, message, tolerance, steps_text(problem, result.steps, result.rejected),
                         residuals=np.array([estimate]), wall_time=wall)


def march_coordinates(problem, result) -> list:
    """The codebook's coordinates of a march: with automatic slabs, the time coordinate's are its accepted steps.

    ``result`` has ``breakpoints`` (None without automatic slabs) and ``times``, the time nodes the states are at.
    """
    coords = coordinate_infos(problem, march=True)
    if result.breakpoints is None:
        return coords
    t = problem.time_coordinate
    bp = result.breakpoints.copy()
    bp[0], bp[-1] = t.domain
    k = [c.name for c in problem.coordinates].index(t.name)
    coords[k] = CoordinateInfo(t.name, tuple(t.domain), len(result.times), t.discretization, t.role,
                               tuple(float(v) for v in bp))
    # the codebook's basis puts the nodes where the march stored the states
    assert np.allclose(coords[k].basis().nodes, result.times, rtol=0, atol=1e-12 * max(1.0, abs(bp[-1])))
    return coords


def steps_text(problem, steps: int, rejected: int) -> str:
    """``"reached t = 0.5 in 7 steps (0 rejected)"``: a march's summary."""
    end = problem.time_coordinate.domain[1]
    return f"reached {problem.time} = {end:.6g} in {steps} steps ({rejected} rejected)"

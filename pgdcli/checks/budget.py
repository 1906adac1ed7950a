"""The cost of a solve and of its reference check, estimated before either starts.

A valid spec can still ask for more than any machine gives: a billion time slabs, a thousand
unknowns coupled in one dense system, fifty coordinates, or a time domain of a hundred million
periods. :func:`check_budget` estimates what the solve and its error gate would allocate and
integrate, from the spec's numbers and one linearization of the equations at their initial
values, and refuses work over the documented limits (:mod:`pgdcli.limits`) with one line naming
the key, the estimate and the limit's variable, before any solve starts.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import LimitError, SolverError
from ..limits import MAX_COORDINATES, MAX_UNKNOWNS, limit
from .reference_system import CompiledSystem, reference_jacobian

__all__ = ["check_budget", "time_nodes", "fastest_rate"]

#: Parameter points at which the equations are linearized: the centre and up to this many corners.
LINEARIZATION_CORNERS = 16


def check_budget(problem, *, march: bool) -> None:
    """Refuse a problem whose solve (by the march when ``march``, else the enrichment) or check
    would exceed a documented limit.

    Raises
    ------
    LimitError
        One line: the spec's key at fault, the estimate and the limit with its variable.
    """
    src = problem.source
    d, q = len(problem.coordinates), len(problem.unknowns)
    if d > MAX_COORDINATES:
        raise LimitError(f"{src}: coordinates: {d} coordinates; at most {MAX_COORDINATES}")
    if q > MAX_UNKNOWNS:
        raise LimitError(f"{src}: unknowns: {q} unknowns (first-order ones included); at most {MAX_UNKNOWNS}")
    if problem.time is None:
        return
    n_time, key = time_nodes(problem)
    cap = limit("time_nodes")
    if n_time > cap:
        raise LimitError(f"{src}: {key}: {n_time:.3g} time nodes; at most {cap} (PGD_MAX_TIME_NODES)")
    if not march:
        _check_enrichment(problem, n_time)
    if not any(c.role == "space" for c in problem.coordinates):
        _check_periods(problem)


def time_nodes(problem) -> tuple[int, str]:
    """The time nodes a solve starts with (slabs x nodes per slab), and the spec key that sets them."""
    t = problem.time_coordinate
    slabs = getattr(problem.solver, "time_slabs", "auto")
    if isinstance(slabs, int) and slabs > 1:
        return slabs * (t.nodes - 1) + 1, "solver.time_slabs"
    return t.nodes, f"coordinates.{t.name}.nodes"


def _check_enrichment(problem, n_time: int) -> None:
    """The enrichment's state (unknowns x time nodes) is one dense mode: its operator terms are
    dense matrices of its size squared, one per linear term of the equations."""
    q = len(problem.unknowns)
    state = q * n_time
    cap = limit("state_size")
    if state > cap:
        raise LimitError(f"{problem.source}: unknowns: the enrichment's dense state has {q} unknowns x {n_time} "
                         f"time nodes = {state} values; at most {cap} (PGD_MAX_STATE_SIZE): fewer unknowns or "
                         f"time nodes, or solver.method: march")
    terms = sum(len(list(eq.polynomial.items())) for eq in problem.equations)
    need = terms * state * state * 8
    cap = limit("work_bytes")
    if need > cap:
        raise LimitError(f"{problem.source}: equations: {terms} linear terms on a dense state of {state} values "
                         f"need {need / 2**30:.3g} GiB of operators; at most {cap / 2**30:.3g} GiB "
                         f"(PGD_MAX_WORK_BYTES)")


def _check_periods(problem) -> None:
    rate = fastest_rate(problem)
    if rate is None:
        return
    t0, t1 = problem.time_coordinate.domain
    periods = (t1 - t0) * rate / (2.0 * math.pi)
    cap = limit("periods")
    if periods > cap:
        raise LimitError(f"{problem.source}: coordinates.{problem.time}.domain: [{t0:g}, {t1:g}] spans about "
                         f"{periods:.3g} periods of the fastest oscillation of the equations at their initial "
                         f"values (angular frequency {rate:.3g}); at most {cap} (PGD_MAX_PERIODS): shorten "
                         f"the time domain")


def fastest_rate(problem) -> float | None:
    """The largest angular frequency ``|Im lambda|`` of the equations' Jacobian at the initial values.

    At the centre of the parameter box and up to :data:`LINEARIZATION_CORNERS` of its corners, the
    reference's Jacobian (:func:`~pgdcli.checks.reference_system.reference_jacobian`). None when the reference cannot
    compile the equations (they are refused elsewhere) or the Jacobian is not finite.
    """
    params = _linearization_points(problem)
    S = len(next(iter(params.values()))) if params else 1
    try:
        with np.errstate(all="ignore"):
            system = CompiledSystem(problem, params, S, max_evaluations=10 * MAX_UNKNOWNS)
            y0 = system.initial(problem, params)
            t0 = float(problem.time_coordinate.domain[0])
            J = reference_jacobian(system, t0, y0)
    except (SolverError, ValueError, ArithmeticError, np.linalg.LinAlgError):
        return None
    finite = np.isfinite(J).all(axis=(1, 2))
    if not finite.any():
        return None
    return float(np.abs(np.linalg.eigvals(J[finite]).imag).max())


def _linearization_points(problem) -> dict[str, np.ndarray]:
    """Parameter coordinate -> values (S,): the box's centre, then corners (all, or a seeded sample)."""
    params = [c for c in problem.coordinates if c.name != problem.time]
    if not params:
        return {}
    low = np.array([c.domain[0] for c in params])
    high = np.array([c.domain[1] for c in params])
    n = len(params)
    if 2 ** n <= LINEARIZATION_CORNERS:
        bits = (np.arange(2 ** n)[:, None] >> np.arange(n)) & 1
    else:
        bits = np.random.default_rng(0).integers(0, 2, size=(LINEARIZATION_CORNERS, n))
    points = np.vstack([(low + high) / 2, low + bits * (high - low)])
    return {c.name: points[:, j] for j, c in enumerate(params)}

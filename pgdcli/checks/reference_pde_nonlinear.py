"""Independent method-of-lines reference for nonlinear PDEs and reaction-diffusion systems.

Fisher-KPP ``der(u) = D*der(u, x, 2) + r*u*(1 - u)``, viscous Burgers, Gray-Scott or Brusselator
systems of two species, Allen-Cahn in two space coordinates: equations polynomial in the unknowns
*and their space derivatives*, or holding functions of them (``u*v/(1 + u)``), which the linear
method-of-lines reference (:func:`pgdcli.checks.reference.solve_reference_pde`) refuses. This module
solves them one parameter sample at a time by strong-form Chebyshev collocation in one or two space
coordinates (:mod:`.reference_pde_collocated`: the reference's own nodes, differentiation matrices and
boundary elimination, never the solvers') and ``solve_ivp`` (Radau, with the Jacobian) on the
interior values.

Its own error is measured, not assumed: the solve is repeated on finer grids (one space coordinate:
``n -> 2n - 1`` nodes from :data:`START_NODES`; two: :data:`START_NODES_2D` nodes along each, then
:data:`STEP_2D` more, a dense implicit solve on ``n^2`` values costing ``n^6``) until two successive
grids agree at the requested points within ``space_tolerance``, or until three grids show the spectral
convergence (a geometric fall of the differences between them) that puts the finest grid's predicted
error within it (:func:`grid_error_estimate`). The returned ``error_estimate`` is that last difference
(the coarser grid's error, an upper estimate of the finer one's once the spectral convergence has set
in) or that prediction with a factor of safety, and a caller must not certify errors below it. Measured against
the exact Cole-Hopf solution of Burgers and exact solutions of systems and 2-D problems
(``tests/checks/test_reference_pde_nonlinear.py``).
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass
from functools import partial
from typing import Mapping

import numpy as np

from .. import executors
from ..blas import one_blas_thread
from ..errors import SolverError
from ..problem.general import has_general
from .collocation import barycentric_matrix, chebyshev_weights
from .reference_base import TIME_UP, ReferenceTimeUp, under_deadline
from .reference_ode import parse_cached
from .reference_pde import PdeReferenceResult
from .reference_pde_collocated import CollocatedModel

__all__ = ["NonlinearPdeReference", "solve_reference_nonlinear_pde", "solve_reference_nonlinear_grid",
           "is_nonlinear_pde", "START_NODES", "MAX_NODES", "START_NODES_2D", "MAX_NODES_2D",
           "space_tolerances", "grid_error_estimate"]

START_NODES = 33
MAX_NODES = 513
#: Two space coordinates: first nodes along each, the step between grids, the finest grid.
START_NODES_2D, STEP_2D, MAX_NODES_2D = 17, 8, 57
#: Radau's rtol = atol. Its global error stays below half of it (Fisher, Brusselator: 3.8e-11 and 5.6e-11 at
#: 1e-10, against a solve at 1e-13), ten thousand times below a tolerance of 1e-6 and twenty times below the
#: grids' agreement; a tenth of it cost 1.4-1.8 times the steps.
RTOL = 1e-10
#: A sample whose two finest grids still differ by more than this (at the finest grid) counts as failed,
#: and the grids stop refining below ``SPACE_TOLERANCE``; both scale with the problem's tolerance above
#: ``TOLERANCE_SCALE`` (:func:`space_tolerances`).
SPACE_TOLERANCE, SPACE_TOLERANCE_LIMIT = 1e-9, 1e-8
TOLERANCE_SCALE = 1e-6
#: Two successive differences between grids that fall by this factor or more show spectral convergence
#: (geometric in the nodes): the next difference, the finest grid's error, is predicted as the last times
#: their ratio, and counted ``PREDICTION_SAFETY`` times over.
GEOMETRIC_RATIO, PREDICTION_SAFETY = 0.05, 10.0
#: Above this many unknowns the Radau Jacobian stays sparse (its LU by SuperLU); below, dense (LAPACK).
DENSE_JACOBIAN = 4000


def space_tolerances(problem) -> tuple[float, float, float]:
    """``(grids agree to, a sample fails beyond, Radau's rtol = atol)`` for the problem's tolerance: 1e-9,
    1e-8 and 1e-10 up to a tolerance of 1e-6, in proportion above (a thousandth, a hundredth and a
    ten-thousandth of it)."""
    scale = max(1.0, float(problem.solver.tolerance) / TOLERANCE_SCALE)
    return SPACE_TOLERANCE * scale, SPACE_TOLERANCE_LIMIT * scale, RTOL * scale


@dataclass
class NonlinearPdeReference:
    """Values of the reference at the requested points.

    Attributes
    ----------
    values : dict of str to ndarray (S, T, P) or (S, T, P_1, ..., P_d)
        Per unknown: sample, time, space point (scattered points) or space grid.
    error_estimate : float
        Max abs difference between the last two grids at the points (the reference's own error).
    nodes : int
        Space nodes (along each space coordinate) of the finest grid.
    """

    values: dict
    error_estimate: float
    nodes: int


def _grids(problem, start: int | None, max_nodes: int | None) -> list[int]:
    """The node counts tried, coarsest first."""
    d = sum(1 for c in problem.coordinates if getattr(c, "role", "") == "space")
    if d >= 2:
        first, last = start or START_NODES_2D, max_nodes or MAX_NODES_2D
        return list(range(first, last + 1, STEP_2D)) or [first]
    first, last = start or START_NODES, max_nodes or MAX_NODES
    out = [first]
    while 2 * out[-1] - 1 <= last:
        out.append(2 * out[-1] - 1)
    return out


#: Solutions kept (dense output per sample and grid): the error gate checks the codebooks of successive
#: rounds of the automatic resolution at the same parameter samples, and the reference is most of its time.
CACHE_SIZE = 64
_SOLUTIONS: dict = {}
_SOLUTIONS_LOCK = threading.Lock()  # samples may be solved on threads (solve_reference_nonlinear_grid)


def _sample_key(sample) -> tuple:
    """A parameter sample ``{name: value}`` as part of a cache key."""
    return tuple(sorted((k, float(np.reshape(v, -1)[0])) for k, v in sample.items()))


def _remember(key, solution) -> None:
    """Keep a sample's solution (the oldest goes past :data:`CACHE_SIZE`)."""
    with _SOLUTIONS_LOCK:
        while len(_SOLUTIONS) >= CACHE_SIZE:
            _SOLUTIONS.pop(next(iter(_SOLUTIONS)))
        _SOLUTIONS[key] = solution


def _sample_solution(problem, n: int, sample, t_end: float, rtol, atol):
    """``(GridMap, OdeSolution)`` of one sample on an ``n``-node grid over ``[t0, t_end]`` (cached; the grid
    and its map to nodal values: :class:`~pgdcli.checks.reference_pde_collocated.GridMap`)."""
    from scipy.integrate import solve_ivp

    key = (problem.source_text, _sample_key(sample), n, float(t_end), rtol, atol)
    with _SOLUTIONS_LOCK:
        if key in _SOLUTIONS:
            return _SOLUTIONS[key]
    model = CollocatedModel(problem, n, sample)
    t0 = float(problem.time_coordinate.domain[0])
    size = model.q * model.m

    def jac(t, y):
        J = model.jacobian(t, y)
        return J.toarray() if size <= DENSE_JACOBIAN else J

    # solve_ivp's t_eval is read from the same dense output: keeping it changes nothing in accuracy. Radau's
    # LU factorizations (n^2 values in two space coordinates) on one BLAS thread: small factorizations
    # lose more to threads competing for the cores than they gain from them
    with one_blas_thread():
        sol = solve_ivp(model.rhs, (t0, t_end), model.initial(problem), method="Radau", dense_output=True,
                        rtol=rtol, atol=atol, jac=jac)
    if sol.status != 0 or not np.isfinite(sol.y).all():
        raise SolverError(f"{problem.source}: the nonlinear method-of-lines reference failed at {dict(sample)} "
                          f"on {n} nodes: {sol.message}")
    _remember(key, (model.grid_map, sol.sol))
    return model.grid_map, sol.sol


def _interpolation(nodes, points, grid: bool) -> list:
    """Per space axis of the grid ``nodes`` (:class:`~pgdcli.checks.reference_pde_collocated.GridMap`), the
    barycentric rows (P_a, n) at the points (grid: per axis; else scattered (P, d))."""
    weights = chebyshev_weights(nodes.n)
    if grid:
        return [barycentric_matrix(axis, weights, np.asarray(p, dtype=float)) for axis, p in zip(nodes.axes, points)]
    points = np.asarray(points, dtype=float).reshape(-1, len(nodes.axes))
    return [barycentric_matrix(axis, weights, points[:, a]) for a, axis in enumerate(nodes.axes)]


def _solve_sample(problem, n: int, sample, times, points, grid: bool, rtol, atol) -> np.ndarray:
    """Values (q, T, P) or (q, T, P_1, ..., P_d) of one sample on an ``n``-node grid."""
    t_end = float(problem.time_coordinate.domain[1])
    nodes, sol = _sample_solution(problem, n, sample, max(t_end, float(np.max(times))), rtol, atol)
    W = _interpolation(nodes, points, grid)
    Y = sol(np.asarray(times, dtype=float))  # (q m, T)
    full = np.stack([nodes.full(Y[:, k]) for k in range(Y.shape[1])], axis=1)  # (q, T, N)
    full = full.reshape(full.shape[:2] + nodes.shape)
    if grid:
        for a, Wa in enumerate(W):  # along each space axis in turn
            full = np.moveaxis(np.tensordot(full, Wa, axes=(2 + a, 1)), -1, 2 + a)
        return full
    if len(W) == 1:
        return full @ W[0].T
    return np.einsum("qtij,pi,pj->qtp", full, W[0], W[1])


def solve_reference_nonlinear_pde(problem, params: Mapping[str, np.ndarray], times: np.ndarray,
                                  points: np.ndarray, *, space_tolerance: float | None = None,
                                  rtol: float | None = None, atol: float | None = None, start_nodes: int | None = None,
                                  max_nodes: int | None = None, grid: bool = False) -> NonlinearPdeReference:
    """The problem at samples x times x space points, on finer grids until two agree.

    Parameters
    ----------
    problem : Problem
        One or two space coordinates, equations ``m der(u) + sum of monomials = 0`` (monomials of unknowns,
        their space derivatives and general atoms), one per unknown.
    params : mapping of str to ndarray (S,)
        The parameter samples.
    times : ndarray (T,)
        Ascending output times (the start time may be included).
    points : ndarray (P,) or (P, d), or with ``grid`` a sequence of d arrays
        Space points (scattered), or the points along each space coordinate of a tensor grid.
    space_tolerance, rtol, atol : float, optional
        Two successive grids must agree to ``space_tolerance`` (max abs at the points) to stop; Radau's
        tolerances. Defaults: :func:`space_tolerances` of the problem.

    Returns
    -------
    NonlinearPdeReference
    """
    S = int(np.broadcast_shapes(*(np.shape(v) for v in params.values()))[0]) if params else 1
    arrays = {k: np.broadcast_to(np.asarray(v, dtype=float), (S,)) for k, v in params.items()}
    times = np.asarray(times, dtype=float)
    default, _, default_rtol = space_tolerances(problem)
    tolerance = default if space_tolerance is None else space_tolerance
    rtol = default_rtol if rtol is None else rtol
    atol = default_rtol if atol is None else atol
    names = list(problem.unknown_names)
    previous, differences, estimate = None, [], np.inf
    for n in _grids(problem, start_nodes, max_nodes):
        current = np.stack([_solve_sample(problem, n, {k: v[i] for k, v in arrays.items()}, times, points, grid,
                                          rtol, atol) for i in range(S)])  # (S, q, T, ...)
        if previous is not None:
            differences.append(float(np.max(np.abs(current - previous))))
            estimate = grid_error_estimate(differences, floor=rtol * max(1.0, float(np.max(np.abs(current)))))
            if estimate <= tolerance:
                break
        previous = current
    return NonlinearPdeReference({u: current[:, i] for i, u in enumerate(names)}, estimate, n)


def grid_error_estimate(differences, floor: float = 0.0) -> float:
    """The finest grid's error, estimated from the max abs differences between successive grids (coarsest first).

    The last difference (an upper estimate of the finer grid's error once the convergence is spectral); or, where
    the last two fall by :data:`GEOMETRIC_RATIO` or more, the next difference predicted from their ratio
    (``ratio * last``, exact for a geometric fall, an overestimate for the faster one of doubled grids) times
    :data:`PREDICTION_SAFETY`, but not below ``floor`` (the time integration's own error, which no finer grid
    removes), if that is smaller. Saves the finest grid's solve, the dearest by far (a dense implicit step on
    ``n^2`` values in two space coordinates costs ``n^6``).
    """
    last = float(differences[-1])
    if len(differences) >= 2 and differences[-2] > 0 and last <= GEOMETRIC_RATIO * differences[-2]:
        return min(last, max(floor, PREDICTION_SAFETY * last * (last / float(differences[-2]))))
    return last


def is_nonlinear_pde(problem) -> bool:
    """A problem with space coordinates whose equations are not linear in the unknowns (this module's case)."""
    space = any(getattr(c, "role", "") == "space" for c in problem.coordinates)
    return space and any(eq.polynomial.degree >= 2 or has_general(eq.polynomial) for eq in problem.equations)


def solve_reference_nonlinear_grid(problem, params: Mapping[str, np.ndarray], space_points: Mapping[str, np.ndarray],
                                   times: np.ndarray, *, progress=None, executor=None, **_ignored) -> PdeReferenceResult:
    """:func:`solve_reference_nonlinear_pde` in the form of the linear reference's grid result (``pgd verify``).

    Each sample is solved on its own (its grids refined until they agree), so that a failing sample is
    reported alone (NaN values, ``success`` False, the message), by the workers of ``executor`` (default:
    the one in effect, :mod:`pgdcli.executors`). The method-of-lines options of the linear reference
    (``method``, ``space_nodes``, ...) do not apply and are ignored.

    Returns
    -------
    pgdcli.checks.reference_pde.PdeReferenceResult
        ``values[u]`` of shape (S, T, P_1, ..., P_d) on the tensor grid of the space points.
    """
    space = [c.name for c in problem.coordinates if getattr(c, "role", "") == "space"]
    axes = [np.asarray(space_points[x], dtype=float) for x in space]
    S = int(np.broadcast_shapes(*(np.shape(v) for v in params.values()))[0]) if params else 1
    arrays = {k: np.broadcast_to(np.asarray(v, dtype=float), (S,)) for k, v in params.items()}
    times = np.asarray(times, dtype=float)
    names = list(problem.unknown_names)
    values = {u: np.full((S, times.size) + tuple(a.size for a in axes), np.nan) for u in names}
    success, messages = np.zeros(S, dtype=bool), [""] * S
    nodes = _grids(problem, None, None)[0]
    samples = [{k: v[i:i + 1] for k, v in arrays.items()} for i in range(S)]
    runner, task, own = _runner(problem, executor, samples, len(space), times, axes)
    with runner if own else contextlib.nullcontext():  # a pool started here is closed here
        for done, (i, outcome) in enumerate(runner.as_completed(task, samples), 1):
            try:
                found, message, *solutions = outcome.result()
            except ReferenceTimeUp:  # the samples after it stop at once too
                found, message, solutions = None, TIME_UP, []
            for key, value in (solutions[0] if solutions else []):  # a worker's: kept for the next round
                _remember(key, value)
            messages[i] = message
            if found is not None:
                success[i] = True
                nodes = max(nodes, found.nodes)
                for u in names:
                    values[u][i] = found.values[u][0]
            if progress is not None:
                progress(done)
    _, _, rtol = space_tolerances(problem)
    return PdeReferenceResult(values=values, success=success, messages=messages, space=space,
                              space_points=dict(zip(space, axes)), nodes={x: nodes for x in space}, method="Radau",
                              rtol=rtol, atol=rtol, times=times)


def _runner(problem, executor, samples: list, dims: int, times, axes):
    """``(executor, task, own)`` for the samples: the executor given or in effect; else, on the cores left
    idle, threads for two space coordinates (Radau's LU of their grids releases the GIL) and forked
    processes for one (its Python steps hold the GIL; a fork is cheap and sees this process's solutions),
    or this process (every sample solved before: from the cache). ``own``: a pool started here, to be closed
    by the caller."""
    runner = executors.as_executor(executor) if executor is not None else executors.current()
    remote = partial(_sample_task, problem.source_text, problem.source, times, axes)
    if problem.source_text and not isinstance(runner, executors.SerialExecutor):
        return runner, under_deadline(remote), False
    here = partial(_one_sample, problem, times=times, points=axes)
    workers = min(len(samples), executors.free_cores())
    with _SOLUTIONS_LOCK:
        solved = {key[1] for key in _SOLUTIONS if key[0] == problem.source_text}
    if workers < 2 or all(_sample_key(sample) in solved for sample in samples):
        return runner, here, False
    if dims >= 2:
        return executors.ThreadExecutor(workers), here, True
    if problem.source_text and executors.pool_context().get_start_method() == "fork":
        return executors.ProcessExecutor(workers), under_deadline(remote), True
    return runner, here, False


def _one_sample(problem, sample, times, points) -> tuple[NonlinearPdeReference | None, str]:
    """One sample's reference on the tensor grid of ``points`` (one array per space coordinate) and ``''``,
    or None and why it failed (ReferenceTimeUp: the time budget)."""
    try:
        with one_blas_thread():  # as in a worker (pgdcli.executor_base.run_in_worker): the same floats here
            ref = solve_reference_nonlinear_pde(problem, sample, times, points, grid=True)
    except SolverError as exc:
        return None, " ".join(str(exc).split())
    _, limit, _ = space_tolerances(problem)
    if ref.error_estimate > limit:
        return None, (f"the reference's grids did not agree (difference {ref.error_estimate:.2g} with "
                      f"{ref.nodes} nodes)")
    return ref, ""


def _sample_task(spec_text: str, source: str, times, points, sample):
    """A worker's task: parse the spec again, solve one sample (:func:`_one_sample`); with the sample's
    solutions (cache entries), which the caller keeps: the next round's gate reuses them."""
    mine = _sample_key(sample)
    with _SOLUTIONS_LOCK:  # a forked worker holds the caller's solutions already
        known = {key for key in _SOLUTIONS if key[1] == mine}
    found, message = _one_sample(parse_cached(spec_text, source), sample, times, points)
    with _SOLUTIONS_LOCK:
        solutions = [(key, value) for key, value in _SOLUTIONS.items() if key[1] == mine and key not in known]
    return found, message, solutions

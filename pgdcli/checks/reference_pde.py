"""The method-of-lines reference of problems with space coordinates (BDF/Radau with the exact
Jacobian, or sparse LU for steady problems) on the collocation grid of :mod:`.collocation`;
the interpolation to the points asked is in :mod:`.reference_pde_points`.

The integration (transient, steady, chunked over workers) and its failure isolation per sample
are one path, kept in one module.
"""

from __future__ import annotations

from dataclasses import dataclass, field
import functools
import math
from functools import partial
from typing import Callable, Mapping

import numpy as np
from scipy.sparse.linalg import splu

from ..blas import one_blas_thread
from ..errors import SolverError
from .collocation import PdeModel
from .collocation_system import PdeSystem
from .reference_base import (DEFAULT_MAX_EVALUATIONS, DEFAULT_SPACE_NODES, PDE_ATOL, PDE_METHODS, PDE_RTOL,
                             CHUNKS, ReferenceBudgetExceeded, ReferenceResult, check_tolerances, checked_params,
                             chunk_executor, reference_times, run_in_chunks, sample_subset, sampled_coordinates,
                             space_coordinates, start_time)
from .reference_ode import parse_cached, scores
from .reference_pde_modal import modal_reference
from .reference_pde_points import (at_points, checked_space_points, clipped_to_domain, interpolation_matrices,
                                   values_at_space_points)

__all__ = ["PdeReferenceResult", "solve_reference_pde"]


# ----------------------------------------------------------------------------------------------
# method of lines: problems with space coordinates
# ----------------------------------------------------------------------------------------------
# Strong-form Chebyshev-Gauss-Lobatto collocation, written here from scratch (nodes,
# differentiation matrices, barycentric interpolation) so that it shares nothing with the PGD
# solver's weak-form discretization in pgdcli.discretization.basis / pgdcli.discretization.linear.

# unknowns per vectorized solve_ivp call (samples integrated together as one block-diagonal system);
# the error norm of solve_ivp is an RMS over the state, so few samples share one call
_PDE_CHUNK_STATES = 1024
_PDE_MAX_CHUNK = 8
# The exact Jacobian goes to solve_ivp as a dense array up to this many unknowns per call, as a sparse
# matrix beyond. Collocation couples every node of a grid line, so the LU of a 2D operator fills in
# almost completely: LAPACK's dense LU is several times faster than SuperLU's on the 2-D heat example's
# 38 x 38 interior nodes, per factorization and per sample.
_DENSE_JACOBIAN_LIMIT = 4096
def _solve_steady_pde(model: PdeModel, params, S, times):
    """Sparse LU solves of ``A y + b = 0``, one per sample, as :func:`_integrate_pde` returns them.

    A sample whose matrix is singular (a pivot below 1e-12 of the largest: pure Neumann
    conditions, say) fails rather than returning the garbage a near-zero pivot gives.
    """
    q, n, m = model.q, model.grid.n, model.m
    with np.errstate(all="ignore"):
        system = PdeSystem(model, params, S, 0)
        A = system.matrix(0.0).tocsr()
        b = np.asarray(sum(system.b.values()) if system.b else np.zeros(S * m), dtype=float)
        y = np.full((S, m), np.nan)
        for i in range(S):
            rows = slice(i * m, (i + 1) * m)
            try:
                lu = splu(A[rows, rows].tocsc())
            except RuntimeError:  # SuperLU: "Factor is exactly singular"
                continue
            pivots = np.abs(lu.U.diagonal())
            if np.isfinite(pivots).all() and pivots.min() > 1e-12 * pivots.max():
                y[i] = lu.solve(-b[rows])
    finite = np.isfinite(y).all(axis=1)
    if not finite.all():
        return None, ~finite, ("the steady system is singular at this point (do the boundary conditions determine "
                               "the solution?)")
    full = (model.Z @ y.T).T + system.h  # (S, q n)
    out = np.broadcast_to(full.reshape(S, q, 1, n), (S, q, times.size, n)).copy()
    return out, np.zeros(S, dtype=bool), ""


def _integrate_pde(model: PdeModel, params, S, t0, times, method, rtol, atol, max_evaluations):
    """One solve_ivp call over S samples. Returns (full grid values (S, q, T, n) or None, failed, message).

    A steady problem (no time coordinate) is one linear solve; its values repeat over ``times``.
    """
    from scipy.integrate import solve_ivp

    if model.time is None:
        return _solve_steady_pde(model, params, S, times)
    q, n, T = model.q, model.grid.n, times.size
    with np.errstate(all="ignore"):
        system = PdeSystem(model, params, S, max_evaluations)
        u0 = model.initial_grid(params, S)
    if system.bad.any():
        return None, system.bad, system.bad_reason
    if not np.isfinite(u0).all():
        return None, ~np.isfinite(u0).reshape(S, -1).all(axis=1), "the initial value is not finite at this point"
    out = np.empty((S, q, T, n))
    late = times > t0
    out[:, :, ~late, :] = u0[:, :, None, :]
    if not late.any():
        return out, np.zeros(S, dtype=bool), ""
    y0 = model.interior_values(u0).reshape(-1)
    dense = y0.size <= _DENSE_JACOBIAN_LIMIT
    if system.constant:
        J = system.jacobian(t0, y0)
        jac = J.toarray() if dense else J.tocsc()
    else:
        def jac(t, y):
            J = system.jacobian(t, y)
            return J.toarray() if dense else J.tocsc()
    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(system, (t0, float(times[-1])), y0, method=method, rtol=rtol, atol=atol, jac=jac,
                            t_eval=times[late])
    except ReferenceBudgetExceeded:
        return None, scores(system, S), (
            f"gave up after {max_evaluations} right-hand side evaluations")
    except (np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError, RuntimeError) as exc:
        return None, scores(system, S), f"integration failed: {' '.join(str(exc).split()) or type(exc).__name__}"
    if sol.status != 0 or sol.y.shape[1] != int(np.count_nonzero(late)):
        where = f" at {model.time} = {sol.t[-1]:.6g}" if sol.t.size else ""
        return None, scores(system, S), f"integration failed{where}: {sol.message}"
    y = sol.y.reshape(S, model.m, -1)  # (S, m, T_late)
    if not np.isfinite(y).all():
        finite = np.isfinite(y).reshape(S, -1).all(axis=1)
        return None, ~finite, "the solution is not finite (blow-up)"
    full = np.stack([model.Z @ y[i] for i in range(S)]) + system.h[:, :, None]  # (S, q n, T_late)
    out[:, :, late, :] = full.reshape(S, q, n, -1).transpose(0, 1, 3, 2)
    return out, np.zeros(S, dtype=bool), ""


def _solve_group_pde(model, params, S, t0, times, method, rtol, atol, max_evaluations):
    """Integrate S samples together; when the call fails, each sample on its own."""
    q, n = model.q, model.grid.n
    out, bad, message = _integrate_pde(model, params, S, t0, times, method, rtol, atol, max_evaluations)
    if out is not None:
        return out, np.ones(S, dtype=bool), [""] * S
    if S == 1:
        return np.full((1, q, times.size, n), np.nan), np.zeros(1, dtype=bool), [message]
    values = np.full((S, q, times.size, n), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if bad.dtype == bool:
        for i in np.flatnonzero(bad):
            messages[i] = message
        singles = np.flatnonzero(~bad)
    else:
        singles = np.arange(S)
    for i in singles:
        rows = np.array([i])
        v, ok, msgs = _solve_group_pde(model, sample_subset(params, rows), 1, t0, times, method, rtol, atol,
                                       max_evaluations)
        values[i], success[i], messages[i] = v[0], ok[0], msgs[0]
    return values, success, messages


@functools.lru_cache(maxsize=4)
def _pde_model(text: str, source: str, nodes: tuple) -> PdeModel:
    return PdeModel(parse_cached(text, source), dict(nodes))


def _pde_chunk_worker(spec_text, source, nodes, settings, chunk):
    """A worker's task: parse the spec again, build the grid, integrate one chunk ``(params, samples)``."""
    model = _pde_model(spec_text, source, nodes)
    with one_blas_thread():  # the method of lines' LU factorizations (see pgdcli.blas)
        return _solve_group_pde(model, *chunk, *settings)


@dataclass
class PdeReferenceResult:
    """Method-of-lines reference values of every unknown.

    Attributes
    ----------
    values : dict of str to ndarray
        Unknown name -> values, shape ``(S, T, X_1, ..., X_d)`` on the tensor grid of the
        requested space points (``grid=True``, or the collocation nodes when no points were
        given), or ``(S, T, P)`` at ``P`` scattered space points (``grid=False``). NaN where the
        sample failed.
    success : ndarray of bool, shape (S,)
    messages : list of str
    space : list of str
        The space coordinates, in the order of the space axes.
    space_points : dict of str to ndarray
        The space points of each coordinate (as requested, or the collocation nodes).
    nodes : dict of str to int
        Collocation nodes per space coordinate.
    grid : bool
    method, rtol, atol, times
        The settings used and the times as given.
    """

    values: dict[str, np.ndarray]
    success: np.ndarray
    messages: list[str]
    space: list[str]
    space_points: dict[str, np.ndarray]
    nodes: dict[str, int]
    grid: bool = True
    method: str = "BDF"
    rtol: float = PDE_RTOL
    atol: float = PDE_ATOL
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))

    @property
    def n_failed(self) -> int:
        return int(np.count_nonzero(~self.success))


def _space_nodes(problem, space_nodes) -> dict[str, int]:
    names = [c.name for c in space_coordinates(problem)]
    if isinstance(space_nodes, Mapping):
        extra = [k for k in space_nodes if k not in names]
        if extra:
            raise SolverError(f"space_nodes: {extra[0]!r} is not a space coordinate ({', '.join(names)})")
        counts = {n: space_nodes.get(n, DEFAULT_SPACE_NODES) for n in names}
    else:
        counts = {n: space_nodes for n in names}
    for n, k in counts.items():
        if isinstance(k, bool) or not isinstance(k, (int, np.integer)) or not 3 <= k <= 1000:
            raise SolverError(f"space_nodes: expected an integer from 3 to 1000 for {n!r}, got {k!r}")
    return {n: int(k) for n, k in counts.items()}


def _grid_states(problem, arrays, S, times, *, nodes, method, rtol, atol, jobs, chunk_size, progress,
                 max_evaluations, executor=None):
    """Full-grid values (S, q, T_unique, n) at the unique sorted times, success, messages, the model, the
    unique times and the inverse map, and the method that computed them (:mod:`.reference_pde_modal`
    for a time-invariant linear system whose samples share one operator, with the default BDF)."""
    t0 = start_time(problem)
    unique, inverse = np.unique(times, return_inverse=True)
    model = _pde_model(problem.source_text, problem.source, tuple(sorted(nodes.items()))) \
        if problem.source_text else PdeModel(problem, nodes)
    q, n = model.q, model.grid.n
    values = np.full((S, q, unique.size, n), np.nan)
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if chunk_size is None:  # whatever runs the chunks (samples sharing a call share its steps)
        chunk_size = max(1, min(_PDE_MAX_CHUNK, _PDE_CHUNK_STATES // max(model.m, 1), math.ceil(S / CHUNKS)))
    if S and (model.time is None or method == "BDF"):  # a shared eigenbasis (the default method): once for all
        exact = modal_reference(model, arrays, S, t0, unique, rtol, atol)
        if exact is not None:
            if progress is not None:
                progress(S)
            return exact[0], np.ones(S, dtype=bool), messages, model, unique, inverse, exact[1] or method
    settings = (t0, unique, method, float(rtol), float(atol), int(max_evaluations))
    key = tuple(sorted(nodes.items()))
    # a problem without spec text cannot be rebuilt in a worker: solve it here
    task = partial(_pde_chunk_worker, problem.source_text, problem.source, key, settings) \
        if problem.source_text else None
    with chunk_executor(jobs, executor) as chunks:
        run_in_chunks(S, chunk_size, chunks, progress, values, success, messages, arrays,
                      lambda chunk: _solve_group_pde(model, *chunk, *settings), task)
    return values, success, messages, model, unique, inverse, method


def solve_reference_pde(
    problem,
    params: Mapping[str, np.ndarray],
    space_points: Mapping[str, np.ndarray] | None,
    times: np.ndarray | None,
    *,
    grid: bool = True,
    space_nodes: int | Mapping[str, int] = DEFAULT_SPACE_NODES,
    method: str = "BDF",
    rtol: float = PDE_RTOL,
    atol: float = PDE_ATOL,
    jobs: int = 1,
    chunk_size: int | None = None,
    progress: Callable[[int], None] | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    executor=None,
) -> PdeReferenceResult:
    """Method-of-lines reference of a problem with space coordinates.

    Every space coordinate is discretized by strong-form Chebyshev-Gauss-Lobatto collocation
    (``space_nodes`` points; tensor-product grid over several space coordinates, sparse
    Kronecker-product operators). At the ends of a coordinate where an unknown has boundary
    conditions, the collocated equation is replaced by the condition (value: ``u = g``; gradient:
    ``du/dx = g``, the derivative along the coordinate, at either end); the boundary values are
    eliminated (each is a linear combination of interior values plus a known part), which leaves
    an ODE system in the interior values. It is integrated by ``solve_ivp`` (BDF or Radau, with
    its exact sparse Jacobian) at each parameter sample (a few samples share one call as a
    block-diagonal system), and the nodal values are interpolated to the requested space points
    with the barycentric formula. At the start time the initial value is evaluated exactly at the
    requested points.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        A linear problem with at least one space coordinate.
    params : dict of str to array_like, shape (S,)
        A value per sample for every coordinate that is neither time nor space (``{}`` when there
        are none: one sample).
    space_points : dict of str to array_like or None
        Points per space coordinate. ``grid=True``: the tensor grid of these 1-D arrays;
        ``grid=False``: ``P`` scattered points, one array of length ``P`` per coordinate.
        None: the collocation nodes themselves (tensor grid).
    times : array_like, shape (T,), or None
        Times at or after the start of the time domain; any order, repeats allowed. None for a
        steady problem (no time coordinate), which is one sparse linear solve per sample.
    grid : bool
        See ``space_points``.
    space_nodes : int or dict of str to int
        Collocation points per space coordinate (default :data:`DEFAULT_SPACE_NODES`).
    method : {'BDF', 'Radau'}
    rtol, atol : float
        Tolerances of ``solve_ivp``.
    jobs : int
        Worker processes (1: in this process, or by the executor in effect).
    chunk_size : int, optional
        Samples per ``solve_ivp`` call (default: as many as fit in about
        1024 unknowns, at most 8, and a sixteenth of the samples).
    progress : callable, optional
        Called with the number of samples finished so far.
    max_evaluations : int
        Right-hand-side evaluations one integration may spend.
    executor : optional
        Where the chunks run (:func:`pgdcli.executors.as_executor`; instead of ``jobs``).

    Returns
    -------
    PdeReferenceResult
        ``values[u]`` has shape ``(S, T, X_1, ..., X_d)`` (grid) or ``(S, T, P)`` (scattered);
        without the ``T`` axis for a steady problem.

    Raises
    ------
    PgdError
        No space coordinate, a nonlinear equation, boundary conditions that do not determine the
        boundary values, invalid samples, points outside the domain, times before the start, an
        unknown method or invalid tolerances.
    """
    _check_settings(method, rtol, atol, jobs)
    space = [c.name for c in space_coordinates(problem)]
    if not space:
        raise SolverError(f"{problem.source}: the problem has no space coordinate; use solve_reference")
    names = [c.name for c in sampled_coordinates(problem)]
    arrays, S = checked_params(params, names, problem.time, space)
    nodes = _space_nodes(problem, space_nodes)
    t0 = start_time(problem)
    times = reference_times(problem, times)

    points = checked_space_points(problem, space_points, space, grid)

    states, success, messages, model, unique, inverse, method = _grid_states(
        problem, arrays, S, times, nodes=nodes, method=method, rtol=rtol, atol=atol, jobs=jobs,
        chunk_size=chunk_size, progress=progress, max_evaluations=max_evaluations, executor=executor)
    if points is None:
        result_points = {c: model.grid.points[c].copy() for c in space}
        out = {u: states[:, s][:, inverse].reshape((S, times.size) + model.grid.shape)
               for s, u in enumerate(problem.unknown_names)}
    else:
        result_points = points
        out = values_at_space_points(problem, model, states, success, arrays, points, grid, unique == t0)
        out = {u: v[:, inverse] for u, v in out.items()}
    if problem.time is None:
        out = {u: v[:, 0] for u, v in out.items()}
    return PdeReferenceResult(values=out, success=success, messages=messages, space=space,
                              space_points=result_points, nodes=nodes, grid=bool(grid or points is None),
                              method=method, rtol=float(rtol), atol=float(atol), times=times)


def _check_settings(method, rtol, atol, jobs) -> None:
    """The method-of-lines reference's method (stiff: BDF or Radau), tolerances and jobs."""
    if method not in PDE_METHODS:
        raise SolverError(f"method {method!r}: the method-of-lines reference is stiff; use one of "
                          f"{', '.join(PDE_METHODS)}")
    check_tolerances(rtol, atol)
    if isinstance(jobs, bool) or int(jobs) < 1:
        raise SolverError(f"jobs must be at least 1, got {jobs}")


def solve_reference_space(problem, params, times, *, method, rtol, atol, jobs, chunk_size, progress,
                          max_evaluations, space_nodes, executor=None) -> ReferenceResult:
    """:func:`solve_reference` for a problem with space coordinates: samples over all non-time
    coordinates; one method-of-lines solve per distinct point of the sampled (non-space) ones."""
    _check_settings(method, rtol, atol, jobs)
    names = [c.name for c in problem.parameter_coordinates]
    arrays, S = checked_params(params, names, problem.time, [])
    space = [c.name for c in space_coordinates(problem)]
    sampled = [c.name for c in sampled_coordinates(problem)]
    for c in space_coordinates(problem):
        arrays[c.name] = clipped_to_domain(c, arrays[c.name], "params")
    nodes = _space_nodes(problem, space_nodes)
    t0 = start_time(problem)
    times = reference_times(problem, times)
    if sampled:
        stacked = np.column_stack([arrays[n] for n in sampled])
        distinct, group = np.unique(stacked, axis=0, return_inverse=True)
        group = np.asarray(group).reshape(-1)
        unique_params = {n: distinct[:, j] for j, n in enumerate(sampled)}
    else:
        unique_params, group = {}, np.zeros(S, dtype=int)
    G = int(group.max()) + 1 if S else 0
    values = {u: np.full((S, times.size), np.nan) for u in problem.unknown_names}
    success = np.zeros(S, dtype=bool)
    messages = [""] * S
    if S:
        def report(done: int) -> None:  # progress in samples, as for ODEs
            progress(S if done >= G else int(S * done / G))

        states, ok, msgs, model, unique, inverse, method = _grid_states(
            problem, unique_params, G, times, nodes=nodes, method=method, rtol=rtol, atol=atol, jobs=jobs,
            chunk_size=chunk_size, progress=report if progress is not None else None,
            max_evaluations=max_evaluations, executor=executor)
        at_start = unique == t0
        shape = model.grid.shape
        for g in range(G):
            rows = np.flatnonzero(group == g)
            success[rows] = ok[g]
            for i in rows:
                messages[i] = msgs[g]
            if not ok[g]:
                continue
            mats = interpolation_matrices(model, {c: arrays[c][rows] for c in space})
            for s, u in enumerate(problem.unknown_names):
                v = at_points(states[g, s], shape, mats)  # (Tu, P)
                values[u][rows] = v[inverse].T
        if at_start.any():  # the initial value exactly at the points
            columns = times == t0
            for s, unknown in enumerate(problem.unknowns):
                exact = np.broadcast_to(unknown.initial.evaluate(**arrays), (S,)) if unknown.initial.terms \
                    else np.zeros(S)
                values[unknown.name][np.ix_(success, columns)] = exact[success, None]
    if problem.time is None:
        values = {u: v[:, 0] for u, v in values.items()}
    return ReferenceResult(values=values, success=success, messages=messages, method=method, rtol=float(rtol),
                           atol=float(atol), times=times)

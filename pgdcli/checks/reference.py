"""Independent reference solutions of a problem with scipy's ``solve_ivp``.

This module exists to check codebooks (``pgd verify``, plots): it must not
share a code path with the PGD solver beyond the parsed spec, so that a bug in
operator assembly cannot cancel out. It therefore never imports
``solver``, ``basis`` or ``separated``: the equations are evaluated pointwise
from the parsed :class:`~pgdcli.problem.expressions.Polynomial` of each equation. Non-separable
coefficients and sources (``sin(w*t)``, ``exp(-k*x*t)``) are evaluated from their expression
trees at the samples (and space grid) at every call, never from the solvers' numerical
separation, so the error gate and ``pgd verify`` check that separation too.

Equation ``r`` reads (lhs - rhs = 0)

    sum_s A_rs(t, p) u_s'  +  g_r(t, p, u)  =  0

where ``A_rs`` is the coefficient of ``der(u_s)`` and ``g_r`` is a polynomial
in the unknown values with separated coefficients (``u``, ``u*v``, ``u**2``
... are all supported; ``der(u)`` may only appear linearly). At every
right-hand-side call the small system ``A u' = -g`` is solved per sample
(a division when every equation holds one ``der`` of its own unknown).

Samples are integrated together: one ``solve_ivp`` call advances a chunk of
``S`` parameter points at once (state of size ``q*S``, sample-major), which is
orders of magnitude faster than a Python loop over samples. The step size of
such a call is set by the worst sample, and a failure at one sample (blow-up,
singular ``A``, too many steps) fails the whole call: the chunk is then split
in halves recursively until the failing samples are isolated, so a failure is
reported for exactly the samples that fail on their own.

Chunks can be spread over worker processes (``jobs``) or the workers of any executor
(:mod:`pgdcli.executors`, a Dask cluster); workers receive the spec text (picklable) and parse it
again. The chunks are the same whatever runs them, and so are the values.

Modules: :mod:`.reference_base` (settings, results, argument checks, worker processes),
:mod:`.reference_ode`, :mod:`.reference_pde` and :mod:`.collocation`; this module is the API.

Problems with space coordinates (:func:`solve_reference_pde`; :func:`solve_reference`
dispatches to it) are solved by the method of lines, independently of the PGD solver's
weak-form discretization: strong-form Chebyshev-Gauss-Lobatto collocation per space
coordinate (nodes, differentiation matrices and barycentric interpolation written here),
tensor-product grids with Kronecker-product operators, the collocated equation replaced by
the boundary condition at the boundary nodes (value ``u = g``, gradient ``du/dx = g``) and
the boundary values eliminated, which leaves an ODE system in the interior values for
``solve_ivp`` (BDF or Radau with the exact Jacobian). Equations must be linear there.
"""

from __future__ import annotations

from typing import Callable, Mapping

import numpy as np

from .collocation import barycentric_matrix, chebyshev_differentiation, chebyshev_points, chebyshev_weights
from .reference_base import (DEFAULT_MAX_EVALUATIONS, DEFAULT_SPACE_NODES, METHODS, PDE_ATOL, PDE_METHODS, PDE_RTOL,
                             ReferenceBudgetExceeded, ReferenceResult, space_coordinates)
from .reference_ode import solve_reference_ode, solve_reference_vectorized
from .reference_pde import PdeReferenceResult, solve_reference_pde, solve_reference_space

__all__ = [
    "METHODS",
    "solve_reference_vectorized",
    "PDE_METHODS",
    "ReferenceResult",
    "PdeReferenceResult",
    "solve_reference",
    "solve_reference_pde",
    "ReferenceBudgetExceeded",
    "DEFAULT_MAX_EVALUATIONS",
    "DEFAULT_SPACE_NODES",
    "chebyshev_points",
    "chebyshev_weights",
    "chebyshev_differentiation",
    "barycentric_matrix",
]


def solve_reference(
    problem,
    params: Mapping[str, np.ndarray],
    times: np.ndarray | None,
    *,
    method: str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    jobs: int = 1,
    chunk_size: int | None = None,
    progress: Callable[[int], None] | None = None,
    max_evaluations: int = DEFAULT_MAX_EVALUATIONS,
    space_nodes: int | Mapping[str, int] = DEFAULT_SPACE_NODES,
    executor=None,
) -> ReferenceResult:
    """Integrate the problem's ODEs at parameter samples with ``scipy.integrate.solve_ivp``.

    A problem with space coordinates is solved by the method of lines of
    :func:`solve_reference_pde` at every distinct point of the other
    coordinates, and each sample reads its own space point off that solution.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        Parsed spec (linear or, with ``allow_nonlinear=True``, polynomial in
        the unknowns; linear when it has space coordinates).
    params : dict of str to array_like, shape (S,)
        A value per sample for every non-time coordinate, space coordinates
        included (``{}`` for a problem without parameters: one sample).
    times : array_like, shape (T,), or None
        Times at which to report the solution, each at or after the start
        of the time domain (where the initial values hold); any order,
        repeats allowed. None for a steady problem (no time coordinate),
        whose values then have shape (S,).
    method : str, optional
        One of :data:`METHODS` (default DOP853); with space coordinates one
        of :data:`PDE_METHODS` (default BDF).
    rtol, atol : float, optional
        Tolerances of ``solve_ivp`` (default 1e-12 and 1e-12; with space
        coordinates :data:`PDE_RTOL` and :data:`PDE_ATOL`).
    jobs : int
        Worker processes (1: in this process, or by the executor in effect: see
        :mod:`pgdcli.executors`).
    chunk_size : int, optional
        Samples per vectorized ``solve_ivp`` call (default: a sixteenth of the
        samples, at least 64 and at most 1024, whatever runs them; a vectorized
        call costs little more than a single sample).
    progress : callable, optional
        Called with the number of samples finished so far, after each chunk.
    max_evaluations : int
        Right-hand-side evaluations one integration may spend.
    space_nodes : int or dict of str to int
        Collocation points per space coordinate (problems with space
        coordinates only).
    executor : optional
        Where the chunks run, instead of ``jobs``: a ``distributed.Client`` or a
        :class:`pgdcli.executors.Executor`. The values do not depend on it.

    Returns
    -------
    ReferenceResult

    Raises
    ------
    PgdError
        Missing or extra coordinates, mismatched shapes, times before the
        start, an unknown method or invalid tolerances.
    """
    if space_coordinates(problem):
        return solve_reference_space(problem, params, times, method=method or "BDF",
                                      rtol=PDE_RTOL if rtol is None else rtol,
                                      atol=PDE_ATOL if atol is None else atol, jobs=jobs, chunk_size=chunk_size,
                                      progress=progress, max_evaluations=max_evaluations, space_nodes=space_nodes,
                                      executor=executor)
    return solve_reference_ode(problem, params, times, method=method, rtol=rtol, atol=atol, jobs=jobs,
                                chunk_size=chunk_size, progress=progress, max_evaluations=max_evaluations,
                                executor=executor)

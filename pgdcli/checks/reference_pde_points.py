"""The method-of-lines reference's nodal states at the points asked: barycentric interpolation
on the collocation grid, the exact initial value at the start time, and the checks of those points.

Part of the independent reference (:mod:`.reference_pde`): shares no numerical code with the solver.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np

from ..errors import SolverError
from .collocation import PdeModel, barycentric_matrix
from .reference_base import space_coordinates

__all__ = ["interpolation_matrices", "on_grid", "at_points", "clipped_to_domain", "checked_space_points",
           "values_at_space_points", "initial_at_space_points"]


def interpolation_matrices(model: PdeModel, points: Mapping[str, np.ndarray]) -> list[np.ndarray]:
    """Per space coordinate (grid order), the barycentric rows of its points on the collocation nodes."""
    grid = model.grid
    return [barycentric_matrix(grid.points[c], grid.weights[c], points[c]) for c in grid.names]


def on_grid(full: np.ndarray, shape: tuple, mats: list[np.ndarray]) -> np.ndarray:
    """(..., n) nodal values -> (..., X_1, ..., X_d) on the tensor grid of the points."""
    lead = full.shape[:-1]
    V = full.reshape(lead + shape)
    for k, W in enumerate(mats):
        axis = len(lead) + k
        V = np.moveaxis(np.tensordot(V, W, axes=([axis], [1])), -1, axis)
    return V


def at_points(full: np.ndarray, shape: tuple, mats: list[np.ndarray]) -> np.ndarray:
    """(A, n) nodal values -> (A, P) at scattered points (row p of every matrix)."""
    A = full.shape[0]
    V = full.reshape((A,) + shape)
    V = np.tensordot(V, mats[0], axes=([1], [1]))  # (A, N_2, ..., N_d, P)
    V = np.moveaxis(V, -1, 1)  # (A, P, N_2, ..., N_d)
    for W in mats[1:]:
        V = np.einsum("ap...j,pj->ap...", V, W) if V.ndim > 3 else np.einsum("apj,pj->ap", V, W)
    return V


def clipped_to_domain(c, x: np.ndarray, label: str) -> np.ndarray:
    """``x`` (finite, within the domain of coordinate ``c`` up to rounding) clipped into it; else SolverError."""
    low, high = map(float, c.domain)
    slack = 1e-12 * max(1.0, abs(low), abs(high))
    inside = np.isfinite(x) & (x >= low - slack) & (x <= high + slack)
    if not inside.all():
        raise SolverError(f"{label}: {c.name} = {float(x[~inside][0])!r} is outside the domain [{low:g}, {high:g}]")
    return np.clip(x, low, high)


def checked_space_points(problem, space_points, space: list[str], grid: bool) -> dict | None:
    """:func:`solve_reference_pde`'s ``space_points``, checked and clipped to the domains (None: the nodes)."""
    if space_points is None:
        return None
    extra = [k for k in space_points if k not in space]
    if extra:
        raise SolverError(f"space_points: {extra[0]!r} is not a space coordinate ({', '.join(space)})")
    missing = [k for k in space if k not in space_points]
    if missing:
        raise SolverError(f"space_points: missing coordinate(s) {', '.join(missing)}")
    points = {k: np.atleast_1d(np.asarray(space_points[k], dtype=float)) for k in space}
    if any(p.ndim != 1 or p.size == 0 for p in points.values()):
        raise SolverError("space_points: expected non-empty 1-D arrays")
    if not grid and len({p.size for p in points.values()}) > 1:
        raise SolverError("space_points: scattered points (grid=False) need arrays of one length")
    for c in space_coordinates(problem):
        points[c.name] = clipped_to_domain(c, points[c.name], "space_points")
    return points


def values_at_space_points(problem, model, states, success, arrays, points, grid: bool, at_start) -> dict:
    """Nodal states (S, unknowns, Tu, n) interpolated to ``points``: per unknown (S, Tu, X_1, ..., X_d) on a
    grid or (S, Tu, P) scattered; at the start time (``at_start``, shape (Tu,)) the exact initial value."""
    shape = model.grid.shape
    S = states.shape[0]
    mats = interpolation_matrices(model, points)
    out = {}
    for s, u in enumerate(problem.unknown_names):
        full = states[:, s]  # (S, Tu, n)
        if grid:
            vals = on_grid(full, shape, mats)
        else:
            vals = at_points(full.reshape(-1, model.grid.n), shape, mats).reshape(S, at_start.size, -1)
        if at_start.any():  # the initial value exactly at the points
            exact = initial_at_space_points(problem.unknowns[s].initial, arrays, points, grid, S)
            vals[success, int(np.flatnonzero(at_start)[0])] = exact[success] if np.ndim(exact) else 0.0
        out[u] = vals
    return out


def initial_at_space_points(initial, arrays, points, grid: bool, S: int):
    """An initial value at the samples' parameters (``arrays``) and the space points: (S, X...) or (S, P); 0.0
    when it has no terms."""
    if not initial.terms:
        return 0.0
    space = list(points)
    if grid:
        mesh = np.meshgrid(*[points[c] for c in space], indexing="ij")
        at = {c: m[None] for c, m in zip(space, mesh)}
        at.update({p: a.reshape((S,) + (1,) * len(space)) for p, a in arrays.items()})
        return np.broadcast_to(initial.evaluate(**at), (S,) + mesh[0].shape)
    at = {c: points[c][None, :] for c in space}
    at.update({p: a[:, None] for p, a in arrays.items()})
    return np.broadcast_to(initial.evaluate(**at), (S, points[space[0]].size))

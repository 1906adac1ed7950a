"""A posteriori error check of a marched codebook against scipy at a stratified sample.

The time march controls an *RMS* over the parameter grid of the local errors it
makes. The worst point of the box (on the rigid body, a corner where the dynamics
are fastest) can be ten times that RMS, and the growth of errors through the
dynamics is in no local estimate. A user who writes ``tolerance: 1e-5`` reads it as
a bound on the error of the values ``pgd query`` returns, so after a march
:func:`pgdcli.solve` measures that error: it integrates the equations with scipy's
DOP853 (one vectorized ``solve_ivp`` call, :mod:`pgdcli.reference`) at a sample of the
parameter box stratified toward its faces and corners, and compares the codebook
there at every time node.

The sample has three parts, because they fail for different reasons:

* corners of the box (all of them up to :data:`CORNERS`, a seeded subset beyond):
  the extreme dynamics;
* grid nodes with every coordinate at an end node with probability 1/2 (edges and
  faces of the grid): the march's own error, which a tighter march reduces;
* points between the nodes (uniform in the box): the interpolation error along the
  parameter coordinates, which only more nodes reduce.

numpy and :mod:`pgdcli.reference` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["CheckResult", "check_codebook", "check_sample", "points_text"]

CORNERS = 64
FACE_NODES = 96
BETWEEN = 96


@dataclass
class CheckResult:
    """Measured error of a codebook at the check sample (max abs over unknowns and time nodes).

    Attributes
    ----------
    error : float
        Max abs error over every checked point and time node (NaN if no reference succeeded).
    node_error, between_error : float
        The same over the points at grid nodes (corners included) and between them.
    points : int
        Parameter points whose reference integration succeeded.
    failed : int
        Parameter points whose reference integration failed (left out).
    where : dict
        Coordinates (time included) of the largest error.
    per_unknown : dict
        Max abs error per unknown.
    """

    error: float
    node_error: float
    between_error: float
    points: int
    failed: int
    where: dict = field(default_factory=dict)
    per_unknown: dict = field(default_factory=dict)


def points_text(n: int) -> str:
    """``"1 check point"``, ``"183 check points"``."""
    return f"{n} check point" + ("s" if n != 1 else "")


def check_sample(problem, codebook, seed: int = 0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Check points of the parameter box and which of them are grid nodes.

    Returns
    -------
    points : dict of str to ndarray, shape (S,)
        A value per point for every parameter coordinate (``{}`` when there are none: one point).
    at_nodes : ndarray of bool, shape (S,)
    """
    names = [c.name for c in problem.parameter_coordinates]
    if not names:
        return {}, np.ones(1, dtype=bool)
    rng = np.random.default_rng([seed, 11])
    nodes = [codebook.coordinate(n).basis().nodes for n in names]
    m = len(names)
    if 2**m <= CORNERS:
        ends = (np.arange(2**m)[:, None] >> np.arange(m)[None, :]) & 1
    else:
        ends = np.unique(rng.integers(0, 2, size=(4 * CORNERS, m)), axis=0)
        ends = ends[rng.permutation(ends.shape[0])[:CORNERS]]
    corner_index = np.where(ends == 1, [len(x) - 1 for x in nodes], 0)
    face_index = np.column_stack([rng.integers(0, len(x), FACE_NODES) for x in nodes])
    on_end = rng.random((FACE_NODES, m)) < 0.5
    face_index = np.where(on_end, np.where(rng.random((FACE_NODES, m)) < 0.5, 0, [len(x) - 1 for x in nodes]),
                          face_index)
    index = np.unique(np.vstack([corner_index, face_index]), axis=0)
    at_grid = {n: x[index[:, j]] for j, (n, x) in enumerate(zip(names, nodes))}
    between = {n: rng.uniform(*problem.coordinate(n).domain, size=BETWEEN) for n in names}
    points = {n: np.concatenate([at_grid[n], between[n]]) for n in names}
    at_nodes = np.concatenate([np.ones(index.shape[0], dtype=bool), np.zeros(BETWEEN, dtype=bool)])
    return points, at_nodes


def _reference(problem, points, S: int, times: np.ndarray, rtol: float, atol: float):
    """Reference values ``{unknown: (S, T)}`` and a success mask ``(S,)``.

    One vectorized DOP853 call with output at the time nodes (its dense output at
    rtol 1e-13 agrees with node-to-node integration at 1e-12 to ~3e-12, and costs a
    tenth); if that call fails (a sample blows up), the node-to-node integration of
    :func:`pgdcli.reference.solve_reference`, which isolates the failing samples.
    """
    from scipy.integrate import solve_ivp

    from .reference import ReferenceBudgetExceeded, _System, solve_reference

    names = [u.name for u in problem.unknowns]
    try:
        with np.errstate(all="ignore"):
            system = _System(problem, points, S, max_evaluations=200_000)
            y0 = system.initial(problem, points)
            if not system.bad.any() and np.isfinite(y0).all():
                sol = solve_ivp(system, (float(times[0]), float(times[-1])), y0.reshape(-1), method="DOP853",
                                rtol=rtol, atol=atol, t_eval=times)
                if sol.status == 0 and sol.y.shape[1] == times.size and np.isfinite(sol.y).all():
                    values = sol.y.reshape(S, len(names), times.size)
                    return {u: values[:, i, :] for i, u in enumerate(names)}, np.ones(S, dtype=bool)
    except (ReferenceBudgetExceeded, np.linalg.LinAlgError, ZeroDivisionError, FloatingPointError, OverflowError):
        pass  # the node-to-node integration below isolates the samples that fail
    ref = solve_reference(problem, points, times, method="DOP853", rtol=max(rtol, 1e-12), atol=max(atol, 1e-12))
    return ref.values, np.asarray(ref.success, dtype=bool)


def _on_sample(codebook, points, time: str, times: np.ndarray, unknowns) -> dict[str, np.ndarray]:
    """Codebook values ``{unknown: (S, T)}`` at every point of the sample and every time.

    A tensor train is contracted with the time rows once (not once per point).
    """
    from .codebook import FieldTT

    names = codebook.coordinate_names
    S = len(next(iter(points.values()))) if points else 1
    mats = [c.basis().interpolation_matrix(times if c.name == time else points[c.name])
            for c in codebook.coordinates]
    out = {}
    for u in unknowns:
        fm = codebook.fields[u]
        if not isinstance(fm, FieldTT):
            from .verification import _evaluate_codebook

            out[u] = _evaluate_codebook(codebook, points, time, times, [u])[u]
            continue
        v = np.ones((S, 1, 1))
        for core, j in zip(fm.cores, fm.mode_order):
            c = np.einsum("pn,anb->pab", mats[j], core)
            v = np.einsum("sxa,tab->stb", v, c) if names[j] == time else np.einsum("sta,sab->stb", v, c)
        out[u] = np.broadcast_to(v[:, :, 0], (S, times.size))
    return out


def check_codebook(problem, codebook, *, seed: int = 0, rtol: float = 1e-13, atol: float = 1e-13) -> CheckResult:
    """Max abs error of a (marched) codebook against scipy's DOP853 at :func:`check_sample`.

    Parameters
    ----------
    problem : pgdcli.spec.Problem
        With a time coordinate and no space coordinates.
    codebook : pgdcli.Codebook
    seed : int
    rtol, atol : float
        Tolerances of the reference integration.

    Returns
    -------
    CheckResult
    """
    points, at_nodes = check_sample(problem, codebook, seed)
    time = problem.time
    times = np.asarray(codebook.coordinate(time).basis().nodes, dtype=float)
    reference, ok = _reference(problem, points, at_nodes.size, times, rtol, atol)
    unknowns = [u.name for u in problem.unknowns]
    approx = _on_sample(codebook, points, time, times, unknowns)
    err = np.zeros((ok.size, times.size))
    per_unknown = {}
    for u in unknowns:
        e = np.abs(approx[u] - reference[u])
        e[~ok] = 0.0
        per_unknown[u] = float(e.max()) if ok.any() else float("nan")
        err = np.maximum(err, e)
    if not ok.any():
        return CheckResult(float("nan"), float("nan"), float("nan"), 0, int(ok.size), {}, per_unknown)
    i, j = np.unravel_index(int(np.argmax(err)), err.shape)
    where = {time: float(times[j])} | {n: float(v[i]) for n, v in points.items()}
    node = err[at_nodes].max() if at_nodes.any() else 0.0
    between = err[~at_nodes].max() if (~at_nodes).any() else 0.0
    return CheckResult(float(err.max()), float(node), float(between), int(ok.sum()), int((~ok).sum()), where,
                       per_unknown)

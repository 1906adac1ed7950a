"""Data of the ``modes`` and ``convergence`` pictures (CP modes, tensor-train HOSVD modes, march history)."""

from __future__ import annotations

import math

import numpy as np

from ..errors import PgdError, QueryError
from ..tensors.tt import TT, tt_centre_cores
from .options import DEFAULT_COUNT, LINE_POINTS, count_points, field_name, time_coordinate_of

__all__ = ["modes_data", "tt_hosvd_modes", "convergence_data"]


# ----------------------------------------------------------------------------------------------
# data
# ----------------------------------------------------------------------------------------------
def modes_data(codebook, count: int = DEFAULT_COUNT, field: str | None = None, *, points: int | None = None) -> dict:
    """The first ``count`` modes of ``field`` per coordinate, on a fine grid.

    A CP unknown (:class:`~pgdcli.tensors.cp.CPTensor`) shows its stored modes.
    A tensor-train unknown (:class:`~pgdcli.tensors.tt.TT`, the time march's
    codebooks) has no per-coordinate modes of its own; it shows its HOSVD modes:
    for coordinate ``j``, the leading left singular vectors of the tensor's
    mode-``j`` unfolding (nodes of ``j`` x nodes of all other coordinates),
    **normalized** to unit Euclidean norm over the nodes, with their singular
    values. They are computed from the cores without forming the tensor (see
    :func:`tt_hosvd_modes`), and each vector's entry of largest magnitude is
    positive (the SVD leaves the sign free).

    Each coordinate's grid is ``points`` (default 201) equispaced samples of its
    domain merged with the basis nodes, and the modes are evaluated there with the
    codebook's own interpolant (``CoordinateInfo.basis().interpolation_matrix``), so
    the curves pass through the nodal values.

    Returns
    -------
    dict
        ``kind``, ``problem``, ``field``, ``representation`` ('cp' or
        'tensor-train'), ``count`` (shown; for a tensor train the largest over
        the panels), ``rank`` (CP: stored modes; tensor train: largest bond rank)
        and ``panels``: one dict per coordinate (codebook order) with
        ``coordinate``, ``role``, ``domain``, ``x`` (P,), ``values`` (P, count),
        ``nodes`` (n,) and ``node_values`` (n, count).
        CP: ``alphas`` (count,).
        Tensor train: ``alphas`` None, ``ranks`` (bond ranks), and per panel
        ``count``, ``rank`` (numerical rank of the unfolding: singular values
        above ``max(unfolding shape) * eps * sigma_1``, numpy's ``matrix_rank``) and
        ``singular_values`` (all min(n, r_{k-1} r_k) of them, decreasing).
    """
    name = field_name(codebook, field)
    if int(count) != count or count < 1:
        raise QueryError(f"--count: expected an integer >= 1, got {count}")
    npts = count_points(points, LINE_POINTS)
    fm = codebook.fields[name]
    tt = isinstance(fm, TT)
    if tt:
        hosvd = tt_hosvd_modes(fm)
        per_coordinate = [hosvd[j] for j in range(len(codebook.coordinates))]
    else:
        n = min(int(count), fm.rank)
        per_coordinate = [(m[:, :n], None) for m in fm.factors]
    panels = []
    grid = [c.nodes for c in codebook.coordinates]
    for j, (c, (m, sigma)) in enumerate(zip(codebook.coordinates, per_coordinate)):
        basis = c.basis()
        x = np.union1d(np.linspace(c.domain[0], c.domain[1], npts), basis.nodes)
        panel = {"coordinate": c.name, "role": c.role, "domain": tuple(c.domain), "x": x,
                 "nodes": np.array(basis.nodes)}
        if tt:
            rank = _numerical_rank(sigma, (c.nodes, math.prod(grid) // c.nodes))
            shown = min(int(count), rank)
            m = m[:, :shown]
            panel.update(count=shown, rank=rank, singular_values=sigma)
        panel["values"] = basis.interpolate(m, x)
        panel["node_values"] = np.array(m)
        panels.append(panel)
    out = {"kind": "modes", "problem": codebook.name, "field": name, "panels": panels}
    if tt:
        out.update(representation="tensor-train", count=max(p["count"] for p in panels), rank=fm.rank,
                   ranks=fm.ranks, alphas=None)
    else:
        out.update(representation="cp", count=n, rank=fm.rank, alphas=np.array(fm.weights[:n]))
    return out


def _numerical_rank(sigma: np.ndarray, shape: tuple[int, int]) -> int:
    """Singular values above ``max(shape) * eps * sigma_1``: numpy's ``matrix_rank`` of a matrix of
    ``shape`` (here the unfolding: nodes of one coordinate x nodes of all the others)."""
    if sigma.size == 0 or not sigma[0] > 0:
        return 0
    return int(np.count_nonzero(sigma > max(shape) * np.finfo(float).eps * sigma[0]))


def tt_hosvd_modes(fm) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """HOSVD modes of a tensor train, without forming the tensor.

    For each core ``k`` (coordinate ``j = fm.mode_order[k]``) the train is
    orthogonalized around it (:func:`pgdcli.tensors.tt.tt_centre_cores`), so that the
    mode-``j`` unfolding of the tensor equals ``C_k`` (core ``k`` reshaped to
    ``(nodes_j, r_{k-1} r_k)``) times a matrix with orthonormal rows. The SVD of ``C_k`` then gives the
    unfolding's left singular vectors and singular values.

    Returns
    -------
    dict
        Coordinate index ``j`` -> ``(U, s)``: ``U`` (nodes_j, m) orthonormal
        columns, each with its entry of largest magnitude positive, and ``s``
        (m,) the singular values in decreasing order, ``m = min(nodes_j,
        r_{k-1} r_k)``.
    """
    out = {}
    for k, centre in enumerate(tt_centre_cores(fm.cores)):
        r0, n, r1 = centre.shape
        u, s, _ = np.linalg.svd(np.transpose(centre, (1, 0, 2)).reshape(n, r0 * r1), full_matrices=False)
        if u.size:
            big = np.argmax(np.abs(u), axis=0)
            u = u * np.where(u[big, np.arange(u.shape[1])] < 0, -1.0, 1.0)
        out[fm.mode_order[k]] = (u, s)
    return out


def convergence_data(codebook) -> dict:
    """How the solver converged, from the stored solver report.

    PGD (enrichment) codebooks: relative residual against the number of modes.
    Time-march codebooks (report ``method`` 'march'): the accepted step sizes
    against time and the tensor-train ranks of the state at the time nodes.

    Returns
    -------
    dict
        Enrichment (``method`` 'pgd'): ``modes`` (int array 0..n), ``residual``
        (the report's ``residual_history``), ``tolerance``, ``converged``,
        ``iterations`` (fixed-point iterations per mode or None) and ``outer``:
        None, or ``{"iteration", "change"}`` from the report's ``outer_history``
        (nonlinear solvers: the outer iteration's change per iteration).
        March (``method`` 'march'): ``step_sizes`` (N,) the report's accepted
        step sizes; ``step_end`` (N,) the times they reach (start of the time
        domain + their cumulative sum) and ``step_start`` (N,) where they begin;
        ``time`` (name), ``node_times`` (T,) the time nodes; ``unknowns``;
        ``ranks`` (T, unknowns) the largest bond rank of each unknown's state at
        each time node (the report's ``node_ranks`` (T, unknowns, bonds) maxed
        over the bonds; 1 when there are no bonds); ``node_ranks`` as stored;
        ``steps``, ``rejected``, ``error_estimate``, ``check_error``, ``tolerance``, ``converged``.
    """
    rep = codebook.report
    if rep.get("method") == "march" or "step_sizes" in rep:
        return _march_convergence_data(codebook)
    history = rep.get("residual_history")
    if history is None or np.size(history) == 0:
        raise PgdError(f"codebook {codebook.name!r} has no residual history in its solver report")
    residual = np.asarray(history, dtype=float).reshape(-1)
    iterations = rep.get("iterations")
    outer = None
    raw = rep.get("outer_history")
    if raw is not None and np.size(raw) > 0:
        change = np.asarray(raw, dtype=float).reshape(-1)
        outer = {"iteration": np.arange(1, change.size + 1), "change": change}
    return {
        "kind": "convergence",
        "method": "pgd",
        "problem": codebook.name,
        "modes": np.arange(residual.size),
        "residual": residual,
        "tolerance": float(rep.get("tolerance", np.nan)),
        "converged": bool(rep.get("converged", False)),
        "iterations": None if iterations is None else np.asarray(iterations).reshape(-1),
        "outer": outer,
    }


def _march_convergence_data(codebook) -> dict:
    rep = codebook.report
    sizes, node_ranks = rep.get("step_sizes"), rep.get("node_ranks")
    if sizes is None or node_ranks is None or np.size(sizes) == 0:
        note = f" ({rep['message']})" if rep.get("message") else ""
        raise PgdError(f"codebook {codebook.name!r} has no time-march history (step sizes and ranks) in its "
                       f"solver report{note}")
    tc = time_coordinate_of(codebook, "a time-march convergence plot")
    node_times = np.array(tc.basis().nodes)
    sizes = np.asarray(sizes, dtype=float).reshape(-1)
    node_ranks = np.asarray(node_ranks)
    unknowns = codebook.unknown_names
    if node_ranks.ndim != 3 or node_ranks.shape[:2] != (node_times.size, len(unknowns)):
        raise PgdError(f"codebook {codebook.name!r}: node_ranks has shape {node_ranks.shape}, expected "
                       f"({node_times.size} time nodes, {len(unknowns)} unknowns, bonds)")
    ranks = node_ranks.max(axis=2) if node_ranks.shape[2] else np.ones(node_ranks.shape[:2], dtype=int)
    end = node_times[0] + np.cumsum(sizes)
    return {
        "kind": "convergence",
        "method": "march",
        "problem": codebook.name,
        "time": tc.name,
        "step_sizes": sizes,
        "step_start": np.concatenate([node_times[:1], end[:-1]]),
        "step_end": end,
        "node_times": node_times,
        "unknowns": list(unknowns),
        "ranks": ranks,
        "node_ranks": node_ranks,
        "steps": int(rep.get("steps", sizes.size)),
        "rejected": int(rep.get("rejected_steps", 0)),
        "error_estimate": float(rep.get("error_estimate", np.nan)),
        "check_error": float(rep.get("check_error", np.nan)),  # NaN: a codebook from before the check
        "tolerance": float(rep.get("tolerance", np.nan)),
        "converged": bool(rep.get("converged", False)),
    }

"""Pictures of a codebook: modes, convergence, solution and error (``pgd plot``).

Two layers, so that tests check numbers rather than pixels:

- ``*_data`` functions compute what is drawn, as plain dicts of numpy arrays:
  :func:`modes_data`, :func:`convergence_data`, :func:`solution_data`,
  :func:`error_data`. Every array handed to matplotlib comes from them.
- ``draw_*`` functions turn such a dict into a :class:`matplotlib.figure.Figure`;
  ``plot_*`` do both (``plot_modes(codebook, ...) -> Figure``), and
  :func:`render` does what ``pgd plot`` does: load, compute, draw, save.

Figures are built as bare :class:`~matplotlib.figure.Figure` objects, never
through ``matplotlib.pyplot``: no display, no GUI backend and no global state
are involved (saving goes through matplotlib's Agg / SVG canvases), and
importing this module does not change the backend of an interactive session.

Conventions
-----------
- Curves ("lines" layout) run along the time coordinate, one per parameter
  point; a point that leaves a non-time coordinate unset takes the midpoint of
  its domain.
- Maps ("map" layout) are drawn over two coordinates ``(x, y)``; every other
  coordinate is fixed, by default at the midpoint of its domain.
- Tensor-train codebooks (the nonlinear time march) have no stored modes:
  ``modes`` shows their HOSVD modes (:func:`tt_hosvd_modes`, normalized, with
  the singular values), and ``convergence`` the march's accepted step sizes
  and the state's tensor-train ranks at the time nodes.
- The independent reference is :func:`pgdcli.checks.reference.solve_reference`
  (scipy ``solve_ivp``) on the spec embedded in the codebook; any callable
  ``reference(params, times) -> result`` with ``result.values[unknown]`` of
  shape ``(S, T)``, ``result.success`` (S,) and ``result.messages`` can be
  passed instead.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np

from ..errors import PgdError, QueryError

__all__ = [
    "KINDS",
    "FORMATS",
    "DEFAULT_DPI",
    "modes_data",
    "tt_hosvd_modes",
    "convergence_data",
    "solution_data",
    "error_data",
    "draw_modes",
    "draw_convergence",
    "draw_solution",
    "draw_error",
    "plot_modes",
    "plot_convergence",
    "plot_solution",
    "plot_error",
    "reference_solver",
    "parse_point",
    "parse_over",
    "parse_size",
    "default_output",
    "save_figure",
    "render",
]

KINDS = ("modes", "convergence", "solution", "error")
FORMATS = ("png", "svg")
DEFAULT_DPI = 150
DEFAULT_COUNT = 6
LINE_POINTS = 201          # samples along a curve
MAP_POINTS = 81            # samples per axis of a map
REFERENCE_MARKERS = 21     # reference markers per curve (solution --reference)
DEFAULT_AT_CURVES = 5      # curves along the first parameter when no --at is given

# Okabe-Ito colors (color-blind safe), each paired with its own line style and marker so
# that curves stay distinguishable in grayscale.
_COLORS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9", "#000000")
_LINESTYLES = ("-", "--", "-.", ":", (0, (6, 2, 1, 2, 1, 2)), (0, (10, 3)), (0, (1, 3)))
_MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
_MAP_CMAP = "viridis"
_ERROR_CMAP = "cividis"


def _style(i: int) -> dict:
    return {"color": _COLORS[i % len(_COLORS)], "linestyle": _LINESTYLES[i % len(_LINESTYLES)],
            "marker": _MARKERS[i % len(_MARKERS)]}


# ----------------------------------------------------------------------------------------------
# argument parsing shared by the CLI and the Python API (errors name the option)
# ----------------------------------------------------------------------------------------------
def _describe(c) -> str:
    return f"{c.name} in [{c.domain[0]:g}, {c.domain[1]:g}]"


def _coordinate(codebook, name: str, option: str):
    for c in codebook.coordinates:
        if c.name == name:
            return c
    raise QueryError(f"{option}: unknown coordinate {name!r}; this codebook has "
                     f"{', '.join(_describe(c) for c in codebook.coordinates)}")


def _check_value(c, value: float, option: str) -> float:
    low, high = c.domain
    if not (math.isfinite(value) and low <= value <= high):
        raise QueryError(f"{option} {c.name}={value:g}: outside the domain [{low:g}, {high:g}] of {c.name!r}")
    return float(value)


def parse_point(text: str | Mapping[str, float], codebook, option: str = "--at") -> dict[str, float]:
    """``'k=3.2,c=0.1'`` (or a mapping) -> ``{'k': 3.2, 'c': 0.1}``, checked against the codebook.

    Raises
    ------
    QueryError
        Malformed text, a missing value, an unknown coordinate, a coordinate
        given twice or a value outside its domain; the message names ``option``.
    """
    if isinstance(text, Mapping):
        items = [(str(k), v) for k, v in text.items()]
    else:
        items = []
        for part in str(text).split(","):
            name, eq, value = part.partition("=")
            name, value = name.strip(), value.strip()
            if not eq or not name:
                raise QueryError(f"{option}: expected NAME=VALUE[,NAME=VALUE...], got {str(text)!r}")
            if not value:
                raise QueryError(f"{option}: missing value for coordinate {name!r} (expected {name}=NUMBER)")
            items.append((name, value))
    out: dict[str, float] = {}
    for name, value in items:
        c = _coordinate(codebook, name, option)
        if name in out:
            raise QueryError(f"{option}: coordinate {name!r} given twice")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise QueryError(f"{option} {name}={value}: not a number") from None
        out[name] = _check_value(c, number, option)
    return out


def parse_over(text: str | Sequence[str], codebook) -> tuple[str, str]:
    """``'k,t'`` -> ``('k', 't')``: the x and y axes of a map (two different coordinates)."""
    names = [n.strip() for n in text.split(",")] if isinstance(text, str) else [str(n) for n in text]
    if len(names) != 2 or not all(names) or names[0] == names[1]:
        names_ = codebook.coordinate_names
        example = f" (e.g. {names_[1]},{names_[0]})" if len(names_) >= 2 else ""
        raise QueryError(f"--over: expected two different coordinate names X,Y{example}, got {text!r}")
    for n in names:
        _coordinate(codebook, n, "--over")
    return names[0], names[1]


def parse_size(text: str) -> tuple[float, float]:
    """``'8x5'`` (inches) -> ``(8.0, 5.0)``."""
    parts = str(text).lower().replace(",", "x").split("x")
    try:
        w, h = (float(p) for p in parts)
    except ValueError:
        raise QueryError(f"--size: expected WIDTHxHEIGHT in inches (e.g. 8x5), got {text!r}") from None
    if not (0.5 <= w <= 100 and 0.5 <= h <= 100):
        raise QueryError(f"--size: width and height must be between 0.5 and 100 inches, got {text!r}")
    return w, h


def _field(codebook, field: str | None) -> str:
    if field is None:
        return codebook.unknown_names[0]
    if field not in codebook.fields:
        raise QueryError(f"--field: unknown {field!r}; this codebook has {', '.join(codebook.unknown_names)}")
    return field


def _time(codebook, what: str):
    for c in codebook.coordinates:
        if c.role == "time":
            return c
    raise QueryError(f"{what} needs a time coordinate; this codebook has none "
                     f"({', '.join(codebook.coordinate_names)})")


def _line_axis(codebook, what: str):
    """The coordinate curves run along: time, or for a steady codebook its first space coordinate."""
    for c in codebook.coordinates:
        if c.role == "time":
            return c
    for c in codebook.coordinates:
        if c.role == "space":
            return c
    return _time(codebook, what)


def _steady(codebook) -> bool:
    return not any(c.role == "time" for c in codebook.coordinates)


def _midpoint(c) -> float:
    return 0.5 * (c.domain[0] + c.domain[1])


def _count_points(points: int | None, default: int, high: int = 100_000, option: str = "--points") -> int:
    if points is None:
        return default
    if int(points) != points or not 2 <= points <= high:
        raise QueryError(f"{option}: expected an integer from 2 to {high}, got {points}")
    return int(points)


def _label(point: Mapping[str, float]) -> str:
    return ", ".join(f"{k}={v:g}" for k, v in point.items()) or "(no parameters)"


# ----------------------------------------------------------------------------------------------
# the independent reference
# ----------------------------------------------------------------------------------------------
def reference_solver(codebook, *, source: str = "<codebook>", method: str | None = None,
                     rtol: float | None = None, atol: float | None = None) -> Callable:
    """The independent reference for ``codebook``: ``solve(params, times) -> ReferenceResult``.

    Re-parses the spec embedded in the codebook and integrates it with
    :func:`pgdcli.checks.reference.solve_reference` (scipy ``solve_ivp``; ``None`` settings: its
    defaults, DOP853 at 1e-12 for ODEs, the method of lines with BDF for space coordinates).
    """
    from ..problem.spec import parse_spec

    if not codebook.spec_text.strip():
        raise PgdError(f"{source}: the codebook has no embedded spec; a reference solution needs one")
    try:
        from ..checks.reference import solve_reference
    except ImportError as exc:  # pragma: no cover - only while pgdcli.checks.reference is missing
        raise PgdError(f"the reference solver is not available ({exc})") from None
    problem = parse_spec(codebook.spec_text, source=source, allow_nonlinear=True)

    def solve(params: Mapping[str, np.ndarray], times: np.ndarray | None):
        return solve_reference(problem, dict(params), None if times is None else np.asarray(times, dtype=float),
                               method=method, rtol=rtol, atol=atol)

    if problem.time is None:
        solve.description = "Chebyshev collocation, sparse direct solve"
    else:
        solve.description = ("solve_ivp " + (method or "(default method)")
                             + (f", rtol={rtol:g}, atol={atol:g}" if rtol is not None and atol is not None else ""))
    return solve


def _reference_values(reference: Callable, field: str, params: Mapping[str, np.ndarray],
                      times: np.ndarray | None, axis: str | None = None) -> tuple[np.ndarray, list[str]]:
    """Reference values (S, T) of ``field``; rows whose solve failed are NaN, with a message each.

    ``times`` are the values along the curves. With ``axis`` (a steady problem: no times) they
    are the values of that coordinate, and the S x T points are solved as points of a
    reference without times; ``times=None`` solves the S points themselves (T = 1).
    """
    params = {k: np.asarray(v, dtype=float).reshape(-1) for k, v in params.items()}
    size = len(next(iter(params.values()))) if params else 1
    if axis is not None:
        count = len(times)
        points = {k: np.repeat(v, count) for k, v in params.items()}
        points[axis] = np.tile(np.asarray(times, dtype=float), size)
        result = reference(points, None)
    else:
        count = 1 if times is None else len(times)
        result = reference(params, times)
    values = np.array(result.values[field], dtype=float, copy=True).reshape(size, count)
    total = size * count if axis is not None else size
    success = np.asarray(getattr(result, "success", np.ones(total, bool)), dtype=bool).reshape(size, -1).all(axis=1)
    messages = list(getattr(result, "messages", None) or [""] * total)
    failures = []
    for s in np.flatnonzero(~success):
        values[s] = np.nan
        where = _label({k: float(v[s]) for k, v in params.items()})
        bad = [m for m in messages[s * (total // size):(s + 1) * (total // size)] if m] or [""]
        failures.append(f"reference failed at {where}: {' '.join(str(bad[0]).split()) or 'unknown reason'}")
    return values, failures


def _reference_description(reference) -> str:
    return getattr(reference, "description", "independent reference")


# ----------------------------------------------------------------------------------------------
# data
# ----------------------------------------------------------------------------------------------
def modes_data(codebook, count: int = DEFAULT_COUNT, field: str | None = None, *, points: int | None = None) -> dict:
    """The first ``count`` modes of ``field`` per coordinate, on a fine grid.

    A CP unknown (:class:`~pgdcli.codebook.codebook.FieldModes`) shows its stored modes.
    A tensor-train unknown (:class:`~pgdcli.codebook.codebook.FieldTT`, the time march's
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
    from ..codebook.codebook import FieldTT

    name = _field(codebook, field)
    if int(count) != count or count < 1:
        raise QueryError(f"--count: expected an integer >= 1, got {count}")
    npts = _count_points(points, LINE_POINTS)
    fm = codebook.fields[name]
    tt = isinstance(fm, FieldTT)
    if tt:
        hosvd = tt_hosvd_modes(fm)
        per_coordinate = [hosvd[j] for j in range(len(codebook.coordinates))]
    else:
        n = min(int(count), fm.rank)
        per_coordinate = [(m[:, :n], None) for m in fm.modes]
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
        panel["values"] = basis.interpolation_matrix(x) @ m
        panel["node_values"] = np.array(m)
        panels.append(panel)
    out = {"kind": "modes", "problem": codebook.name, "field": name, "panels": panels}
    if tt:
        out.update(representation="tensor-train", count=max(p["count"] for p in panels), rank=fm.rank,
                   ranks=fm.ranks, alphas=None)
    else:
        out.update(representation="cp", count=n, rank=fm.rank, alphas=np.array(fm.alphas[:n]))
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
    from ..tensors.tt import tt_centre_cores

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
    tc = _time(codebook, "a time-march convergence plot")
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


def _line_points(codebook, at, what: str) -> tuple[object, list[dict[str, float]]]:
    """Complete ``--at`` points: every coordinate but the curves' axis set (default: domain midpoint)."""
    tc = _line_axis(codebook, what)
    others = [c for c in codebook.coordinates if c is not tc]
    if isinstance(at, (str, Mapping)):
        at = [at]
    if at is None or len(at) == 0:
        if others:  # a few values of the first parameter, the others at their midpoints
            first = others[0]
            given = [{first.name: float(v)} for v in np.linspace(first.domain[0], first.domain[1],
                                                                  DEFAULT_AT_CURVES)]
        else:
            given = [{}]
    else:
        given = [parse_point(p, codebook, "--at") for p in at]
    points = []
    for g in given:
        if tc.name in g:
            rest = ", ".join(c.name for c in others) or "nothing"
            raise QueryError(f"--at: {tc.name!r} is the time axis of the curves; give only {rest}")
        points.append({c.name: g.get(c.name, _midpoint(c)) for c in others})
    return tc, points


def _map_axes(codebook, over, fix, npts: int):
    if over is None:
        tc = _line_axis(codebook, "a map without --over")
        others = [c for c in codebook.coordinates if c is not tc]
        if not others:
            raise QueryError("--over: this codebook has a single coordinate; there is no map to draw")
        xn, yn = tc.name, others[0].name
    else:
        xn, yn = parse_over(over, codebook)
    fixed_given: dict[str, float] = {}
    for f in ([] if fix is None else ([fix] if isinstance(fix, (str, Mapping)) else list(fix))):
        for k, v in parse_point(f, codebook, "--fix").items():
            if k in (xn, yn):
                raise QueryError(f"--fix: {k!r} is an axis of the map (--over {xn},{yn}); fix only the others")
            if k in fixed_given:
                raise QueryError(f"--fix: coordinate {k!r} given twice")
            fixed_given[k] = v
    fixed = {c.name: fixed_given.get(c.name, _midpoint(c)) for c in codebook.coordinates if c.name not in (xn, yn)}
    cx, cy = codebook.coordinate(xn), codebook.coordinate(yn)
    xv = np.linspace(cx.domain[0], cx.domain[1], npts)
    yv = np.linspace(cy.domain[0], cy.domain[1], npts)
    return xn, yn, xv, yv, fixed


def _map_coordinates(xn, yn, xv, yv, fixed) -> dict[str, np.ndarray]:
    gx, gy = np.meshgrid(xv, yv, indexing="xy")  # (ny, nx): rows follow y, as matplotlib draws
    coords = {xn: gx, yn: gy}
    coords.update({k: np.full(gx.shape, v) for k, v in fixed.items()})
    return coords


def _map_reference(codebook, reference, field, xn, yn, xv, yv, fixed) -> tuple[np.ndarray, list[str]]:
    """The reference on the map grid, shape (len(yv), len(xv))."""
    coords = _map_coordinates(xn, yn, xv, yv, fixed)
    if _steady(codebook):  # no times: every map point is a point of the reference
        values, failures = _reference_values(reference, field, {k: v.reshape(-1) for k, v in coords.items()}, None)
        return values.reshape(yv.size, xv.size), failures
    tc = _time(codebook, "a reference solution")
    if tc.name in (xn, yn):  # one solve per point of the other axis, all times at once
        pn, pv, time_is_x = (yn, yv, True) if tc.name == xn else (xn, xv, False)
        times = xv if time_is_x else yv
        params = {pn: pv}
        params.update({k: np.full(pv.size, v) for k, v in fixed.items() if k != tc.name})
        values, failures = _reference_values(reference, field, params, times)  # (n_p, n_t)
        return (values if time_is_x else values.T), failures
    t = fixed[tc.name]
    params = {k: v.reshape(-1) for k, v in coords.items() if k != tc.name}
    values, failures = _reference_values(reference, field, params, np.array([t]))
    return values.reshape(yv.size, xv.size), failures


def solution_data(codebook, field: str | None = None, *, at=None, over=None, fix=None,
                  points: int | None = None, reference=False) -> dict:
    """The unknown ``field`` along time at parameter points (``at``) or over two coordinates (``over``).

    Parameters
    ----------
    at : sequence of str or mapping, optional
        Points such as ``'k=3.2,c=0.1'``; unspecified non-time coordinates take
        their domain midpoints. Default: 5 values spanning the first parameter.
    over : str or (str, str), optional
        ``'k,t'``: a map with ``k`` along x and ``t`` along y.
    fix : str or sequence, optional
        ``'c=0.3'`` for the coordinates that are not axes of the map (default midpoints).
    points : int, optional
        Samples along each curve (201) or per map axis (81).
    reference : bool or callable
        True: add the independent reference (markers at 21 times per curve, or
        the map on the same grid); a callable is used as the reference solver.

    Returns
    -------
    dict
        ``layout`` 'lines': ``time``, ``t`` (T,), ``points`` (list of dicts),
        ``labels``, ``values`` (P, T) = codebook values; ``reference`` None or
        ``{"t", "values" (P, Tr), "description"}``.
        ``layout`` 'map': ``x``, ``y`` (names), ``xv`` (nx,), ``yv`` (ny,),
        ``fixed``, ``values`` (ny, nx); ``reference`` None or ``{"values", "description"}``.
        Both: ``kind``, ``problem``, ``field``, ``failures`` (reference failures).
    """
    name = _field(codebook, field)
    if at and over is not None:
        raise QueryError("--at and --over: give curves (--at) or a map (--over), not both")
    ref = None
    if reference is True:
        ref = reference_solver(codebook)
    elif callable(reference):
        ref = reference
    out = {"kind": "solution", "problem": codebook.name, "field": name, "failures": [], "reference": None}
    if over is None and fix:
        raise QueryError("--fix applies to maps (--over X,Y); curves take their parameters from --at")
    if over is None:
        tc, pts = _line_points(codebook, at, "curves along time")
        t = np.linspace(tc.domain[0], tc.domain[1], _count_points(points, LINE_POINTS))
        values = np.array([codebook.evaluate({**p, tc.name: t}, fields=[name])[name] for p in pts])
        out.update(layout="lines", time=tc.name, t=t, points=pts, labels=[_label(p) for p in pts], values=values)
        if ref is not None:
            tr = np.linspace(tc.domain[0], tc.domain[1], REFERENCE_MARKERS)
            params = {k: np.array([p[k] for p in pts]) for k in pts[0]} if pts and pts[0] else {}
            rv, failures = _reference_values(ref, name, params, tr, tc.name if _steady(codebook) else None)
            out["reference"] = {"t": tr, "values": rv, "description": _reference_description(ref)}
            out["failures"] = failures
        return out
    npts = _count_points(points, MAP_POINTS, 1000)
    xn, yn, xv, yv, fixed = _map_axes(codebook, over, fix, npts)
    values = codebook.evaluate(_map_coordinates(xn, yn, xv, yv, fixed), fields=[name])[name]
    out.update(layout="map", x=xn, y=yn, xv=xv, yv=yv, fixed=fixed, values=values)
    if ref is not None:
        rv, failures = _map_reference(codebook, ref, name, xn, yn, xv, yv, fixed)
        out["reference"] = {"values": rv, "description": _reference_description(ref)}
        out["failures"] = failures
    return out


def error_data(codebook, field: str | None = None, *, at=None, over=None, fix=None,
               points: int | None = None, reference=None) -> dict:
    """Absolute error ``|codebook - reference|`` of ``field`` along time (``at``) or over a map.

    Without ``at`` the default is a map over (time, first parameter), the other
    coordinates at their domain midpoints. ``reference`` is a callable like
    :func:`reference_solver`'s result (default: that reference).

    Returns
    -------
    dict
        As :func:`solution_data` (``layout`` 'lines' or 'map'), with ``values`` the
        absolute error, ``codebook`` and ``reference`` the two solutions on the same
        grid, ``description`` naming the reference, and ``max`` the largest error
        with ``argmax`` (the coordinates where it occurs).
    """
    name = _field(codebook, field)
    if at and over is not None:
        raise QueryError("--at and --over: give curves (--at) or a map (--over), not both")
    if at and fix:
        raise QueryError("--fix applies to maps (--over X,Y); curves take their parameters from --at")
    ref = reference_solver(codebook) if reference is None or reference is True else reference
    out = {"kind": "error", "problem": codebook.name, "field": name, "description": _reference_description(ref)}
    single = over is None and len(codebook.coordinates) == 1
    if at or single:
        tc, pts = _line_points(codebook, at, "error curves along time")
        t = np.linspace(tc.domain[0], tc.domain[1], _count_points(points, LINE_POINTS))
        cbv = np.array([codebook.evaluate({**p, tc.name: t}, fields=[name])[name] for p in pts])
        params = {k: np.array([p[k] for p in pts]) for k in pts[0]} if pts[0] else {}
        rv, failures = _reference_values(ref, name, params, t, tc.name if _steady(codebook) else None)
        err = np.abs(cbv - rv)
        out.update(layout="lines", time=tc.name, t=t, points=pts, labels=[_label(p) for p in pts],
                   codebook=cbv, reference=rv, values=err, failures=failures)
        if np.isfinite(err).any():
            i, j = np.unravel_index(np.nanargmax(err), err.shape)
            out.update(max=float(err[i, j]), argmax={**pts[i], tc.name: float(t[j])})
        else:
            out.update(max=float("nan"), argmax=None)
        return out
    npts = _count_points(points, MAP_POINTS, 1000)
    xn, yn, xv, yv, fixed = _map_axes(codebook, over, fix, npts)
    cbv = codebook.evaluate(_map_coordinates(xn, yn, xv, yv, fixed), fields=[name])[name]
    rv, failures = _map_reference(codebook, ref, name, xn, yn, xv, yv, fixed)
    err = np.abs(cbv - rv)
    out.update(layout="map", x=xn, y=yn, xv=xv, yv=yv, fixed=fixed, codebook=cbv, reference=rv, values=err,
               failures=failures)
    if np.isfinite(err).any():
        j, i = np.unravel_index(np.nanargmax(err), err.shape)
        out.update(max=float(err[j, i]), argmax={xn: float(xv[i]), yn: float(yv[j]), **fixed})
    else:
        out.update(max=float("nan"), argmax=None)
    return out


# ----------------------------------------------------------------------------------------------
# drawing
# ----------------------------------------------------------------------------------------------
def _new_figure(fig, figsize):
    if fig is not None:
        return fig
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, dpi=DEFAULT_DPI, layout="constrained")


def _title(fig, data: dict, what: str) -> None:
    fig.suptitle(f"{data['problem']}: {what}", fontsize="large")


def _fixed_note(fixed: Mapping[str, float]) -> str:
    return f" ({_label(fixed)})" if fixed else ""


def _compact(v: float) -> str:
    """Two significant digits, short exponents: 243 -> '240', 1.4e-05 -> '1.4e-5'."""
    a = abs(v)
    if a == 0 or 1e-3 <= a < 1e4:
        return f"{v:.2g}" if a < 100 else f"{float(f'{v:.2g}'):.0f}"
    mant, exp = f"{v:.1e}".split("e")
    return f"{mant}e{int(exp)}"


def _sci(v: float) -> str:
    """Two significant digits, exponent without padding: 1e-09 -> '1e-9'."""
    return f"{v:.2g}".replace("e-0", "e-").replace("e+0", "e+")


def _sigma_title(rank: int, sigma: np.ndarray, count: int, chars: int) -> str:
    """'unfolding rank R' and the first ``count`` singular values, wrapped at ``chars`` characters a
    line on at most two lines (values that do not fit are left out, as the ones after ``count`` are)."""
    lines, line = [], "\u03c3 = "
    values = [_compact(v) for v in sigma[:max(count, 1)]]
    shown = 0
    for i, v in enumerate(values):
        piece = v + ("," if i < len(values) - 1 else "")
        if len(line) + len(piece) + 2 > chars and shown:  # room for ' …'
            if len(lines) == 1:
                break
            lines.append(line.rstrip())
            line = ""
        line += piece + " "
        shown += 1
    line = line.rstrip()
    if shown < sigma.size:
        line = line.rstrip(",") + ", \u2026"
    lines.append(line)
    return "\n".join([f"unfolding rank {rank}"] + lines)


def draw_modes(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`modes_data`: one panel per coordinate, one curve per mode.

    CP codebooks: the legend gives each mode's weight alpha. Tensor trains: the
    HOSVD modes (unit norm over the nodes), the singular values above each panel.
    """
    panels = data["panels"]
    tt = data.get("representation") == "tensor-train"
    npan = len(panels)
    ncols = npan if npan <= 3 else (2 if npan == 4 else 3)
    nrows = math.ceil(npan / ncols)
    fig = _new_figure(fig, figsize or (3.6 * ncols + 1.4, (3.2 if tt else 2.9) * nrows + 0.6))
    axes = fig.subplots(nrows, ncols, squeeze=False).ravel()
    field = data["field"]
    for ax, panel in zip(axes, panels):
        x, vals = panel["x"], panel["values"]
        step = max(1, x.size // 8)
        for i in range(vals.shape[1]):
            st = _style(i)
            label = f"mode {i + 1}" if tt else f"mode {i + 1} (\u03b1={data['alphas'][i]:.3g})"
            ax.plot(x, vals[:, i], color=st["color"], linestyle=st["linestyle"], marker=st["marker"],
                    markersize=4.5, markerfacecolor="white", markevery=(i * step // max(vals.shape[1], 1), step),
                    linewidth=1.6, label=label)
        ax.axhline(0.0, color="0.6", linewidth=0.6, zorder=0)
        # the basis nodes as a rug along the bottom: where the stored values live
        ax.plot(panel["nodes"], np.zeros(panel["nodes"].size), linestyle="none", marker=2, markersize=6,
                color="0.35", transform=ax.get_xaxis_transform(), clip_on=False, label="_nodes")
        role = "time, " if panel["role"] == "time" else ""
        ax.set_xlabel(f"{panel['coordinate']}  ({role}{panel['nodes'].size} nodes: ticks on the axis)")
        ax.set_ylabel(f"modes of {field} in {panel['coordinate']}")
        ax.set_xlim(*panel["domain"])
        ax.grid(True, linewidth=0.4, alpha=0.5)
        if tt:
            # about 15 characters of the small font per inch of panel
            chars = max(12, int(15 * (fig.get_size_inches()[0] - 1.4) / ncols))
            ax.set_title(_sigma_title(panel["rank"], panel["singular_values"], panel["count"], chars),
                         fontsize="small", loc="left")
    for ax in axes[npan:]:
        ax.set_visible(False)
    if tt:
        widest = max(range(npan), key=lambda k: panels[k]["values"].shape[1])
        handles, labels = axes[widest].get_legend_handles_labels()
        ranks = "-".join(str(r) for r in data["ranks"]) or "none"
        fig.legend(handles, labels, loc="outside right upper", fontsize="small", title_fontsize="small",
                   title=f"{field}: tensor train\nranks {ranks}\n\nHOSVD modes,\nnormalized to\n"
                         f"unit 2-norm\nat the nodes")
        _title(fig, data, f"first {data['count']} HOSVD modes of {field}" if data["count"]
               else f"{field} is zero at every node: no HOSVD modes")
        return fig
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right upper", fontsize="small", title=f"{field}: {data['rank']} modes")
    _title(fig, data, f"first {data['count']} modes of {field}")
    return fig


def draw_convergence(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`convergence_data`: residual (log) per mode, and the outer iteration if recorded;
    for a time march, the step sizes against time and the ranks at the time nodes."""
    if data.get("method") == "march":
        return _draw_march_convergence(data, fig=fig, figsize=figsize)
    outer = data["outer"]
    fig = _new_figure(fig, figsize or ((10.0, 4.2) if outer is not None else (6.4, 4.2)))
    axes = fig.subplots(1, 2 if outer is not None else 1, squeeze=False).ravel()
    ax = axes[0]
    res = np.where(data["residual"] > 0, data["residual"], np.nan)
    ax.semilogy(data["modes"], res, color=_COLORS[0], linestyle="-", marker="o", markersize=4,
                markerfacecolor="white", linewidth=1.6, label="relative residual")
    tol = data["tolerance"]
    if math.isfinite(tol) and tol > 0:
        ax.axhline(tol, color="0.25", linestyle="--", linewidth=1.0, label=f"tolerance {tol:.1e}")
    ax.set_xlabel("number of modes")
    ax.set_ylabel("relative residual")
    ax.xaxis.get_major_locator().set_params(integer=True)
    ax.grid(True, which="both", linewidth=0.4, alpha=0.5)
    ax.legend(fontsize="small")
    state = "converged" if data["converged"] else "not converged"
    ax.set_title(f"{data['modes'][-1]} enrichment modes, {state}", fontsize="medium")
    if outer is not None:
        ax2 = axes[1]
        change = np.where(outer["change"] > 0, outer["change"], np.nan)
        ax2.semilogy(outer["iteration"], change, color=_COLORS[1], linestyle="--", marker="s", markersize=4,
                     markerfacecolor="white", linewidth=1.6)
        ax2.set_xlabel("outer iteration")
        ax2.set_ylabel("change per iteration")
        ax2.xaxis.get_major_locator().set_params(integer=True)
        ax2.grid(True, which="both", linewidth=0.4, alpha=0.5)
        ax2.set_title("outer (nonlinear) iteration", fontsize="medium")
    _title(fig, data, "convergence")
    return fig


def _draw_march_convergence(data: dict, *, fig=None, figsize=None):
    """(a) accepted step sizes against time, (b) tensor-train rank per time node and unknown."""
    fig = _new_figure(fig, figsize or (8.4, 6.4))
    ax1, ax2 = fig.subplots(2, 1, sharex=True)
    tname, nodes = data["time"], data["node_times"]
    sizes, start, end = data["step_sizes"], data["step_start"], data["step_end"]
    # each step size held over the interval it covers, a marker where the step ends
    ax1.stairs(sizes, np.concatenate([start[:1], end]), color=_COLORS[0], linewidth=1.6, baseline=None,
               label="_intervals")
    ax1.plot(end, sizes, linestyle="none", marker="o", markersize=4.5, markerfacecolor="white",
             color=_COLORS[0], label="accepted step (marker at its end)", clip_on=False, zorder=4)
    positive = sizes[sizes > 0]
    if positive.size and positive.max() > 10 * positive.min():
        ax1.set_yscale("log")
    else:
        ax1.set_ylim(0.0, 1.15 * float(sizes.max()) if sizes.size else 1.0)
    ax1.plot(nodes, np.zeros(nodes.size), linestyle="none", marker=2, markersize=6, color="0.35",
             transform=ax1.get_xaxis_transform(), clip_on=False, label="_nodes")
    ax1.set_ylabel("step size")
    ax1.grid(True, which="both", linewidth=0.4, alpha=0.5)
    ax1.legend(fontsize="small", loc="best")
    rejected = f", {data['rejected']} rejected" if data["rejected"] else ", none rejected"
    ax1.set_title(f"(a) {sizes.size} accepted steps{rejected} (ticks on the axis: time nodes)",
                  fontsize="medium", loc="left")
    ranks = data["ranks"]
    seen: dict[tuple, str] = {}
    for i, u in enumerate(data["unknowns"]):
        st = _style(i)
        key = tuple(ranks[:, i].tolist())
        label = u if key not in seen else f"{u} (same as {seen[key]})"
        seen.setdefault(key, u)
        # later lines drawn thinner with larger open markers: coinciding curves stay visible
        ax2.plot(nodes, ranks[:, i], color=st["color"], linestyle=st["linestyle"], marker=st["marker"],
                 markersize=4.5 + 2.0 * i, markerfacecolor="none", linewidth=max(0.8, 1.8 - 0.4 * i),
                 label=label, zorder=3 + len(data["unknowns"]) - i, clip_on=False)
    ax2.set_xlabel(f"{tname}  (time, {nodes.size} nodes)")
    ax2.set_ylabel("tensor-train rank\n(largest bond)")
    ax2.set_ylim(0, max(1, int(ranks.max()) if ranks.size else 1) * 1.15 + 0.5)
    ax2.yaxis.get_major_locator().set_params(integer=True)
    ax2.set_xlim(nodes[0], nodes[-1])
    ax2.grid(True, linewidth=0.4, alpha=0.5)
    ax2.legend(fontsize="small", loc="lower right", title="unknown", title_fontsize="small")
    ax2.set_title("(b) rank of the state over the non-time coordinates, at the time nodes", fontsize="medium",
                  loc="left")
    state = "" if data["converged"] else ", not converged"
    measured = "" if np.isnan(data["check_error"]) else f"max error {_sci(data['check_error'])} vs scipy, "
    _title(fig, data, f"time march, {measured}RMS estimate {_sci(data['error_estimate'])} "
                      f"(tolerance {_sci(data['tolerance'])}){state}")
    return fig


def _draw_lines(ax, data: dict, *, markers: bool) -> None:
    t, vals = data["t"], data["values"]
    step = max(1, t.size // 10)
    for i, label in enumerate(data["labels"]):
        st = _style(i)
        kw = dict(marker=st["marker"], markersize=4.5, markerfacecolor="white",
                  markevery=(i * step // max(len(data["labels"]), 1), step)) if markers else {}
        ax.plot(t, vals[i], color=st["color"], linestyle=st["linestyle"], linewidth=1.6, label=label, **kw)


def _map_mesh(ax, fig, data: dict, z, *, cmap: str, norm=None, label: str):
    mesh = ax.pcolormesh(data["xv"], data["yv"], z, cmap=cmap, norm=norm, shading="nearest", rasterized=True)
    fig.colorbar(mesh, ax=ax, label=label, extend="min" if norm is not None else "neither")
    ax.set_xlabel(data["x"])
    ax.set_ylabel(data["y"])
    return mesh


def draw_solution(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`solution_data`: curves along time, or a heat map (reference as markers / contours)."""
    from matplotlib.lines import Line2D

    field = data["field"]
    ref = data.get("reference")
    if data["layout"] == "lines":
        fig = _new_figure(fig, figsize or (8.4, 4.6))
        ax = fig.subplots()
        _draw_lines(ax, data, markers=ref is None)
        if ref is not None:
            for i in range(len(data["labels"])):
                st = _style(i)
                ax.plot(ref["t"], ref["values"][i], linestyle="none", marker=st["marker"], markersize=6,
                        markerfacecolor="none", markeredgecolor=st["color"], markeredgewidth=1.1)
            handles, labels = ax.get_legend_handles_labels()
            handles.append(Line2D([], [], linestyle="none", marker="s", markerfacecolor="none",
                                  markeredgecolor="0.2", markersize=6))
            labels.append("reference (open markers)")
            handles.insert(0, Line2D([], [], color="0.2", linewidth=1.6))
            labels.insert(0, "PGD codebook")
            fig.legend(handles, labels, fontsize="small", loc="outside right upper")
            ax.set_title(f"markers: reference ({ref['description']})", fontsize="small", pad=8)
        else:
            fig.legend(*ax.get_legend_handles_labels(), fontsize="small", loc="outside right upper")
        ax.set_xlabel(data["time"])
        ax.set_ylabel(field)
        ax.set_xlim(data["t"][0], data["t"][-1])
        ax.grid(True, linewidth=0.4, alpha=0.5)
        _title(fig, data, f"{field} against {data['time']}")
        return fig
    fig = _new_figure(fig, figsize or (7.0, 5.2))
    ax = fig.subplots()
    _map_mesh(ax, fig, data, data["values"], cmap=_MAP_CMAP, label=field)
    if ref is not None:
        z = data["values"]
        levels = np.linspace(np.nanmin(z), np.nanmax(z), 9)[1:-1]
        if levels.size and np.ptp(levels) > 0:
            ax.contour(data["xv"], data["yv"], z, levels=levels, colors="black", linewidths=1.4)
            ax.contour(data["xv"], data["yv"], ref["values"], levels=levels, colors="white", linewidths=1.0,
                       linestyles="--")
        ax.legend([Line2D([], [], color="black", linewidth=1.4), Line2D([], [], color="white", linestyle="--")],
                  ["PGD codebook (contours)", f"reference ({ref['description']})"], fontsize="small",
                  loc="upper right", facecolor="0.75", framealpha=0.9)
    _title(fig, data, f"{field} over {data['x']}, {data['y']}{_fixed_note(data['fixed'])}")
    return fig


def draw_error(data: dict, *, fig=None, figsize=None):
    """Figure of :func:`error_data`: |error| along time (log axis) or as a log-scaled heat map."""
    from matplotlib.colors import LogNorm

    field = data["field"]
    what = f"|{field} \u2212 {field}_ref|"
    if data["layout"] == "lines":
        fig = _new_figure(fig, figsize or (8.4, 4.6))
        ax = fig.subplots()
        shown = dict(data)
        shown["values"] = np.where(data["values"] > 0, data["values"], np.nan)  # log axis: exact zeros omitted
        shown["labels"] = [f"{lab} (max {np.nanmax(v) if np.isfinite(v).any() else float('nan'):.2g})"
                           for lab, v in zip(data["labels"], data["values"])]
        _draw_lines(ax, shown, markers=True)
        ax.set_yscale("log")
        ax.set_xlabel(data["time"])
        ax.set_ylabel(f"absolute error {what}")
        ax.set_xlim(data["t"][0], data["t"][-1])
        ax.grid(True, which="both", linewidth=0.4, alpha=0.5)
        fig.legend(*ax.get_legend_handles_labels(), fontsize="small", loc="outside right upper")
        ax.set_title(f"reference: {data['description']}", fontsize="small", pad=8)
        _title(fig, data, f"error of {field} against {data['time']}")
        return fig
    fig = _new_figure(fig, figsize or (7.0, 5.2))
    ax = fig.subplots()
    z = data["values"]
    positive = z[np.isfinite(z) & (z > 0)]
    if positive.size:
        vmax = float(positive.max())
        vmin = max(float(positive.min()), vmax * 1e-5)  # five decades: rounding-level zeros clip
        if vmin >= vmax:
            vmin = vmax / 10.0
        shown = np.clip(np.where(np.isfinite(z), z, np.nan), vmin, vmax)
        _map_mesh(ax, fig, data, shown, cmap=_ERROR_CMAP, norm=LogNorm(vmin=vmin, vmax=vmax),
                  label=f"absolute error {what}")
    else:  # identical everywhere (or the reference failed everywhere)
        _map_mesh(ax, fig, data, np.where(np.isfinite(z), z, np.nan), cmap=_ERROR_CMAP,
                  label=f"absolute error {what}")
    if data.get("argmax"):
        am = data["argmax"]
        ax.plot([am[data["x"]]], [am[data["y"]]], linestyle="none", marker="X", markersize=10,
                markerfacecolor="white", markeredgecolor="black", label=f"max {data['max']:.2g}", clip_on=False,
                zorder=5)
        ax.legend(fontsize="small", loc="upper right", framealpha=0.9)
    ax.set_title(f"reference: {data['description']}", fontsize="small", pad=10)
    _title(fig, data, f"error of {field} over {data['x']}, {data['y']}{_fixed_note(data['fixed'])}")
    return fig


def plot_modes(codebook, count: int = DEFAULT_COUNT, field: str | None = None, *, points=None, fig=None,
               figsize=None):
    """:func:`modes_data` drawn by :func:`draw_modes`; returns the Figure."""
    return draw_modes(modes_data(codebook, count, field, points=points), fig=fig, figsize=figsize)


def plot_convergence(codebook, *, fig=None, figsize=None):
    """:func:`convergence_data` drawn by :func:`draw_convergence`; returns the Figure."""
    return draw_convergence(convergence_data(codebook), fig=fig, figsize=figsize)


def plot_solution(codebook, field: str | None = None, *, fig=None, figsize=None, **options):
    """:func:`solution_data` drawn by :func:`draw_solution`; returns the Figure."""
    return draw_solution(solution_data(codebook, field, **options), fig=fig, figsize=figsize)


def plot_error(codebook, field: str | None = None, *, fig=None, figsize=None, **options):
    """:func:`error_data` drawn by :func:`draw_error`; returns the Figure."""
    return draw_error(error_data(codebook, field, **options), fig=fig, figsize=figsize)


# ----------------------------------------------------------------------------------------------
# files
# ----------------------------------------------------------------------------------------------
def default_output(codebook_path: str | os.PathLike, kind: str) -> Path:
    """``<directory of the codebook>/<codebook stem>-<kind>.png``."""
    p = Path(codebook_path)
    return p.with_name(f"{p.stem}-{kind}.png")


def _format(path: Path) -> str:
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise PgdError(f"--output {path}: unsupported file type {path.suffix or '(no suffix)'!r}; "
                       f"expected a .png or .svg file")
    return fmt


def save_figure(fig, path: str | os.PathLike, *, dpi: int = DEFAULT_DPI) -> Path:
    """Write ``fig`` as PNG or SVG (by the suffix of ``path``), atomically; returns the path.

    The image is ``figsize * dpi`` pixels (PNG) or ``figsize * 72`` points (SVG);
    no tight bounding box, so the size is exactly the figure's.
    """
    import tempfile

    import matplotlib

    path = Path(path)
    fmt = _format(path)
    if path.is_dir():
        raise PgdError(f"--output {path}: is a directory, expected a .png or .svg file name")
    if not path.parent.is_dir():
        raise PgdError(f"--output {path}: directory {str(path.parent)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    # reproducible files: no timestamps, fixed SVG ids
    metadata = {"Date": None} if fmt == "svg" else {"Software": None}
    try:
        with matplotlib.rc_context({"svg.hashsalt": "pgdcli", "svg.fonttype": "path"}):
            fig.savefig(tmp, format=fmt, dpi=dpi, metadata=metadata)
        os.chmod(tmp, 0o666 & ~_umask())  # mkstemp creates 0600; an image gets the usual permissions
        os.replace(tmp, path)
    except OSError as exc:
        _unlink(tmp)
        raise PgdError(f"--output {path}: cannot write ({exc.strerror or exc})") from None
    except BaseException:
        _unlink(tmp)
        raise
    return path


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _unlink(p: str) -> None:
    try:
        os.unlink(p)
    except FileNotFoundError:
        pass


_APPLIES = {
    "modes": {"--count", "--points", "--field"},
    "convergence": set(),
    "solution": {"--at", "--over", "--fix", "--reference", "--points", "--field"},
    "error": {"--at", "--over", "--fix", "--points", "--field"},
}


def render(codebook_path: str | os.PathLike, kind: str = "modes", output: str | os.PathLike | None = None, *,
           field: str | None = None, count: int | None = None, at: Iterable[str] | None = None,
           over: str | None = None, fix: Iterable[str] | None = None, reference: bool = False,
           points: int | None = None, dpi: int = DEFAULT_DPI, size: str | tuple[float, float] | None = None,
           warn: Callable[[str], None] | None = None) -> Path:
    """What ``pgd plot`` does: load the codebook, compute, draw and save; returns the written path.

    Options that do not apply to ``kind`` raise :class:`QueryError` (naming
    the option) rather than being ignored. ``warn`` receives reference
    failures (one line each).
    """
    from ..codebook.codebook import Codebook

    if kind not in KINDS:
        raise QueryError(f"--kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    target = Path(output) if output is not None else default_output(codebook_path, kind)
    _format(target)  # before any work
    if int(dpi) != dpi or not 10 <= dpi <= 1200:
        raise QueryError(f"--dpi: expected an integer between 10 and 1200, got {dpi}")
    figsize = parse_size(size) if isinstance(size, str) else (tuple(size) if size is not None else None)
    at = list(at or [])
    fix = list(fix or [])
    given = {"--count": count is not None, "--at": bool(at), "--over": over is not None, "--fix": bool(fix),
             "--reference": bool(reference), "--points": points is not None, "--field": field is not None}
    for opt, present in given.items():
        if present and opt not in _APPLIES[kind]:
            applies = [k for k, a in _APPLIES.items() if opt in a]
            note = " (error plots always compare with the reference)" if opt == "--reference" else ""
            raise QueryError(f"{opt} does not apply to --kind {kind}; it is for --kind {' and '.join(applies)}{note}")
    cb = Codebook.load(codebook_path)
    if kind == "modes":
        data = modes_data(cb, DEFAULT_COUNT if count is None else count, field, points=points)
        fig = draw_modes(data, figsize=figsize)
    elif kind == "convergence":
        data = convergence_data(cb)
        fig = draw_convergence(data, figsize=figsize)
    elif kind == "solution":
        ref = reference_solver(cb, source=str(codebook_path)) if reference else False
        data = solution_data(cb, field, at=at, over=over, fix=fix, points=points, reference=ref)
        fig = draw_solution(data, figsize=figsize)
    else:
        ref = reference_solver(cb, source=str(codebook_path))
        data = error_data(cb, field, at=at, over=over, fix=fix, points=points, reference=ref)
        fig = draw_error(data, figsize=figsize)
    if warn is not None:
        for message in data.get("failures", []):
            warn(message)
    return save_figure(fig, target, dpi=dpi)

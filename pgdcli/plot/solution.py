"""Data of the ``solution`` and ``error`` pictures: curves along time, maps over two coordinates, the reference."""

from __future__ import annotations

import time
from typing import Callable, Mapping

import numpy as np

from ..checks.reference import solve_reference
from ..checks.reference_base import TIME_UP, time_budget
from ..errors import PgdError, QueryError, TimeBudgetExceeded
from .options import (DEFAULT_AT_CURVES, LINE_POINTS, MAP_POINTS, REFERENCE_MARKERS, count_points, domain_midpoint,
                      field_name, is_steady, line_axis, parse_over, parse_point, point_label, time_coordinate_of)

__all__ = ["solution_data", "error_data", "reference_solver", "line_points", "reference_values"]


# ----------------------------------------------------------------------------------------------
# the independent reference
# ----------------------------------------------------------------------------------------------
def reference_solver(codebook, *, source: str = "<codebook>", method: str | None = None,
                     rtol: float | None = None, atol: float | None = None,
                     max_seconds: float | None = None) -> Callable:
    """The independent reference for ``codebook``: ``solve(params, times) -> ReferenceResult``.

    ``max_seconds`` bounds the time of all its integrations together (None: no bound).
    Re-parses the spec embedded in the codebook and integrates it with
    :func:`pgdcli.checks.reference.solve_reference` (scipy ``solve_ivp``; ``None`` settings: its
    defaults, DOP853 at 1e-12 for ODEs, the method of lines with BDF for space coordinates).
    """
    from ..problem.spec import parse_spec

    if not codebook.spec_text.strip():
        raise PgdError(f"{source}: the codebook has no embedded spec; a reference solution needs one")
    problem = parse_spec(codebook.spec_text, source=source, allow_nonlinear=True)

    started = time.monotonic()

    def solve(params: Mapping[str, np.ndarray], times: np.ndarray | None):
        left = None if max_seconds is None else max_seconds - (time.monotonic() - started)
        with time_budget(left):
            result = solve_reference(problem, dict(params), None if times is None else np.asarray(times, dtype=float),
                                     method=method, rtol=rtol, atol=atol)
        if TIME_UP in result.messages:
            raise TimeBudgetExceeded(f"{source}: the reference integrations stopped at the time budget of "
                                     f"{max_seconds:g} s before the picture was complete (raise --max-seconds); "
                                     f"nothing written")
        return result

    if problem.time is None:
        solve.description = "Chebyshev collocation, sparse direct solve"
    else:
        solve.description = ("solve_ivp " + (method or "(default method)")
                             + (f", rtol={rtol:g}, atol={atol:g}" if rtol is not None and atol is not None else ""))
    return solve


def reference_values(reference: Callable, field: str, params: Mapping[str, np.ndarray],
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
        where = point_label({k: float(v[s]) for k, v in params.items()})
        bad = [m for m in messages[s * (total // size):(s + 1) * (total // size)] if m] or [""]
        failures.append(f"reference failed at {where}: {' '.join(str(bad[0]).split()) or 'unknown reason'}")
    return values, failures


def _reference_description(reference) -> str:
    return getattr(reference, "description", "independent reference")


def line_points(codebook, at, what: str) -> tuple[object, list[dict[str, float]]]:
    """Complete ``--at`` points: every coordinate but the curves' axis set (default: domain midpoint)."""
    tc = line_axis(codebook, what)
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
        points.append({c.name: g.get(c.name, domain_midpoint(c)) for c in others})
    return tc, points


def _map_axes(codebook, over, fix, npts: int):
    if over is None:
        tc = line_axis(codebook, "a map without --over")
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
    fixed = {c.name: fixed_given.get(c.name, domain_midpoint(c)) for c in codebook.coordinates if c.name not in (xn, yn)}
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
    if is_steady(codebook):  # no times: every map point is a point of the reference
        values, failures = reference_values(reference, field, {k: v.reshape(-1) for k, v in coords.items()}, None)
        return values.reshape(yv.size, xv.size), failures
    tc = time_coordinate_of(codebook, "a reference solution")
    if tc.name in (xn, yn):  # one solve per point of the other axis, all times at once
        pn, pv, time_is_x = (yn, yv, True) if tc.name == xn else (xn, xv, False)
        times = xv if time_is_x else yv
        params = {pn: pv}
        params.update({k: np.full(pv.size, v) for k, v in fixed.items() if k != tc.name})
        values, failures = reference_values(reference, field, params, times)  # (n_p, n_t)
        return (values if time_is_x else values.T), failures
    t = fixed[tc.name]
    params = {k: v.reshape(-1) for k, v in coords.items() if k != tc.name}
    values, failures = reference_values(reference, field, params, np.array([t]))
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
    name = field_name(codebook, field)
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
        tc, pts = line_points(codebook, at, "curves along time")
        t = np.linspace(tc.domain[0], tc.domain[1], count_points(points, LINE_POINTS))
        values = np.array([codebook.evaluate({**p, tc.name: t}, fields=[name])[name] for p in pts])
        out.update(layout="lines", time=tc.name, t=t, points=pts, labels=[point_label(p) for p in pts], values=values)
        if ref is not None:
            tr = np.linspace(tc.domain[0], tc.domain[1], REFERENCE_MARKERS)
            params = {k: np.array([p[k] for p in pts]) for k in pts[0]} if pts and pts[0] else {}
            rv, failures = reference_values(ref, name, params, tr, tc.name if is_steady(codebook) else None)
            out["reference"] = {"t": tr, "values": rv, "description": _reference_description(ref)}
            out["failures"] = failures
        return out
    npts = count_points(points, MAP_POINTS, 1000)
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
    name = field_name(codebook, field)
    if at and over is not None:
        raise QueryError("--at and --over: give curves (--at) or a map (--over), not both")
    if at and fix:
        raise QueryError("--fix applies to maps (--over X,Y); curves take their parameters from --at")
    ref = reference_solver(codebook) if reference is None or reference is True else reference
    out = {"kind": "error", "problem": codebook.name, "field": name, "description": _reference_description(ref)}
    single = over is None and len(codebook.coordinates) == 1
    if at or single:
        tc, pts = line_points(codebook, at, "error curves along time")
        t = np.linspace(tc.domain[0], tc.domain[1], count_points(points, LINE_POINTS))
        cbv = np.array([codebook.evaluate({**p, tc.name: t}, fields=[name])[name] for p in pts])
        params = {k: np.array([p[k] for p in pts]) for k in pts[0]} if pts[0] else {}
        rv, failures = reference_values(ref, name, params, t, tc.name if is_steady(codebook) else None)
        err = np.abs(cbv - rv)
        out.update(layout="lines", time=tc.name, t=t, points=pts, labels=[point_label(p) for p in pts],
                   codebook=cbv, reference=rv, values=err, failures=failures)
        if np.isfinite(err).any():
            i, j = np.unravel_index(np.nanargmax(err), err.shape)
            out.update(max=float(err[i, j]), argmax={**pts[i], tc.name: float(t[j])})
        else:
            out.update(max=float("nan"), argmax=None)
        return out
    npts = count_points(points, MAP_POINTS, 1000)
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

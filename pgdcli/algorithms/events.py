"""Event times from a codebook: the first crossing of an event's condition, as a separated field.

For a parameter point the condition ``g(u(t, p), t, p)`` is scanned along the codebook's time
nodes and the midpoints between them (the codebook resolves ``u`` there, so a crossing between
two scan points is a single sign change of a smooth function); the first bracket in the event's
direction is narrowed on the codebook's own interpolant by Chandrupatla's bracketing method
(``scipy.optimize.elementwise.find_root``), all points at once. At the start time the exact initial
values decide (a condition that holds there exactly is not an event there, as in ``solve_ivp``'s
event location).

:func:`event_field` builds the event time on the grid of the codebook's parameter nodes as a tensor
train (a cross approximation, or the whole grid when small) whose time core is constant: a field
of the codebook's coordinates that does not depend on time.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
from scipy.optimize.elementwise import find_root

from ..codebook.codebook import Codebook
from ..discretization.coordinates import CoordinateInfo
from ..errors import SolverError
from ..problem.events import Event, condition_values, state_gradient_norm
from ..tensors.cross import tt_cross
from ..tensors.tt import TT

__all__ = ["first_crossings", "event_field", "time_per_state", "NoEvent", "MAX_DOUBLINGS"]

#: Scan values held at once (points x scan times x unknowns): bounds the memory of one batch.
SCAN_BATCH_VALUES = 2_000_000
ROOT_ITERATIONS = 80
#: A crossing is located to this share of the time span (far below any tolerance).
SETTLED = 1e-13
#: Grids of parameter nodes of at most this many points are located whole (cheaper than a cross).
DENSE_EVENT_GRID = 20_000
#: Times a coordinate's node intervals may be halved for an event (beyond the codebook's nodes).
MAX_DOUBLINGS = 4
#: Most nodes of an event's coordinate.
MAX_EVENT_NODES = 1025
#: Points off the nodes per coordinate at which an event field is measured before it is kept.
LINE_POINTS = 24


class NoEvent(SolverError):
    """The event does not happen before the end time at some parameter point."""


def _initial_values(problem, params: Mapping[str, np.ndarray], S: int) -> dict[str, np.ndarray]:
    return {u.name: np.broadcast_to(np.asarray(u.initial.evaluate(**params), dtype=float), (S,))
            for u in problem.unknowns}


def _crossed(g0: np.ndarray, g1: np.ndarray, direction: str) -> np.ndarray:
    rising = (g0 < 0) & (g1 >= 0)
    falling = (g0 > 0) & (g1 <= 0)
    return rising if direction == "rising" else falling if direction == "falling" else rising | falling


def _scan_times(codebook, time: str) -> np.ndarray:
    nodes = codebook.coordinate(time).basis().nodes
    scan = np.empty(2 * nodes.size - 1)
    scan[0::2] = nodes
    scan[1::2] = 0.5 * (nodes[1:] + nodes[:-1])
    return scan


def _condition(event: Event, codebook, time: str, t: np.ndarray, params: Mapping[str, np.ndarray]) -> np.ndarray:
    """``g`` at one time per point (``t`` of shape (S,))."""
    values = codebook.evaluate({time: t, **params})
    return condition_values(event, values, {time: t, **params})


def _brackets(problem, codebook, event: Event, params: Mapping[str, np.ndarray], S: int):
    """Per point, the first scan interval where the condition crosses: (a, b, found)."""
    time = problem.time
    scan = _scan_times(codebook, time)
    g = np.empty((S, scan.size))
    step = max(1, SCAN_BATCH_VALUES // (scan.size * max(1, len(problem.unknowns))))
    for lo in range(0, S, step):
        rows = {n: v[lo:lo + step] for n, v in params.items()}
        values = codebook.evaluate_series(rows, {time: scan}) if params else \
            {u: v.reshape(1, -1) for u, v in codebook.evaluate_series({}, {time: scan}).items()}
        g[lo:lo + step] = condition_values(event, values, {time: scan[None, :], **{n: v[:, None] for n, v in rows.items()}})
    start = condition_values(event, _initial_values(problem, params, S), {time: np.full(S, scan[0]), **params})
    g[:, 0] = np.where(start == 0.0, g[:, 1], start)  # met exactly at the start: not an event there
    hit = _crossed(g[:, :-1], g[:, 1:], event.direction)
    found = hit.any(axis=1)
    k = np.argmax(hit, axis=1)
    return scan[k], scan[k + 1], found


def time_per_state(problem, codebook, event: Event, params: Mapping[str, np.ndarray], t: np.ndarray) -> np.ndarray:
    """``sum_i |dg/du_i| / |dg/dt|`` at the crossings ``t`` on the codebook: how far in time an error of
    the state moves the event (1 where the crossing is not slow: at least the time's own units)."""
    time = problem.time
    lo, hi = codebook.coordinate(time).domain
    h = 1e-6 * (hi - lo)
    a, b = np.clip(t - h, lo, hi), np.clip(t + h, lo, hi)
    with np.errstate(all="ignore"):
        rate = np.abs(_condition(event, codebook, time, b, params) - _condition(event, codebook, time, a, params)) / (b - a)
        state = codebook.evaluate({time: t, **params})
        norm = state_gradient_norm(event, state, {time: t, **params})
        scale = norm / rate
    return np.where(np.isfinite(scale), np.maximum(scale, 1.0), 1.0)


def first_crossings(problem, codebook, event: Event, params: Mapping[str, np.ndarray]) -> np.ndarray:
    """The event's time at parameter points, from the codebook (NaN where it does not happen).

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        An ODE problem (a time coordinate, no space coordinates).
    codebook : pgdcli.Codebook
    event : pgdcli.problem.events.Event
    params : mapping of str to ndarray, shape (S,)
        Every parameter coordinate's values (``{}``: the one point of a problem without parameters).

    Returns
    -------
    ndarray, shape (S,)
    """
    params = {n: np.asarray(v, dtype=float).reshape(-1) for n, v in params.items()}
    S = next(iter(params.values())).size if params else 1
    a, b, found = _brackets(problem, codebook, event, params, S)
    lo, hi = codebook.coordinate(problem.time).domain
    names = list(params)
    root = a.copy()
    rows = np.flatnonzero(found)
    if rows.size:
        def g(t, *values):
            return _condition(event, codebook, problem.time, t, dict(zip(names, values)))

        with np.errstate(all="ignore"):
            res = find_root(g, (a[rows], b[rows]), args=tuple(params[n][rows] for n in names),
                            tolerances={"xatol": SETTLED * (hi - lo), "xrtol": 4 * np.finfo(float).eps,
                                        "fatol": 0.0, "frtol": 0.0}, maxiter=ROOT_ITERATIONS)
        # a bracket the codebook's own values do not confirm (a crossing within rounding of the start)
        # keeps its start
        root[rows] = np.where(np.isfinite(res.x) & (res.status >= 0), res.x, a[rows])
    return np.where(found, root, np.nan)


def _event_coordinates(codebook, time: str, doublings: dict[str, int]) -> list:
    """The event field's coordinates: time with two nodes (the field is constant along it), every other
    coordinate as the codebook's with its node intervals doubled ``doublings[name]`` times."""
    out = []
    for c in codebook.coordinates:
        if c.name == time:
            out.append(CoordinateInfo(c.name, c.domain, 2, "chebyshev", c.role))
        else:
            out.append(CoordinateInfo(c.name, c.domain, (c.nodes - 1) * 2 ** doublings[c.name] + 1, c.discretization,
                                      c.role, c.breakpoints))
    return out


def _train_on(problem, codebook, event: Event, coordinates: list, tolerance: float, counter: list) -> TT:
    """The event time on the grid of ``coordinates``' nodes (time excluded) as a train, time core first."""
    time = problem.time
    others = [c for c in coordinates if c.name != time]
    nodes = [c.basis().nodes for c in others]

    def times_at(indices: np.ndarray) -> np.ndarray:
        params = {c.name: x[indices[:, j]] for j, (c, x) in enumerate(zip(others, nodes))}
        out = first_crossings(problem, codebook, event, params)
        counter[0] += out.size
        missing = np.flatnonzero(~np.isfinite(out))
        if missing.size:
            where = ", ".join(f"{n}={v[missing[0]]:.6g}" for n, v in params.items())
            end = codebook.coordinate(time).domain[1]
            raise NoEvent(f"event {event.name!r} ({event.text}) does not happen before {time}={end:g} at "
                          f"{where or 'the start'}: an event time is stored for every parameter point; extend the "
                          f"time domain or narrow the parameters' domains")
        return out

    names = [c.name for c in coordinates]
    if not others:
        value = float(times_at(np.zeros((1, 0), dtype=int))[0])
        return TT([np.full((1, 2, 1), value)], [names.index(time)])
    result = tt_cross(times_at, [x.size for x in nodes], tolerance, dense_limit=DENSE_EVENT_GRID)
    if not result.converged:
        raise SolverError(f"event {event.name!r}: its time is not a smooth function of the parameters "
                          f"({result.message}); it may jump where the first crossing changes")
    cores = [np.ones((1, 2, 1))] + [np.asarray(c) for c in result.train.cores]
    order = [names.index(time)] + [names.index(others[j].name) for j in result.train.mode_order]
    return TT(cores, order)


def _line_errors(problem, codebook, event: Event, book, coordinates: list, rng) -> dict[str, float]:
    """Per parameter coordinate, the largest error of the field off its nodes in that coordinate alone
    (the others at random nodes), against the crossing located on the codebook itself, over the time an
    error of one unit of the state moves the crossing (:func:`time_per_state`, at least 1)."""
    time = problem.time
    others = [c for c in coordinates if c.name != time]
    nodes = {c.name: c.basis().nodes for c in others}
    errors = {}
    for c in others:
        x = nodes[c.name]
        k = rng.integers(0, x.size - 1, LINE_POINTS)
        points = {n: v[rng.integers(0, v.size, LINE_POINTS)] for n, v in nodes.items()}
        points[c.name] = x[k] + (x[k + 1] - x[k]) * rng.uniform(0.3, 0.7, LINE_POINTS)
        exact = first_crossings(problem, codebook, event, points)
        got = book.evaluate({**points, time: float(codebook.coordinate(time).domain[0])}, [event.name])[event.name]
        if not np.isfinite(exact).all():
            errors[c.name] = np.inf
            continue
        scale = time_per_state(problem, codebook, event, points, exact)
        errors[c.name] = float(np.max(np.abs(got - exact) / scale))
    return errors


def event_field(problem, codebook, event: Event, tolerance: float, rng=None) -> tuple[list, TT, dict]:
    """The event's time as a tensor train on its own grid, refined until it interpolates within ``tolerance``.

    The grid starts from the codebook's parameter nodes; a coordinate whose points off the nodes
    (the others at nodes) miss ``tolerance`` has its node intervals halved, up to
    :data:`MAX_DOUBLINGS` times (an event time may need more nodes than the solution: the root of a
    polynomial in a parameter is not a polynomial in it).

    Parameters
    ----------
    problem, codebook, event
        As :func:`first_crossings`.
    tolerance : float
        Max error of the field's interpolation against the crossing located on the codebook, in time
        units, or in the state's where the crossing is slow (see :func:`time_per_state`).

    Returns
    -------
    coordinates : list of CoordinateInfo
        The field's coordinates, in codebook order (time with 2 nodes).
    field : TT
        Mode order: time first, then the parameters.
    info : dict
        ``evaluations`` (crossings located), ``nodes`` (per coordinate) and ``error`` (the largest
        off-node error measured).

    Raises
    ------
    NoEvent
        The event does not happen before the end time at a parameter node, named.
    SolverError
        The field does not converge (its time jumps) within :data:`MAX_DOUBLINGS` refinements.
    """
    rng = rng or np.random.default_rng(7)
    time = problem.time
    doublings = {c.name: 0 for c in codebook.coordinates if c.name != time}
    counter = [0]
    while True:
        coordinates = _event_coordinates(codebook, time, doublings)
        train = _train_on(problem, codebook, event, coordinates, 0.1 * tolerance, counter)
        if not doublings:
            return coordinates, train, {"evaluations": counter[0], "nodes": {}, "error": 0.0}
        book = Codebook(coordinates, {event.name: train}, name=event.name)
        errors = _line_errors(problem, codebook, event, book, coordinates, rng)
        worst = max(errors.values())
        short = [n for n, e in errors.items() if not e <= tolerance]
        if not short:
            return coordinates, train, {"evaluations": counter[0], "error": worst,
                                        "nodes": {c.name: c.nodes for c in coordinates if c.name != time}}
        if any(doublings[n] >= MAX_DOUBLINGS or
               (codebook.coordinate(n).nodes - 1) * 2 ** (doublings[n] + 1) + 1 > MAX_EVENT_NODES for n in short):
            raise SolverError(f"event {event.name!r}: its time is not resolved along {short[0]!r} (error {worst:.2g} "
                              f"> {tolerance:.2g} off the nodes with {dict((c.name, c.nodes) for c in coordinates)[short[0]]} nodes); "
                              f"it may jump where the first crossing changes, or graze the condition")
        for n in short:
            doublings[n] += 1

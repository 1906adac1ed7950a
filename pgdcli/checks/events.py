"""Event times of a codebook against scipy's event location (``solve_ivp(events=...)``).

At the check sample's parameter points (corners, face nodes, uniform points and points off the nodes
in one coordinate at a time: :func:`~pgdcli.checks.sampling.check_sample`,
:func:`~pgdcli.checks.sampling.line_sample`) each event's condition is located by ``solve_ivp`` on
the problem's own equations at tight tolerances, one point at a time (an event is a property of
one trajectory); the codebook's event times must be within ``tolerance + relative_tolerance * |t|``
of it, or else be the exact event time of a trajectory within ``tolerance`` of the true one (the
reference state at the codebook's event time within ``tolerance`` of the event's surface: a slow
crossing moves far in time for a small error of the state). A reference event at the start time
itself is not an event (the codebook's rule).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..problem.events import condition_values, state_gradient_norm
from .reference_ode import implicit_options
from .reference_system import CompiledSystem
from .sampling import check_sample, line_sample

__all__ = ["EventCheck", "check_events", "reference_event_times", "EVENT_POINTS"]

#: Most parameter points at which the event times are checked (each is one reference solve).
EVENT_POINTS = 160
#: The reference: DOP853, or Radau for a stiff problem, at these tolerances.
RTOL, ATOL = 1e-12, 1e-13
_DIRECTION = {"any": 0, "rising": 1, "falling": -1}


@dataclass
class EventCheck:
    """One event's time measured against the reference.

    Attributes
    ----------
    name : str
    error : float
        Max abs error of the event time over the points (inf where the reference finds no event).
    ratio : float
        Max over the points of the smaller of error / (tolerance + relative_tolerance * |t|) and
        distance / tolerance, ``distance`` the reference state's at the codebook's event time from
        the event's surface (``|g| / sum_i |dg/du_i|``).
    where : dict
        The parameter point of the largest ratio.
    points : int
        Points the reference located the event at (or ran to the end without one).
    failed : int
        Points where the reference integration failed.
    """

    name: str
    error: float
    ratio: float
    where: dict
    points: int
    failed: int

    @property
    def accurate(self) -> bool:
        return bool(self.points) and self.ratio <= 1.0


def _sample(problem, codebook, seed: int) -> dict[str, np.ndarray]:
    points, _ = check_sample(problem, codebook, seed)
    if not points:
        return {}
    lines, _ = line_sample(problem, codebook, seed)
    points = {n: np.concatenate([points[n], lines[n]]) for n in points}
    S = next(iter(points.values())).size
    if S > EVENT_POINTS:
        keep = np.unique(np.linspace(0, S - 1, EVENT_POINTS).round().astype(int))
        points = {n: v[keep] for n, v in points.items()}
    return points


def _event_function(event, system, time: str, params: dict):
    index = system.index

    def g(t, y):
        values = {u: y[i:i + 1] for u, i in index.items()}
        return float(condition_values(event, values, {time: np.array([t]), **params})[0])

    g.direction = _DIRECTION[event.direction]
    return g


def reference_event_times(problem, points: dict, *, stiff: bool = False, max_evaluations: int = 2_000_000,
                          at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every event's first time after the start at parameter points, from ``solve_ivp``.

    All points in one vectorized call with dense output (each event's first crossing bracketed
    between the solver's steps and located by ``brentq`` on the dense output); where that call
    fails, one call per point with ``solve_ivp``'s own event location (:func:`_one_by_one`).
    Parameters and returns are those of :func:`_one_by_one`.
    """
    together = _together(problem, points, stiff, max_evaluations, at)
    return together if together is not None else _one_by_one(problem, points, stiff=stiff,
                                                              max_evaluations=max_evaluations, at=at)


def _together(problem, points: dict, stiff: bool, max_evaluations: int, at):
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    time = problem.time
    t0, t1 = problem.coordinate(time).domain
    S = next(iter(points.values())).size if points else 1
    method = "Radau" if stiff else "DOP853"
    with np.errstate(all="ignore"):
        system = CompiledSystem(problem, points, S, max_evaluations)
        y0 = system.initial(problem, points)
    if system.bad.any() or not np.isfinite(y0).all():
        return None
    try:
        with np.errstate(all="ignore"):
            sol = solve_ivp(system, (t0, t1), y0.reshape(-1), method=method, rtol=RTOL, atol=ATOL, dense_output=True,
                            **implicit_options(method, system.q, S))
    except (ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError):
        return None
    if sol.status != 0 or not np.isfinite(sol.y).all():
        return None
    q, index = system.q, system.index
    states = sol.y.reshape(S, q, -1)
    times = np.full((len(problem.events), S), np.nan)
    distance = np.full((len(problem.events), S), np.nan)
    for k, event in enumerate(problem.events):
        where = {time: sol.t[None, :], **{n: v[:, None] for n, v in points.items()}}
        g = condition_values(event, {u: states[:, i, :] for u, i in index.items()}, where)
        g = np.array(g)
        g[:, 0] = np.where(g[:, 0] == 0.0, g[:, 1], g[:, 0])  # met exactly at the start: not an event there
        rising, falling = (g[:, :-1] < 0) & (g[:, 1:] >= 0), (g[:, :-1] > 0) & (g[:, 1:] <= 0)
        hit = rising if event.direction == "rising" else falling if event.direction == "falling" else rising | falling
        for i in np.flatnonzero(hit.any(axis=1)):
            j = int(np.argmax(hit[i]))
            params = {n: v[i:i + 1] for n, v in points.items()}

            def g_at(t, i=i, params=params):
                y = sol.sol(t).reshape(S, q)[i]
                return float(condition_values(event, {u: y[c:c + 1] for u, c in index.items()},
                                              {time: np.array([t]), **params})[0])

            a, b = float(sol.t[j]), float(sol.t[j + 1])
            times[k, i] = b if g_at(b) == 0.0 else brentq(g_at, a, b, xtol=1e-15 * max(1.0, abs(b)), rtol=1e-15)
        if at is not None:
            for i in np.flatnonzero(np.isfinite(at[k])):
                y = sol.sol(float(at[k, i])).reshape(S, q)[i]
                distance[k, i] = _distance(event, system, y, time, float(at[k, i]),
                                           {n: v[i:i + 1] for n, v in points.items()})
    return times, np.ones(S, dtype=bool), distance


def _one_by_one(problem, points: dict, *, stiff: bool = False, max_evaluations: int = 2_000_000,
                at: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every event's first time after the start at parameter points, one ``solve_ivp`` with event location
    per point.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        With events, a time coordinate and no space coordinates.
    points : dict of str to ndarray, shape (S,)
        Every parameter coordinate's values (``{}``: the one point of a problem without parameters).
    stiff : bool
        Integrate with Radau instead of DOP853.
    at : ndarray, shape (n_events, S), optional
        Times at which to measure the distance of the reference state from each event's surface.

    Returns
    -------
    times : ndarray, shape (n_events, S)
        NaN where the event does not happen before the end time.
    ok : ndarray of bool, shape (S,)
        False where the integration failed.
    distance : ndarray, shape (n_events, S)
        ``|g| / sum_i |dg/du_i|`` of the reference state at ``at`` (NaN without ``at``).
    """
    from scipy.integrate import solve_ivp

    time = problem.time
    t0, t1 = problem.coordinate(time).domain
    S = next(iter(points.values())).size if points else 1
    times = np.full((len(problem.events), S), np.nan)
    distance = np.full((len(problem.events), S), np.nan)
    ok = np.ones(S, dtype=bool)
    for i in range(S):
        params = {n: v[i:i + 1] for n, v in points.items()}
        with np.errstate(all="ignore"):
            system = CompiledSystem(problem, params, 1, max_evaluations)
            y0 = system.initial(problem, params).reshape(-1)
        if system.bad.any() or not np.isfinite(y0).all():
            ok[i] = False
            continue
        functions = [_event_function(e, system, time, params) for e in problem.events]
        try:
            with np.errstate(all="ignore"):
                sol = solve_ivp(system, (t0, t1), y0, method="Radau" if stiff else "DOP853", rtol=RTOL, atol=ATOL,
                                events=functions, dense_output=at is not None)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError):
            ok[i] = False
            continue
        if sol.status == -1:
            ok[i] = False
            continue
        for k, found in enumerate(sol.t_events):
            later = found[found > t0 + 8 * np.spacing(max(abs(t0), abs(t1)))]
            if later.size:
                times[k, i] = later[0]
            if at is not None and np.isfinite(at[k, i]):
                distance[k, i] = _distance(problem.events[k], system, sol.sol(at[k, i]), time, at[k, i], params)
    return times, ok, distance


def _distance(event, system, y: np.ndarray, time: str, t: float, params: dict) -> float:
    """``|g| / sum_i |dg/du_i|`` at the state ``y``: how far it is from the event's surface."""
    values = {u: y[i:i + 1] for u, i in system.index.items()}
    where = {time: np.array([t]), **params}
    with np.errstate(all="ignore"):
        g = condition_values(event, values, where)[0]
        norm = state_gradient_norm(event, values, where)[0]
    return float(abs(g) / norm) if norm > 0 else float(abs(g))


def check_events(problem, codebook, *, tolerance: float, relative_tolerance: float = 0.0, stiff: bool = False,
                 seed: int = 0, points: dict | None = None) -> list[EventCheck]:
    """The codebook's event times (``codebook.event_times``) against :func:`reference_event_times`.

    ``points`` (parameter coordinate -> values) replaces the check sample (``pgd verify`` gives its own).

    Returns
    -------
    list of EventCheck
        One per event of the problem, in spec order.
    """
    points = _sample(problem, codebook, seed) if points is None else {n: np.asarray(v, dtype=float).reshape(-1)
                                                                         for n, v in points.items()}
    approx = codebook.event_times(points) if points else {k: np.atleast_1d(v)
                                                           for k, v in codebook.event_times({}).items()}
    at = np.array([np.asarray(approx[e.name], dtype=float).reshape(-1) for e in problem.events])
    reference, ok, distance = reference_event_times(problem, points, stiff=stiff, at=at)
    out = []
    for k, event in enumerate(problem.events):
        ref = reference[k][ok]
        got = at[k][ok]
        with np.errstate(invalid="ignore"):
            error = np.where(np.isnan(ref), np.inf, np.abs(got - ref))
            in_time = error / (tolerance + relative_tolerance * np.abs(np.nan_to_num(ref)))
            ratio = np.fmin(in_time, distance[k][ok] / tolerance)
        if ratio.size == 0:
            out.append(EventCheck(event.name, float("nan"), float("nan"), {}, 0, int((~ok).sum())))
            continue
        worst = int(np.argmax(ratio))
        where = {n: float(v[ok][worst]) for n, v in points.items()}
        out.append(EventCheck(event.name, float(error.max()), float(ratio.max()), where, int(ok.sum()),
                              int((~ok).sum())))
    return out

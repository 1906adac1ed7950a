"""Event times of a codebook against scipy's event location (``solve_ivp(events=...)``).

At the check sample's parameter points (corners, face nodes, uniform points and points off the nodes
in one coordinate at a time: :func:`~pgdcli.checks.sampling.check_sample`,
:func:`~pgdcli.checks.sampling.line_sample`) each event's condition is located by ``solve_ivp`` on
the problem's own equations at tight tolerances, one point at a time (an event is a property of
one trajectory); the codebook's event times must be within ``tolerance + relative_tolerance * |t|``
of it. A reference event at the start time itself is not an event (the codebook's rule).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..problem.events import condition_values
from .reference_ode import CompiledSystem
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
        Max of error / (tolerance + relative_tolerance * |t|).
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


def reference_event_times(problem, points: dict, *, stiff: bool = False, max_evaluations: int = 2_000_000
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Every event's first time after the start at parameter points, by ``solve_ivp`` with event location.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        With events, a time coordinate and no space coordinates.
    points : dict of str to ndarray, shape (S,)
        Every parameter coordinate's values (``{}``: the one point of a problem without parameters).
    stiff : bool
        Integrate with Radau instead of DOP853.

    Returns
    -------
    times : ndarray, shape (n_events, S)
        NaN where the event does not happen before the end time.
    ok : ndarray of bool, shape (S,)
        False where the integration failed.
    """
    from scipy.integrate import solve_ivp

    time = problem.time
    t0, t1 = problem.coordinate(time).domain
    S = next(iter(points.values())).size if points else 1
    times = np.full((len(problem.events), S), np.nan)
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
                                events=functions)
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
    return times, ok


def check_events(problem, codebook, *, tolerance: float, relative_tolerance: float = 0.0, stiff: bool = False,
                 seed: int = 0) -> list[EventCheck]:
    """The codebook's event times (``codebook.event_times``) against :func:`reference_event_times`.

    Returns
    -------
    list of EventCheck
        One per event of the problem, in spec order.
    """
    points = _sample(problem, codebook, seed)
    reference, ok = reference_event_times(problem, points, stiff=stiff)
    approx = codebook.event_times(points) if points else {k: np.atleast_1d(v)
                                                           for k, v in codebook.event_times({}).items()}
    out = []
    for k, event in enumerate(problem.events):
        ref = reference[k][ok]
        got = np.asarray(approx[event.name], dtype=float).reshape(-1)[ok]
        with np.errstate(invalid="ignore"):
            error = np.where(np.isnan(ref), np.inf, np.abs(got - ref))
            ratio = error / (tolerance + relative_tolerance * np.abs(np.nan_to_num(ref)))
        if ratio.size == 0:
            out.append(EventCheck(event.name, float("nan"), float("nan"), {}, 0, int((~ok).sum())))
            continue
        worst = int(np.argmax(ratio))
        where = {n: float(v[ok][worst]) for n, v in points.items()}
        out.append(EventCheck(event.name, float(error.max()), float(ratio.max()), where, int(ok.sum()),
                              int((~ok).sum())))
    return out

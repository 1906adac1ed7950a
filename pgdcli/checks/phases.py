"""A motion with an acting event against scipy: ``solve_ivp`` stopped at the event and restarted.

The reference of a codebook with phases (:class:`~pgdcli.codebook.phases.PhasedCodebook`) is
scipy's documented pattern for resets: integrate with a terminal event, apply the reset to the state
at the event, restart from there, until the end time. One point at a time (DOP853 at rtol 1e-12, or
Radau for a stiff problem); each segment's dense output gives the state at any time of that segment.

:func:`check_phases` measures a phased codebook at parameter points (corners, faces, random points)
and times across every phase. The state jumps at an event, so a time between the codebook's event
time and the reference's has its value on the other side of the jump in one of them: such a time is
not compared (the event times themselves are measured under the event rule); every other time is held
to ``tolerance + relative_tolerance * |u|``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..problem.events import acting_event, condition_values, reset_values
from .reference_system import CompiledSystem

__all__ = ["Motion", "reference_motion", "PhaseCheck", "check_phases", "phase_sample", "RTOL", "ATOL"]

RTOL, ATOL = 1e-12, 1e-13
_DIRECTION = {"any": 0, "rising": 1, "falling": -1}


@dataclass
class Motion:
    """One trajectory of the reference: its segments between events.

    Attributes
    ----------
    events : list of float
        The acting event's times, in order (the last may be after the end time when asked for).
    segments : list of (float, float, OdeSolution)
        Start, end and dense output of each segment.
    ended : bool
        A terminal event ended the motion at ``events[0]``.
    failed : bool
        The integration failed.
    index : dict
        Unknown name -> its row in the state.
    """

    events: list = field(default_factory=list)
    segments: list = field(default_factory=list)
    ended: bool = False
    failed: bool = False
    index: dict = field(default_factory=dict)

    def state(self, t: float) -> np.ndarray | None:
        """The state at ``t`` (None after a terminal event or beyond the segments); at an event time, after it."""
        if self.ended and t >= self.events[0]:
            return None
        for start, end, sol in self.segments:
            if start <= t < end or (t == end and sol is self.segments[-1][2]):
                return sol(t)
        return None


def _event_function(event, system, time: str, params: dict):
    def g(t, y):
        values = {u: y[i:i + 1] for u, i in system.index.items()}
        return float(condition_values(event, values, {time: np.array([t]), **params})[0])

    g.terminal = True
    g.direction = _DIRECTION[event.direction]
    return g


def reference_motion(problem, params: dict, *, stiff: bool = False, beyond: bool = False,
                     most: int = 64) -> Motion:
    """The reference trajectory at one parameter point (``params``: name -> array of one value).

    ``beyond``: after the end time, integrate on to the next event (up to ten times the time span),
    so that every phase the codebook needs has its event. ``most`` caps the events (a Zeno motion).
    """
    from scipy.integrate import solve_ivp

    event = acting_event(problem.events)
    time = problem.time
    t0, t1 = problem.coordinate(time).domain
    horizon = t1 + 10 * (t1 - t0) if beyond else t1
    system = CompiledSystem(problem, params, 1, 2_000_000)
    y = system.initial(problem, params).reshape(-1)
    g = _event_function(event, system, time, params)
    motion, t = Motion(index=dict(system.index)), t0
    while t < horizon and len(motion.events) <= most:
        try:
            with np.errstate(all="ignore"):
                sol = solve_ivp(system, (t, horizon), y, method="Radau" if stiff else "DOP853", rtol=RTOL, atol=ATOL,
                                events=[g], dense_output=True)
        except (ArithmeticError, ValueError, np.linalg.LinAlgError, RuntimeError):
            sol = None
        if sol is None or sol.status == -1:
            motion.failed = True
            return motion
        end = float(sol.t[-1])
        motion.segments.append((t, end, sol.sol))
        if sol.status != 1:
            return motion
        motion.events.append(end)
        if event.terminal:
            motion.ended = True
            return motion
        before = {u: sol.y_events[0][0][i:i + 1] for u, i in system.index.items()}
        after = reset_values(event, before, {time: np.array([end]), **params})
        y, t = np.array([float(after[u][0]) for u in system.index]), end
        if beyond and end > t1:
            return motion
    return motion


def phase_sample(problem, random: int, seed: int = 0) -> dict[str, np.ndarray]:
    """Corners, a point on each face and ``random`` uniform points of the parameter box."""
    names = [c.name for c in problem.coordinates if c.role != "time"]
    if not names:
        return {}
    rng = np.random.default_rng([seed, 17])
    domains = [problem.coordinate(n).domain for n in names]
    corners = np.array(list(itertools.product(*domains)), dtype=float)
    faces = np.array([[rng.uniform(*d) for d in domains] for _ in range(2 * len(names))])
    for j in range(len(names)):
        faces[2 * j, j], faces[2 * j + 1, j] = domains[j]
    uniform = np.column_stack([rng.uniform(*d, size=random) for d in domains])
    rows = np.vstack([corners, faces, uniform])
    return {n: rows[:, j] for j, n in enumerate(names)}


@dataclass
class PhaseCheck:
    """The phased codebook against the reference: largest error, its ratio to the tolerance, where."""

    error: float
    ratio: float
    where: dict
    points: int
    compared: int
    skipped: int
    failed: int


def check_phases(problem, codebook, *, tolerance: float, relative_tolerance: float = 0.0, stiff: bool = False,
                 points: dict | None = None, times: int = 24, seed: int = 0) -> PhaseCheck:
    """The codebook's values against :func:`reference_motion` at ``points`` (default :func:`phase_sample`)
    and ``times`` times per point (uniform, plus just after each reference event)."""
    points = phase_sample(problem, 24, seed) if points is None else points
    time = problem.time
    t0, t1 = problem.coordinate(time).domain
    S = next(iter(points.values())).size if points else 1
    rng = np.random.default_rng([seed, 19])
    worst = PhaseCheck(0.0, 0.0, {}, 0, 0, 0, 0)
    for i in range(S):
        params = {n: v[i:i + 1] for n, v in points.items()}
        motion = reference_motion(problem, params, stiff=stiff)
        if motion.failed:
            worst.failed += 1
            continue
        worst.points += 1
        ts = np.concatenate([rng.uniform(t0, t1, times), [t0, t1],
                             [e + 1e-3 * (t1 - t0) for e in motion.events if e + 1e-3 * (t1 - t0) < t1]])
        _compare(problem, codebook, motion, params, ts, tolerance, relative_tolerance, worst)
    return worst


def _compare(problem, codebook, motion: Motion, params: dict, ts: np.ndarray, tolerance: float,
             relative_tolerance: float, worst: PhaseCheck) -> None:
    time = problem.time
    mine = codebook.event_sequence({n: v for n, v in params.items()})[0] if params else codebook.event_sequence({})
    mine = np.atleast_1d(mine)
    theirs = np.array(motion.events, dtype=float)
    got = codebook.evaluate({time: ts, **{n: np.full(ts.size, v[0]) for n, v in params.items()}})
    names = list(got)
    for j, t in enumerate(ts):
        k_mine, k_ref = int(np.sum(mine <= t)), int(np.sum(theirs <= t))
        if k_mine != k_ref:  # between the two event times: on either side of the jump
            worst.skipped += 1
            continue
        state = motion.state(float(t))
        values = np.array([got[u][j] for u in names])
        if state is None:
            ok = bool(np.all(np.isnan(values)))
            ratio, error = (0.0, 0.0) if ok else (np.inf, np.inf)
        else:
            ref = np.array([state[motion.index[u]] for u in names])
            error = float(np.max(np.abs(values - ref)))
            ratio = float(np.max(np.abs(values - ref) / (tolerance + relative_tolerance * np.abs(ref))))
            ratio = ratio if np.isfinite(ratio) else np.inf
        worst.compared += 1
        if ratio > worst.ratio:
            worst.ratio, worst.error = ratio, error
            worst.where = {**{n: float(v[0]) for n, v in params.items()}, time: float(t)}


"""A motion with an acting event against scipy: ``solve_ivp`` stopped at the event and restarted.

The reference of a codebook with phases (:class:`~pgdcli.codebook.phases.PhasedCodebook`) is
scipy's documented pattern for resets: integrate with a terminal event, apply the reset to the state
at the event, restart from there, until the end time. One point at a time (DOP853 at rtol 1e-12, or
Radau for a stiff problem); each segment's dense output gives the state at any time of that segment.

:func:`check_phases` measures a phased codebook at parameter points (corners, faces, random points)
and times across every phase. The state jumps at an event, so at a time between the codebook's event
time and the reference's the two are on either side of the jump: the reference is taken on the
codebook's side (with the codebook's own event time), and the event times are measured apart. Every
value is held to ``tolerance + relative_tolerance * |u|``, every later event time to
``tolerance + relative_tolerance * |t|``.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, field

import numpy as np

from ..problem.events import acting_event, condition_values, reset_values
from .events import EventCheck
from .reference_system import CompiledSystem

__all__ = ["Motion", "reference_motion", "PhaseValues", "phase_values", "PhaseCheck", "check_phases", "phase_sample",
           "RTOL", "ATOL"]

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

    def segment_state(self, k: int, t: float) -> np.ndarray | None:
        """The state at ``t`` on segment ``k`` (after the k-th event; None after a terminal event or without
        that segment). A ``t`` just outside the segment extends its last (or first) step."""
        if self.ended and k >= 1 or k >= len(self.segments):
            return None
        return self.segments[k][2](t)


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
class PhaseValues:
    """The codebook and the reference at ``S`` parameter points and ``T`` times (:func:`phase_values`).

    Attributes
    ----------
    reference, codebook : dict of str to ndarray, shape (S, T)
        Per unknown (NaN: no value, after a terminal event, or a failed reference).
    success : ndarray of bool, shape (S,)
    messages : list of str
        Why the reference failed at a point ('' where it did not).
    events : list of EventCheck
        The acting event's second, third, ... times (``name[2]``, ...) against the reference's.
    """

    reference: dict
    codebook: dict
    success: np.ndarray
    messages: list
    events: list


def phase_values(problem, codebook, points: dict, times: np.ndarray, *, tolerance: float,
                 relative_tolerance: float = 0.0, stiff: bool = False) -> PhaseValues:
    """The phased codebook and :func:`reference_motion` at every point and time.

    At a time between the codebook's event time and the reference's the two are on either side of the
    jump: the reference is then taken on the codebook's side (its segment's dense output, a step beyond
    the segment's end by at most that gap), so a value is always compared with the motion it follows.
    """
    time = problem.time
    event = acting_event(problem.events)
    S = next(iter(points.values())).size if points else 1
    T = times.size
    names = list(problem.unknown_names)
    reference = {u: np.full((S, T), np.nan) for u in names}
    mine = codebook.evaluate({time: np.broadcast_to(times, (S, T)),
                              **{n: np.broadcast_to(v[:, None], (S, T)) for n, v in points.items()}})
    sequences = codebook.event_sequence(points) if points else codebook.event_sequence({})[None, :]
    success, messages = np.ones(S, dtype=bool), [""] * S
    gaps = {}
    for i in range(S):
        params = {n: v[i:i + 1] for n, v in points.items()}
        motion = reference_motion(problem, params, stiff=stiff)
        if motion.failed:
            success[i], messages[i] = False, "the restarted reference failed"
            continue
        ours = sequences[i]
        for k, theirs in enumerate(motion.events[:ours.size]):
            if k > 0:
                gaps.setdefault(k, []).append((i, ours[k], theirs))
        for j, t in enumerate(times):
            k = int(np.sum(ours <= t))
            state = motion.segment_state(k, float(t))
            for u in names:
                reference[u][i, j] = np.nan if state is None else state[motion.index[u]]
    checks = [_event_check(f"{event.name}[{k + 1}]", rows, points, tolerance, relative_tolerance)
              for k, rows in sorted(gaps.items())]
    return PhaseValues(reference, {u: np.asarray(mine[u]) for u in names}, success, messages, checks)


def _event_check(name: str, rows: list, points: dict, tolerance: float, relative_tolerance: float) -> EventCheck:
    i = np.array([r[0] for r in rows])
    ours, theirs = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])
    error = np.abs(ours - theirs)
    ratio = error / (tolerance + relative_tolerance * np.abs(theirs))
    worst = int(np.argmax(ratio))
    where = {n: float(v[i[worst]]) for n, v in points.items()}
    return EventCheck(name, float(error.max()), float(ratio.max()), where, int(i.size), 0)


@dataclass
class PhaseCheck:
    """The phased codebook against the reference: largest error, its ratio to the tolerance, where."""

    error: float
    ratio: float
    where: dict
    points: int
    events: list


def check_phases(problem, codebook, *, tolerance: float, relative_tolerance: float = 0.0, stiff: bool = False,
                 points: dict | None = None, times: int = 40, seed: int = 0) -> PhaseCheck:
    """The codebook's values and later event times against :func:`reference_motion` at ``points`` (default
    :func:`phase_sample`) and ``times`` uniform times plus both ends."""
    points = phase_sample(problem, 40, seed) if points is None else points
    time = problem.time
    t0, t1 = problem.coordinate(time).domain
    rng = np.random.default_rng([seed, 19])
    ts = np.sort(np.concatenate([rng.uniform(t0, t1, times), [t0, t1]]))
    got = phase_values(problem, codebook, points, ts, tolerance=tolerance, relative_tolerance=relative_tolerance,
                       stiff=stiff)
    worst = PhaseCheck(0.0, 0.0, {}, int(got.success.sum()), got.events)
    for u, ref in got.reference.items():
        mine = got.codebook[u][got.success]
        ref = ref[got.success]
        with np.errstate(invalid="ignore"):
            error = np.where(np.isnan(ref) & np.isnan(mine), 0.0, np.abs(mine - ref))
            error = np.where(np.isnan(error), np.inf, error)
            ratio = error / (tolerance + relative_tolerance * np.abs(np.nan_to_num(ref)))
        if ratio.size and ratio.max() > worst.ratio:
            i, j = np.unravel_index(int(np.argmax(ratio)), ratio.shape)
            rows = np.flatnonzero(got.success)
            worst.ratio, worst.error = float(ratio[i, j]), float(error[i, j])
            worst.where = {**{n: float(v[rows[i]]) for n, v in points.items()}, time: float(ts[j])}
    for check in got.events:
        if check.ratio > worst.ratio:
            worst.ratio, worst.error, worst.where = check.ratio, check.error, {**check.where, "event": check.name}
    return worst

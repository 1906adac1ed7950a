"""Blow-up of the separated time march: predicted from the accepted steps, located on the grid.

Near a pole ``u ~ c / (t* - t)`` the error control shrinks every step, so the step-size floor
is reached only after hundreds of ever smaller steps at growing ranks. :class:`BlowupWatch`
extrapolates ``1/max|u|`` to zero once the steps keep shrinking and stops the march long
before; :func:`blowup_region` names where the last good state is largest.
"""

from __future__ import annotations

import numpy as np

from ..tensors.tt import TT
from .polynomial_rhs import SINGLE_POINT, NonlinearSystem

__all__ = ["BlowupWatch", "blowup_region", "largest_value", "confirmed", "first_zero_after", "WATCH_AGREE"]

# Blow-up prediction (see BlowupWatch): near a pole u ~ c / (t* - t) the error control shrinks
# every step, so the step-size floor above is reached only after hundreds of ever smaller steps
# at growing ranks (the paper's 4.2 on [0, 1]: 504 steps, ~100 s). Once the steps have shrunk
# WATCH_STEPS times in a row and WATCH_SHRINK-fold overall, 1/max|u| is extrapolated to zero.
WATCH_STEPS, WATCH_SHRINK = 8, 10.0
# The prediction stops the march when the state grew BLOWUP_GROWTH-fold and two extrapolations
# a span of at least WATCH_SPAN x (the distance left) apart agree to WATCH_AGREE x that distance:
# a pole's estimates converge, an exponential's (1/max|u| = exp(-lambda t)) move with t.
BLOWUP_GROWTH, WATCH_SPAN, WATCH_AGREE = 10.0, 0.3, 0.1
# Grids up to this many nodes are searched whole for max|u| once armed, larger ones at their corners
# (if the largest value is inside, its 1/M may not fall to zero: no prediction, the floor still holds).
WATCH_POINTS = 200_000


class BlowupWatch:
    """Predicts a finite-time blow-up from the accepted steps, long before the steps underflow.

    Only while the steps keep shrinking (``WATCH_STEPS`` in a row, ``WATCH_SHRINK``-fold
    below the largest) does it look at the state: the largest nodal value ``M(t)`` of any
    unknown. Near a pole ``1/M`` falls (almost linearly) to zero at the blow-up time ``t*``, so
    the parabola through the last three samples estimates ``t*`` (the line through two, at
    first). The march is stopped when ``M`` grew ``BLOWUP_GROWTH``-fold since the start, and
    the estimate made at least ``WATCH_SPAN`` x (the distance left) earlier agrees with the
    current one to ``WATCH_AGREE`` x that distance, and ``t*`` plus twice their disagreement
    lies before the end of the time domain. Exponential growth also shrinks the steps
    (absolute error control), but its extrapolated ``t*`` stays ``1/lambda`` ahead of ``t``:
    the two estimates then differ by the span between them and it never fires.
    """

    def __init__(self, system: NonlinearSystem, state, t_final: float, largest=None):
        self.system, self.t_final = system, t_final
        # the largest nodal |value| of a state: of trains by default; the grid march passes its own
        self.largest_of = largest or (lambda st: largest_value(system, st, WATCH_POINTS)[0])
        self.initial = max(self.largest_of(state), 1e-300)
        self.largest = 0.0  # the largest accepted step so far
        self.samples: list[tuple[float, float, float | None]] = []  # (t, 1/M, estimate of t*)

    def __call__(self, t: float, sizes: list[float], state: list[TT]) -> float | None:
        """After an accepted step ending at ``t`` (``sizes``: the march's accepted steps, this one
        last): the predicted blow-up time, or None."""
        h = sizes[-1]
        self.largest = max(self.largest, h)
        recent = sizes[-WATCH_STEPS - 1:]
        shrinking = (len(recent) == WATCH_STEPS + 1 and all(b < a for a, b in zip(recent, recent[1:]))
                     and h * WATCH_SHRINK <= self.largest)
        if not shrinking:
            self.samples.clear()
            return None
        biggest = self.largest_of(state)
        inverse = 1.0 / biggest if biggest > 0 else np.inf
        self.samples.append((t, inverse, None))
        estimate = first_zero_after(self.samples[-3:]) if len(self.samples) >= 2 else None
        self.samples[-1] = (t, inverse, estimate)
        if estimate is None or biggest < BLOWUP_GROWTH * self.initial or estimate >= self.t_final:
            return None
        for t_then, _, earlier in reversed(self.samples[:-1]):
            if t - t_then >= WATCH_SPAN * (estimate - t):
                return estimate if earlier is not None and confirmed(t, estimate, earlier, self.t_final) else None
        return None


def confirmed(t: float, estimate: float, earlier: float, t_final: float) -> bool:
    """Two estimates of the blow-up time agree to ``WATCH_AGREE`` x the distance left, and the
    end lies after the estimate by more than twice their disagreement (a pole just past the end is
    no failure: the march goes on and reaches the end)."""
    spread = abs(estimate - earlier)
    return spread <= WATCH_AGREE * (estimate - t) and estimate + 2.0 * spread < t_final


def first_zero_after(samples: list[tuple]) -> float | None:
    """Where the line (two samples) or parabola (three) through ``(t, 1/M)`` first reaches zero after
    the last ``t``; None if it does not fall to zero. Near a pole ``1/M = (t* - t)/c + O((t* - t)^2)``:
    the parabola's root is accurate to third order in the distance left, the line's to second."""
    ts = np.array([x[0] for x in samples])
    ys = np.array([x[1] for x in samples])
    if not np.all(np.isfinite(ys)):
        return None
    t_last, scale = ts[-1], ts[-1] - ts[0]
    coef = np.polyfit((ts - t_last) / scale, ys, len(ts) - 1)  # about the last sample, unit span
    roots = np.roots(coef)
    ahead = [float(r.real) for r in roots if abs(r.imag) <= 1e-12 * max(1.0, abs(r)) and r.real > 0.0]
    return t_last + scale * min(ahead) if ahead else None


def largest_value(system: NonlinearSystem, state: list[TT], max_points: int = 2_000_000) -> tuple[float, tuple]:
    """Largest nodal |value| of any unknown and its grid index: the whole grid if it has at most
    ``max_points`` nodes, else the corners of the box only (where blow-ups start in practice)."""
    shape = system.shape
    if int(np.prod(shape)) <= max_points:
        values = np.max([np.abs(u.full()) for u in state], axis=0)
        idx = np.unravel_index(int(np.argmax(values)), shape)
        return float(values[idx]), tuple(int(i) for i in idx)
    best, idx = -1.0, None
    for corner in np.ndindex(*(2,) * len(shape)):
        ix = tuple(0 if c == 0 else n - 1 for c, n in zip(corner, shape))
        mats = [np.eye(n)[[i]] for n, i in zip(shape, ix)]
        v = max(abs(float(u.evaluate(mats)[0])) for u in state)
        if v > best:
            best, idx = v, ix
    return best, idx


def blowup_region(system: NonlinearSystem, state: list[TT]) -> str:
    """Where the last good state is largest, as 'a=0, b=1, c=1' (nodes of the parameter grid)."""
    if system.params == [SINGLE_POINT]:
        return ""
    _, idx = largest_value(system, state)
    parts = [f"{p}={system.bases[p].nodes[i]:.4g}" for p, i in zip(system.params, idx)]
    return ", ".join(parts)

"""Switch location: a march step ends where a switching function of time switches at some node.

A switching function of time and the parameters (``step(t - 0.7)``, ``max(t - a, 0)``,
``where(t < T, F, 0)``) makes the right-hand side non-smooth at a time that each node of the
parameter grid knows from the formula alone (:func:`pgdcli.problem.switches.time_switches`). A
Runge-Kutta step across it loses its order, and the step control shrinks the steps around it until
they underflow at a jump. The march on arrays therefore finds, before trying a step, the earliest
sign change of a switch argument at any node inside it (bisection on the formula, to a relative
``1e-13`` of the time domain) and ends the step just before it: the step is smooth for every node,
and the time slab (the step) ends at that node's switch, so its codebook interpolates smooth pieces
in time. The next step starts from the right-hand side evaluated just past the switch
(:meth:`SwitchLocator.past`), so that its first stage is on the side of the switch the step lies on.

Switches of the unknowns (``max(-y, 0)`` along a trajectory) are not located: a trial step across
one gives a dense output polluted by the switch itself, and locating them reliably needs the
right-hand side evaluated with each switch frozen on its side, which the march does not do.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..problem.general import evaluate

__all__ = ["SwitchLocator", "past_switch"]

#: Bisection stops when the bracket is this fraction of the time domain.
BRACKET = 1e-13
#: A sign change this close (fraction of the time domain) to the start of a step is the switch the
#: previous step ended at, or one too close to cut a step at (the step control's floor is 1e-7): it
#: is left inside the step. The next step's first stage is evaluated a tenth of this past the start.
MARGIN = 1e-6
#: Every located switch adds a time slab for every node: the march stops locating (and steps across
#: switches as the step control allows) once the stored values this adds would pass this count.
MAX_LOCATED_VALUES = 2 ** 26


class SwitchLocator:
    """The switch arguments of time and parameters at the nodes of an array state (unknowns, P).

    Parameters
    ----------
    switches : sequence of tuple
        Trees with ``('name', n)`` leaves: the time and parameters.
    params : sequence of str
    nodes : mapping of str to ndarray
        The grid nodes of every parameter.
    indices : ndarray of int, shape (P, d), optional
        The parameter multi-indices of the P nodes; None: the whole grid, C order.
    time : str
    span : float
        The length of the time domain.
    unknowns : int
        The number of unknowns (for the budget of stored values).
    """

    def __init__(self, switches: Sequence[tuple], params: Sequence[str], nodes, indices, time: str, span: float,
                 unknowns: int = 1):
        self.switches, self.time, self.span = list(switches), time, span
        if indices is None:
            grids = np.meshgrid(*[nodes[p] for p in params], indexing="ij")
            self.params = {p: g.reshape(-1) for p, g in zip(params, grids)}
        else:
            self.params = {p: nodes[p][indices[:, k]] for k, p in enumerate(params)}
        size = next(iter(self.params.values())).size if self.params else 1
        self.size = size
        self.located = 0
        self.budget = MAX_LOCATED_VALUES // (16 * unknowns * size)

    def values(self, t: float) -> np.ndarray:
        """The arguments at the nodes at time t, shape (switches, P)."""
        values = dict(self.params)
        values[self.time] = t
        with np.errstate(all="ignore"):
            return np.stack([np.broadcast_to(evaluate(tree, values), (self.size,)) for tree in self.switches])

    def cut(self, t: float, h: float) -> float | None:
        """The time just before the earliest switch at any node inside the step ``(t, t + h)``, or None."""
        if self.located >= self.budget:
            return None
        low = t + MARGIN * self.span  # a switch closer to the start: the one just landed on, left inside
        if low >= t + h:
            return None
        before = self.before(low, t + h)
        if before is None or t + h - before < 10 * BRACKET * self.span:
            return None  # none, or a switch at the very end of the step
        self.located += 1
        return before

    def before(self, low: float, high: float) -> float | None:
        """Just before (within :data:`BRACKET`) the earliest sign change at any node in ``(low, high)``, or None."""
        start = np.sign(self.values(low))
        changes = start * np.sign(self.values(high)) < 0
        if not changes.any():
            return None
        while high - low > BRACKET * self.span:  # bisection on the earliest sign change at any node
            mid = 0.5 * (low + high)
            if (changes & (start * np.sign(self.values(mid)) < 0)).any():
                high = mid
            else:
                low = mid
        return low

    def past(self, rhs, t: float, y: np.ndarray, f: np.ndarray) -> np.ndarray:
        """The right-hand side just past the switch a step ended before (:func:`past_switch`)."""
        return past_switch(rhs, t, y, f, self.span)

    def time_derivative(self, rhs, t: float, y: np.ndarray) -> np.ndarray:
        """``df/dt`` at ``(t, y)`` on the smooth piece a step from t marches on (linearly implicit steppers).

        A central difference would straddle the switch the previous step ended at: a one-sided
        difference of second order, from just past t (as :func:`past_switch`), over a stencil of
        ``2 delta`` (``delta`` the relative ``eps^(1/3)`` of the time scale) shortened to end before
        the next switch at any node.
        """
        start = t + 0.1 * MARGIN * self.span
        delta = np.finfo(float).eps ** (1.0 / 3.0) * max(abs(t), self.span)
        before = self.before(start, start + 2.0 * delta)
        if before is not None:
            delta = max(0.5 * (before - start), 0.1 * BRACKET * self.span)
        f0, f1, f2 = (rhs(start + k * delta, y) for k in range(3))
        return (4.0 * f1 - 3.0 * f0 - f2) / (2.0 * delta)


def past_switch(rhs, t: float, y: np.ndarray, f: np.ndarray, span: float) -> np.ndarray:
    """The right-hand side just past the switch a step ended before: an Euler nudge of ``MARGIN / 10``
    of the time domain's length ``span``, so that the next step's first stage is on the switch's far side."""
    delta = 0.1 * MARGIN * span
    return rhs(t + delta, y + delta * f)

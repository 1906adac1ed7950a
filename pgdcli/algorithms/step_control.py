"""Step-size control of the separated time march: error per unit step, rejections, stiffness.

All errors are in the norm of the march's state: the root-mean-square over the nodes of the
parameter grid (the grid's array), or the Frobenius norm of tensor trains (that times the square
root of the grid size). The local Runge-Kutta error of a step of length
``h`` may be ``LOCAL_FRACTION * tolerance * h / span``: the local errors of all steps add up
to at most that share of the tolerance.
"""

from __future__ import annotations

import numpy as np

from ..discretization.basis import chebyshev_unit_nodes

__all__ = ["StepControl", "MAX_GROWTH", "SAFETY", "LOCAL_FRACTION", "STATE_FRACTION", "STAGE_FRACTION",
           "MIN_STEP", "STIFF_MIN_STEP", "MAX_GROWTH_OF_NORM", "MAX_STAGE_TIGHTENINGS", "output_times", "step_refusal"]

# Step-size control. The error per unit step grows along these solutions, so the
# usual safety factor 0.9 made every other step a rejection; 0.8 removes them on the
# shipped problems.
MAX_GROWTH = 3.0
SAFETY = 0.8
# Shares of the tolerance: local Runge-Kutta error, state rounding per step,
# stage rounding (enters the step multiplied by h).
LOCAL_FRACTION, STATE_FRACTION, STAGE_FRACTION = 0.3, 0.02, 0.05
# Blow-up detection: a step below MIN_STEP * (time span), or a state whose norm grew
# by MAX_GROWTH_OF_NORM, ends the march (near a finite-time singularity the steps
# shrink geometrically, so waiting for a floating-point underflow costs hundreds of steps).
MIN_STEP = 1e-7
# A stiff stepper's first steps resolve transients many decades shorter than the time domain
# (kinetics over [0, 1e5] with a transient of 1e-6): its floor is only the arithmetic's.
STIFF_MIN_STEP = 1e-14
# Below this order an explicit pair's small steps may be its accuracy, not its stability (step_refusal).
LOW_ORDER = 5
# Steps per time domain below which an explicit pair out of steps is not called stiff (step_refusal): a cap
# this low is the user's solver.max_steps, and only raising it helps.
FEW_STEPS = 1000
MAX_GROWTH_OF_NORM = 1e6
# Stiff problems: a rounding error dY of a stage value reaches the error estimate as J dY, which
# no step size reduces; each time that is detected the stage rounding is made 10x tighter, at
# most this many times (then the step-size floor ends the march: 'blows up or is stiff').
MAX_STAGE_TIGHTENINGS = 4
# A shorter step that did not halve the error estimate shows rounding noise when an error of the
# method's order would have fallen about twelvefold: at NOISE_STEP h for an order-7 estimate per
# unit step, at NOISE_STEP^(7/p) h for order p.
NOISE_STEP = 0.7


class StepControl:
    """Accepts or rejects trial steps of an embedded pair and proposes the next step.

    Parameters
    ----------
    span : float
        Length of the time domain.
    local_tol : float
        Bound of the local errors added up over the march (in the state space's norm).
    order : int
        The embedded estimate's order ``p`` (scipy's ``error_estimator_order``): the local error
        is O(h^(p+1)) per step, O(h^p) per unit step.
    per_step : bool
        Bound the error per step by ``local_tol`` instead of the error per unit step by
        ``local_tol / span``: for stiff steppers, whose local errors in a fast transient are damped
        by the dynamics instead of adding up (the error gate measures the result either way).
    """

    def __init__(self, span: float, local_tol: float, order: int, per_step: bool = False):
        self.span, self.local_tol, self.per_step = span, local_tol, per_step
        self.exponent = -1.0 / (order + 1) if per_step else -1.0 / order
        self.noise_step = NOISE_STEP ** (7.0 / order)
        self.just_rejected = False
        self.last_rejection: tuple[float, float, float] | None = None  # (t, h, ratio) of the last rejected step
        self.tightenings = 0

    def ratio(self, error: float, h: float) -> float:
        """The step's error over its allowance (per unit step or per step); inf when not finite."""
        if not error < float("inf"):
            return float("inf")
        return error / self.local_tol if self.per_step else error / (self.local_tol * h / self.span)

    def rejected(self, t: float, h: float, ratio: float) -> float | None:
        """After a rejected trial step from ``t``: the next trial step, or None when the stage
        roundings must be made 10x tighter and the same step retried."""
        self.just_rejected = True
        last = self.last_rejection
        if (ratio < float("inf") and last is not None and last[0] == t and h <= self.noise_step * last[1]
                and ratio >= 0.5 * last[2] and self.tightenings < MAX_STAGE_TIGHTENINGS):
            # a shorter step did not lower the estimate, as an error of the method's order would:
            # it is the stage roundings' noise, amplified by a stiff Jacobian (dK = J dY).
            self.tightenings += 1
            self.last_rejection = None
            return None
        self.last_rejection = (t, h, ratio)
        # an overflowed trial step (ratio inf) was far too long for a stiff or fast problem:
        # shrink it as much as allowed (a blow-up shows in the accepted steps, BlowupWatch)
        return h * max(0.2, SAFETY * ratio ** self.exponent)

    def accepted(self, h: float, ratio: float) -> float:
        """After an accepted step of length ``h``: the next trial step (growth capped, since a
        rejected step costs all its stages, and none right after a rejection)."""
        if not self.just_rejected or ratio < 0.5:
            h *= MAX_GROWTH if ratio == 0.0 else min(MAX_GROWTH, max(0.2, SAFETY * ratio ** self.exponent))
        self.just_rejected = False
        return h


def output_times(t: float, h: float, t_new: float, nodes: np.ndarray, last_stored: float,
                 slab_nodes: int | None) -> list[float]:
    """The times inside ``(t, t_new]`` where the state is stored: a slab's Chebyshev-Lobatto
    nodes (the step is the slab, the last node ``t_new``), else the time basis's nodes."""
    if slab_nodes:
        outs = list(t + h * (chebyshev_unit_nodes(slab_nodes)[1:] + 1.0) / 2.0)
        outs[-1] = t_new
        return outs
    return [float(x) for x in nodes if last_stored < x <= t_new]


def step_refusal(steps: int, rejected: int, max_steps: int, h: float, span: float, hint,
                 method: str = "DOP853", order: int = 8, explicit: bool = True) -> str | None:
    """Why a march cannot try another step (the caps), or None; ``hint()`` adds to a step-size underflow,
    ``method`` and ``order`` name the method (``explicit``: held to a stability limit on stiff problems)."""
    if steps + rejected >= max_steps and not explicit:
        return f"max_steps={max_steps} reached (steps of {h:.2g} with {method}: raise solver.max_steps)"
    if steps + rejected >= max_steps:
        # an explicit method on a stiff problem steps at its stability limit, whatever the tolerance:
        # say so when the steps are that small, so the user knows what raising max_steps buys
        if h * max_steps < span and span / h < FEW_STEPS:
            return (f"max_steps={max_steps} reached (steps of {h:.2g}: {span / h:.2g} of them per time domain: "
                    "raise solver.max_steps)")
        if h * max_steps < span and order < LOW_ORDER:
            return (f"max_steps={max_steps} reached (steps of {h:.2g}: {span / h:.2g} of them per time domain; "
                    f"the {method} pair of order {order} needs steps this small for this tolerance, or on a "
                    "stiff problem for its stability: use solver.integrator: dop853, loosen the tolerance or "
                    "raise solver.max_steps)")
        if h * max_steps < span:
            return (f"max_steps={max_steps} reached (steps of {h:.2g}: {span / h:.2g} of them per time domain; "
                    f"steps this small on a smooth solution are the stability limit of the explicit {method} "
                    "on a stiff problem: use solver.integrator: rodas4 or auto, raise solver.max_steps or shorten "
                    "the time domain)")
        return f"max_steps={max_steps} reached (raise solver.max_steps)"
    if h < (MIN_STEP if explicit else STIFF_MIN_STEP) * span:
        return "step size underflow (the solution blows up or is stiff" + hint() + ")"
    return None

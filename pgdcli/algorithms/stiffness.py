"""Stiffness detection: an explicit march held at its stability limit hands over to a stiff stepper.

An explicit pair on a stiff problem takes steps ``h`` with ``h |lambda| ~ its stability limit``
(``lambda`` the Jacobian's eigenvalue of fastest decay), whatever the tolerance: a smooth solution
marched in steps far shorter than its accuracy needs. As LSODA does, the march watches for it:
every :data:`EVERY` accepted steps (from step :data:`FIRST`) :class:`StiffnessWatch` computes the
fastest decay rate of the exact Jacobian at up to 256 nodes (:meth:`ArraySpace.decay_rate
<pgdcli.algorithms.grid_steps.ArraySpace.decay_rate>`); when ``h`` times it has stayed above
:data:`HELD` of the stepper's stability limit (an eighth) for :data:`PATIENCE` checks in a row, with more than
:data:`REMAINING` steps of that length still to go, the march raises :class:`StiffnessDetected` and
:func:`pgdcli.algorithms.march.solve_march` starts it again with the linearly implicit stepper
(``solver.integrator: auto``). So does an explicit step below the march's floor (a transient many
decades shorter than the time domain: :meth:`StiffnessDetected.floor`). A purely oscillatory problem (eigenvalues on the imaginary axis) is
never called stiff: its steps resolve the oscillation.
"""

from __future__ import annotations

__all__ = ["StiffnessDetected", "StiffnessWatch", "FIRST", "EVERY", "HELD", "PATIENCE", "REMAINING"]

#: The first accepted step the watch looks at, and how often it looks after it.
FIRST, EVERY = 40, 10
#: ``h * decay rate`` above this share of the stability limit: the steps are held by the fast mode, not by the
#: solution's own variation. A stiff mode driven by a slow forcing holds DOP853 near ``h * rate = 1``, a sixth
#: of its limit, at the march's tolerances (its error estimate, not instability, stops it there); non-stiff
#: problems stay below a sixteenth (pendulums, Van der Pol, Lotka-Volterra: 0.02 to 0.06 three checks in a
#: row).
HELD = 0.125
#: Checks in a row that must find the steps held.
PATIENCE = 3
#: Steps of the current length still needed to reach the end: fewer are not worth a new march.
REMAINING = 200


class StiffnessDetected(Exception):
    """The explicit march cannot go on at a reasonable cost; ``time`` says where (the message is for the report)."""

    def __init__(self, message: str, time: float):
        super().__init__(message)
        self.time = time

    @classmethod
    def held(cls, method: str, time: float, step: float, rate: float, limit: float, steps: int):
        """Steps held at the stability limit (:class:`StiffnessWatch`)."""
        return cls(f"stiff: from t = {time:.4g} the explicit {method} was held at its stability limit (steps of "
                   f"{step:.2g} after {steps} steps, h x the fastest decay rate {rate:.3g} of the Jacobian = "
                   f"{step * rate:.2g}, its limit {limit:.2g})", time)

    @classmethod
    def capped(cls, method: str, time: float, step: float, max_steps: int, span: float):
        """``max_steps`` spent with steps too short to cross the time domain in as many: the explicit stepper's
        stability limit, or a transient too fast for it."""
        return cls(f"stiff: at t = {time:.4g} the explicit {method} reached max_steps={max_steps} with steps of "
                   f"{step:.2g} ({span / step:.2g} of them per time domain)", time)

    @classmethod
    def floor(cls, method: str, time: float, step: float):
        """Steps below the explicit march's floor: a transient many decades shorter than the time domain."""
        return cls(f"stiff or multiscale: at t = {time:.4g} the explicit {method} needed steps below {step:.2g}, "
                   f"its floor on this time domain", time)


class StiffnessWatch:
    """Called after every accepted step of an explicit stepper whose ``detect_stiffness`` is set.

    Parameters
    ----------
    stepper : Stepper
        Explicit, with its ``stability_limit``.
    t_final : float
    """

    def __init__(self, stepper, t_final: float):
        self.stepper, self.t_final = stepper, t_final
        self.held = 0

    def __call__(self, space, t: float, y, h: float, steps: int) -> None:
        """Raise :class:`StiffnessDetected` when the steps have been held at the stability limit."""
        if steps < FIRST or (steps - FIRST) % EVERY:
            return
        rate = space.decay_rate(t, y)
        limit = self.stepper.stability_limit
        if h * rate > HELD * limit and (self.t_final - t) > REMAINING * h:
            self.held += 1
        else:
            self.held = 0
        if self.held >= PATIENCE:
            raise StiffnessDetected.held(self.stepper.title, t, h, rate, limit, steps)

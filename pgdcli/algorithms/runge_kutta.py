"""Explicit embedded Runge-Kutta pairs as data (:class:`ExplicitRungeKutta`).

A pair is a subclass that sets its coefficients, named as in scipy's ``RungeKutta`` subclasses:
the tableau ``A, B, C``, the embedded error weights ``E``, the dense-output coefficients ``P``,
``order``, ``error_estimator_order`` and ``n_stages``; it is selected by its entry in
:data:`pgdcli.algorithms.steppers.METHODS` and steps any
:class:`~pgdcli.algorithms.stepping.StateSpace`. The state at a time inside a step is a linear
combination of the step's start, its end and its stages (:meth:`ExplicitRungeKutta.dense_weights`),
so a tensor train there is one more rounded sum of trains and a batch of replayed trajectories one
matrix product.
"""

from __future__ import annotations

import numpy as np

from .stepping import StateSpace, Stepper, Trial

__all__ = ["ExplicitRungeKutta"]


class ExplicitRungeKutta(Stepper):
    """An explicit embedded Runge-Kutta pair with FSAL stage and polynomial dense output.

    The default error is ``h ||sum_j E_j K_j||`` per unknown over the ``n_stages + 1`` stages (the
    last is ``f(t + h, y_new)``); the default dense output is scipy's ``RkDenseOutput``,
    ``y(t + x h) = y + h sum_j K_j sum_k P_jk x^(k+1)``. A pair whose error or dense output
    differs (:class:`pgdcli.algorithms.dop853.Dop853`) overrides :meth:`error_weights`,
    :meth:`local_error`, :meth:`dense_stages` and :meth:`dense_weights`.
    """

    A: np.ndarray = NotImplemented  # (n_stages, n_stages)
    B: np.ndarray = NotImplemented  # (n_stages,)
    C: np.ndarray = NotImplemented  # (n_stages,)
    E: np.ndarray = NotImplemented  # (n_stages + 1,)
    P: np.ndarray = NotImplemented  # (n_stages + 1, degree of the dense output)

    def step(self, space: StateSpace, t: float, y, f, h: float, estimate: bool = True) -> Trial:
        n = self.n_stages
        K = space.stages(f, self.slots)
        y_new, norm, local = None, np.inf, None
        try:
            with np.errstate(all="ignore"):  # an overflow is a rejected step, not a warning
                for s in range(1, n):
                    K[s] = space.rhs(t + self.C[s] * h, space.stage(y, K, self.A[s, :s], h))
                y_new = space.state(y, K, self.B, h)
                if not estimate:
                    K[n] = space.rhs(t + h, y_new)
                    return Trial(y_new, K[n], K, None)
                norm = space.norm(y_new)
                if np.isfinite(norm):
                    K[n] = space.rhs(t + h, y_new)
                    local = self.local_errors(space, K, h)
        except np.linalg.LinAlgError:  # a factorization met the non-finite values of an overflow
            return Trial(None, None, K, None)
        return Trial(y_new, K[n] if local is not None else None, K, local, norm)

    def error_weights(self) -> list[np.ndarray]:
        return [self.E]

    def dense_weights(self, x: float, h: float) -> np.ndarray:
        w = np.zeros(2 + self.slots)
        w[0] = 1.0
        powers = np.cumprod(np.full(self.P.shape[1], x))
        w[2:3 + self.n_stages] = h * (self.P @ powers)
        return w

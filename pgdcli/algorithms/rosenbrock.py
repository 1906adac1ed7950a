"""Linearly implicit (Rosenbrock) steppers for stiff problems (``solver.integrator: rodas4``).

A Rosenbrock method replaces the Newton iterations of an implicit Runge-Kutta method by one linear
solve per stage with ``W = 1/(gamma h) I - J``, ``J`` the exact Jacobian of the right-hand side at
the step's start (:meth:`pgdcli.algorithms.stepping.StateSpace.jacobian`). In the form of Hairer &
Wanner's RODAS (Solving ODEs II, IV.7), with ``U_i`` the stage increments (they carry the factor h),

    W U_i = f(t + c_i h, y + sum_j A_ij U_j) + sum_j (C_ij / h) U_j + d_i h df/dt,
    y_new = y + sum_i M_i U_i,      error = sum_i (M_i - M_hat_i) U_i.

:class:`Rosenbrock` is that step on any space with a Jacobian; a method is a subclass with its
coefficients. The stages live in the space's container as ``[f, df/dt, U_1 .. U_s, f(t + h,
y_new)]``, so the new state, the error and the dense output are linear combinations of them, and a
replay on other nodes (:func:`pgdcli.algorithms.grid_steps.replay`) repeats the arithmetic exactly.
"""

from __future__ import annotations

import numpy as np

from .stepping import StateSpace, Stepper, Trial

__all__ = ["Rosenbrock", "Rodas4"]


class Rosenbrock(Stepper):
    """A Rosenbrock method; subclasses set ``gamma``, the stage times ``c``, the time-derivative
    weights ``d``, ``A`` and ``C`` (strictly lower triangular, ``n_stages`` square), ``M``, ``M_hat``.

    Its error is bounded per step (:class:`pgdcli.algorithms.step_control.StepControl`, ``per_step``):
    on a stiff problem the errors of a fast transient are damped by the dynamics instead of adding up
    (the error gate measures the codebook either way).
    """

    requires = ("jacobian",)
    explicit = False
    error_per_step = True
    gamma: float = NotImplemented
    c: np.ndarray = NotImplemented  # (n_stages,)
    d: np.ndarray = NotImplemented  # (n_stages,)
    A: np.ndarray = NotImplemented  # (n_stages, n_stages)
    C: np.ndarray = NotImplemented  # (n_stages, n_stages)
    M: np.ndarray = NotImplemented  # (n_stages,)
    M_hat: np.ndarray = NotImplemented  # (n_stages,)

    @property
    def slots(self) -> int:
        return self.n_stages + 3  # f, df/dt, the increments, f(t + h, y_new)

    @staticmethod
    def over_slots(increments: np.ndarray, first: float = 0.0, time: float = 0.0) -> np.ndarray:
        """Weights over the slots ``[f, df/dt, U_1 ..]`` from weights of the first increments."""
        return np.concatenate([[first, time], increments])

    def step(self, space: StateSpace, t: float, y, f, h: float, estimate: bool = True) -> Trial:
        s = self.n_stages
        K = space.stages(f, self.slots)
        y_new, norm, local = None, np.inf, None
        try:
            with np.errstate(all="ignore"):  # an overflow is a rejected step, not a warning
                jacobian = space.jacobian(t, y)
                K[1] = jacobian.time_derivative
                shift = 1.0 / (self.gamma * h)
                for i in range(s):
                    value = f if i == 0 else space.rhs(t + self.c[i] * h,
                                                       space.stage(y, K, self.over_slots(self.A[i, :i]), 1.0))
                    right = space.stage(value, K, self.over_slots(self.C[i, :i] / h, time=self.d[i] * h), 1.0)
                    K[2 + i] = jacobian.solve(shift, right)
                y_new = space.state(y, K, self.over_slots(self.M), 1.0)
                if not estimate:
                    K[2 + s] = space.rhs(t + h, y_new)
                    return Trial(y_new, K[2 + s], K, None)
                norm = space.norm(y_new)
                if np.isfinite(norm):
                    K[2 + s] = space.rhs(t + h, y_new)
                    local = self.local_errors(space, K, h)
        except np.linalg.LinAlgError:  # W singular: a step too long for this Jacobian
            return Trial(None, None, K, None)
        return Trial(y_new, K[2 + s] if local is not None else None, K, local, norm)

    def error_weights(self) -> list[np.ndarray]:
        return [self.over_slots(self.M - self.M_hat)]

    def local_error(self, h: float, norms: list[np.ndarray]) -> np.ndarray:
        return norms[0]  # the increments carry the factor h


class Rodas4(Rosenbrock):
    """RODAS4 (Hairer & Wanner, Solving ODEs II, IV.7; the coefficients of their ``rodas.f``).

    Order 4, embedded order 3, six stages (five right-hand sides and one Jacobian a step, and
    ``f(t + h, y_new)`` for the next), L-stable. Both the solution and the embedded solution are
    stiffly accurate (their last stage is the solution itself), so the error estimate, the last
    increment ``U_6``, stays reliable on the stiff components without the ``(I - gamma h J)^-1``
    filter that methods with a non-stiffly-accurate embedded formula (ROS3P) need. Its dense output
    is ``rodas.f``'s, of order 3: ``(1 - x) y + x y_new + x (1 - x) (D2 U + x D3 U)``.
    """

    name = "rodas4"
    title = "RODAS4"
    order = 4
    error_estimator_order = 3
    n_stages = 6
    gamma = 0.25
    c = np.array([0.0, 0.386, 0.21, 0.63, 1.0, 1.0])
    d = np.array([0.25, -0.1043, 0.1035, -0.3620000000000023e-01, 0.0, 0.0])
    _a = [[1.544],
          [0.9466785280815826, 0.2557011698983284],
          [3.314825187068521, 2.896124015972201, 0.9986419139977817],
          [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895],
          [1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0]]
    _c = [[-5.6688],
          [-2.430093356833875, -0.2063599157091915],
          [-0.1073529058151375, -9.594562251023355, -20.47028614809616],
          [7.496443313967647, -10.24680431464352, -33.99990352819905, 11.7089089320616],
          [8.083246795921522, -7.981132988064893, -31.52159432874371, 16.31930543123136, -6.058818238834054]]
    A = np.array([row + [0.0] * (6 - len(row)) for row in [[]] + _a])
    C = np.array([row + [0.0] * (6 - len(row)) for row in [[]] + _c])
    M = np.array([1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0, 1.0])
    M_hat = np.array([1.221224509226641, 6.019134481288629, 12.53708332932087, -0.687886036105895, 1.0, 0.0])
    D2 = np.array([10.12623508344586, -7.487995877610167, -34.80091861555747, -7.992771707568823,
                   1.025137723295662, 0.0])
    D3 = np.array([-0.6762803392801253, 6.087714651680015, 16.43084320892478, 24.76722511418386,
                   -6.594389125716872, 0.0])

    def dense_weights(self, x: float, h: float) -> np.ndarray:
        w = np.zeros(2 + self.slots)
        w[0], w[1] = 1.0 - x, x
        w[4:4 + self.n_stages] = x * (1.0 - x) * (self.D2 + x * self.D3)
        return w

"""Bogacki-Shampine 3(2): a low-order explicit pair for loose tolerances (``solver.integrator: bs32``).

P. Bogacki and L. F. Shampine, "A 3(2) pair of Runge-Kutta formulas", Appl. Math. Lett. 2 (1989)
321-325; the pair of scipy's ``RK23``, with its cubic Hermite dense output. Three stages a step
(the fourth, ``f(t + h, y_new)``, is the next step's first) against DOP853's twelve: cheaper per
step, but its steps shrink as ``tolerance^(1/3)``, so it pays off only at loose tolerances.
"""

from __future__ import annotations

import numpy as np

from .runge_kutta import ExplicitRungeKutta

__all__ = ["BogackiShampine32"]


class BogackiShampine32(ExplicitRungeKutta):
    """Bogacki-Shampine 3(2): order 3, embedded order 2, dense output of order 3."""

    name = "bs32"
    title = "Bogacki-Shampine 3(2)"
    order = 3
    error_estimator_order = 2
    n_stages = 3
    stability_limit = 2.5  # where its stability region meets the negative real axis
    C = np.array([0.0, 1 / 2, 3 / 4])
    A = np.array([[0.0, 0.0, 0.0],
                  [1 / 2, 0.0, 0.0],
                  [0.0, 3 / 4, 0.0]])
    B = np.array([2 / 9, 1 / 3, 4 / 9])
    E = np.array([5 / 72, -1 / 12, -1 / 9, 1 / 8])  # third- minus second-order weights
    P = np.array([[1.0, -4 / 3, 5 / 9],
                  [0.0, 1.0, -2 / 3],
                  [0.0, 4 / 3, -8 / 9],
                  [0.0, -1.0, 1.0]])

"""Dormand-Prince 8(5,3): the explicit pair of scipy's ``DOP853``, the march's default.

The coefficients are :class:`scipy.integrate.DOP853`'s. Its error estimate combines two embedded
estimates, of orders 5 and 3, as scipy's ``DOP853._estimate_error_norm`` does (here in the norm
the state space measures); its dense output of order 7 needs three stages more and is scipy's
nested polynomial ``Dop853DenseOutput``, applied to weights instead of states.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import DOP853

from .runge_kutta import ExplicitRungeKutta
from .stepping import StateSpace

__all__ = ["Dop853", "dense_weights"]


def dense_weights(x: float, h: float, D: np.ndarray) -> np.ndarray:
    """DOP853 dense output at ``t_old + x h`` as weights of ``[y_old, y_new, K_0..K_15]``.

    The same nested polynomial as scipy's ``Dop853DenseOutput``, applied to
    coefficient vectors instead of states, so the value is one linear
    combination of tensor trains.
    """
    nk = D.shape[1]
    size = 2 + nk
    y_old, y_new = np.eye(size)[0], np.eye(size)[1]
    K = np.eye(size)[2:]
    delta = y_new - y_old
    F = [delta, h * K[0] - delta, 2 * delta - h * (K[12] + K[0])] + [h * (D[i] @ K) for i in range(D.shape[0])]
    y = np.zeros(size)
    for i, f in enumerate(reversed(F)):
        y = y + f
        y = y * (x if i % 2 == 0 else 1.0 - x)
    return y + y_old


class Dop853(ExplicitRungeKutta):
    """Dormand-Prince 8(5,3) with its order-7 dense output (scipy's ``DOP853``)."""

    name = "dop853"
    title = "DOP853"
    order = DOP853.order
    error_estimator_order = DOP853.error_estimator_order
    n_stages = DOP853.n_stages
    A, B, C = DOP853.A, DOP853.B, DOP853.C
    E3, E5 = DOP853.E3, DOP853.E5
    D, A_EXTRA, C_EXTRA = DOP853.D, DOP853.A_EXTRA, DOP853.C_EXTRA
    extra_stages = len(DOP853.C_EXTRA)
    stability_limit = 6.0  # where its stability region meets the negative real axis (Hairer's dop853.f tests 6.1)

    def error_weights(self) -> list[np.ndarray]:
        return [self.E5, self.E3]

    def local_error(self, h: float, norms: list[np.ndarray]) -> np.ndarray:
        """``h e5^2 / sqrt(e5^2 + 0.01 e3^2)`` per unknown (zero where both vanish)."""
        e5, e3 = norms
        denom = np.sqrt(e5 * e5 + 0.01 * e3 * e3)
        return np.where(denom > 0.0, h * e5 * e5 / np.where(denom > 0.0, denom, 1.0), 0.0)

    def dense_stages(self, space: StateSpace, t: float, h: float, y, K) -> None:
        """The three stages of the dense output, into ``K[13:16]``."""
        with np.errstate(all="ignore"):  # an overflowed node: the caller refuses its values
            for s, (a, c) in enumerate(zip(self.A_EXTRA, self.C_EXTRA), start=self.n_stages + 1):
                K[s] = space.rhs(t + c * h, space.stage(y, K, a[:s], h))

    def dense_weights(self, x: float, h: float) -> np.ndarray:
        return dense_weights(x, h, self.D)

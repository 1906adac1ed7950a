"""The Jacobian of the compiled right-hand side at arrays of parameter nodes (linearly implicit steppers).

At every node ``p`` the state is the m unknowns, and ``J[p] = df/du`` is an m x m matrix, exact:
a monomial ``c u_i1 ... u_ik`` of the polynomial part contributes ``c`` times the product of the
other factors for each of its factors, a general term its expression trees differentiated
symbolically (:meth:`pgdcli.algorithms.general_rhs.GeneralPart.grid_jacobian`,
:func:`pgdcli.problem.derivative.derivative`). :class:`ArrayJacobian` solves ``(shift I - J) x = b``
at all nodes at once: the m x m matrices are inverted once per step (m, the number of unknowns, is a
handful) and every stage's solve is then one batched product.

``df/dt`` (the Rosenbrock steps' time term) is zero for an autonomous system; when a coefficient or
a general term depends on time it is a central difference of the right-hand side in t (the
Jacobian in the unknowns stays exact).
"""

from __future__ import annotations

import numpy as np

__all__ = ["ArrayJacobian", "jacobian_at", "time_derivative", "autonomous", "stiffest_rate"]


class ArrayJacobian:
    """``J`` at the nodes (:class:`pgdcli.algorithms.stepping.Jacobian`), with ``df/dt`` there.

    Parameters
    ----------
    matrices : ndarray, shape (P, m, m)
        ``matrices[p, s, j] = d f_s / d u_j`` at node ``p``.
    time_derivative : ndarray, shape (m, P)
        ``df/dt`` at the nodes (zeros for an autonomous system).
    """

    def __init__(self, matrices: np.ndarray, time_derivative: np.ndarray):
        self.matrices, self.time_derivative = matrices, time_derivative
        self._shift, self._inverse = None, None

    def solve(self, shift: float, b: np.ndarray) -> np.ndarray:
        """``x`` (m, P) with ``(shift I - J) x = b`` at every node (LinAlgError where singular)."""
        if shift != self._shift:
            m = self.matrices.shape[1]
            self._inverse = np.linalg.inv(shift * np.eye(m) - self.matrices)
            self._shift = shift
        return np.einsum("pij,jp->ip", self._inverse, b)


def jacobian_at(rhs, t: float, Y: np.ndarray) -> np.ndarray:
    """``d f / d u`` of a :class:`pgdcli.algorithms.grid_steps.GridRhs` at ``(t, Y)``: shape (P, m, m)."""
    m, nodes = Y.shape
    J = np.zeros((m, m, nodes))
    system = rhs.system
    for s, monomials in enumerate(system.rhs):
        for k, (_, factors) in enumerate(monomials):
            coefficient = rhs.coefficient(s, k, t)
            for position, j in enumerate(factors):
                term = coefficient
                for i in factors[:position] + factors[position + 1:]:
                    term = term * Y[i]
                J[s, j] += term
        part = system.general[s] if system.general else None
        if part is not None:
            if rhs.indices is None:
                slopes = part.grid_jacobian(t, {name: Y[i].reshape(rhs.shape) for name, i in part.needed})
            else:
                slopes = part.point_jacobian(t, rhs.indices, {name: Y[i] for name, i in part.needed})
            for j, values in slopes.items():
                J[s, j] += np.reshape(values, -1)
    return np.ascontiguousarray(J.transpose(2, 0, 1))


def autonomous(rhs) -> bool:
    """Whether ``f`` does not depend on t: no timed coefficient and no general term (which may)."""
    system = rhs.system
    fixed = all((s, k) in rhs.fixed for s, monomials in enumerate(system.rhs) for k in range(len(monomials)))
    return fixed and not any(part is not None for part in (system.general or []))


def time_derivative(rhs, t: float, Y: np.ndarray, span: float) -> np.ndarray:
    """``df/dt`` at ``(t, Y)``: zeros when :func:`autonomous`, else a central difference (relative step
    ``eps^(1/3)`` of the time scale)."""
    if autonomous(rhs):
        return np.zeros_like(Y)
    delta = np.finfo(float).eps ** (1.0 / 3.0) * max(abs(t), span)
    return (rhs(t + delta, Y) - rhs(t - delta, Y)) / (2.0 * delta)


def stiffest_rate(matrices: np.ndarray, nodes: int = 256) -> float:
    """The largest decay rate ``max(-Re lambda)`` of ``J`` over (at most ``nodes`` evenly spread) nodes.

    A large decay rate is what holds an explicit stepper to its stability limit (a purely imaginary
    eigenvalue is an oscillation the stepper must resolve anyway); 0 when no eigenvalue decays.
    """
    step = max(1, len(matrices) // nodes)
    with np.errstate(all="ignore"):
        values = np.linalg.eigvals(matrices[::step])
    rates = -values.real[np.isfinite(values.real)]
    return float(max(rates.max(initial=0.0), 0.0))

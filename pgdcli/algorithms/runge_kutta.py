"""Explicit embedded Runge-Kutta pairs as data, stepped on any kind of state.

A method is a subclass of :class:`ExplicitRungeKutta` that sets its coefficients, named as in
scipy's ``RungeKutta`` subclasses: the tableau ``A, B, C``, the embedded error weights ``E``,
the dense-output coefficients ``P``, ``order``, ``error_estimator_order`` and ``n_stages``; it is
selected by its entry in :data:`pgdcli.algorithms.steppers.METHODS`. A method never touches a
state: every sum ``y + h sum_j a_j K_j``, every right-hand side and every norm goes through the
:class:`StateSpace` it is given. The grid's array of nodal values
(:class:`pgdcli.algorithms.grid_steps.ArraySpace`) and a tensor train per unknown rounded to its
error budget (:class:`pgdcli.algorithms.train_steps.TrainSpace`) are the two spaces; the one
adaptive march over either is :func:`pgdcli.algorithms.march_loop.march_steps`.

The state at a time inside an accepted step (the dense output) is a linear combination of the
step's start ``y``, its end ``y_new`` and its stages ``K``: :meth:`ExplicitRungeKutta.dense_weights`
gives its weights, so a tensor train there is one more rounded sum of trains and a batch of
replayed trajectories one matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

__all__ = ["StateSpace", "Trial", "ExplicitRungeKutta"]


class StateSpace(Protocol):
    """The arithmetic of one kind of state, as a stepper needs it.

    ``K`` is the container of a step's stages (:meth:`stages`); ``y`` a state; weights are 1-D
    arrays over the first stages of ``K``. Implementations round (or not) as their format needs.
    """

    def rhs(self, t: float, y: Any) -> Any:
        """``f(t, y)``."""

    def stages(self, f: Any, slots: int) -> Any:
        """A container of ``slots`` stages, ``f`` in the first (indexable, assignable)."""

    def stage(self, y: Any, K: Any, a: np.ndarray, h: float) -> Any:
        """The stage value ``y + h sum_j a_j K_j``."""

    def state(self, y: Any, K: Any, b: np.ndarray, h: float) -> Any:
        """The step's new state ``y + h sum_j b_j K_j``."""

    def norm(self, y: Any) -> float:
        """A size of the state (inf or nan after an overflow): its growth is watched."""

    def error_norms(self, K: Any, count: int, weights: list[np.ndarray]) -> list[np.ndarray]:
        """Per weight vector ``w``: the norm of ``sum_j w_j K_j`` (``j < count``) of every unknown."""

    def dense(self, y: Any, y_new: Any, K: Any, W: np.ndarray | None, count: int, out: Any = None) -> Any:
        """``count`` states: the rows of ``W`` combine ``[y, y_new, K_0, ...]``, the rest are ``y_new``."""


@dataclass
class Trial:
    """One trial step: the new state, ``f`` there, the stages, the local error and the state's norm."""

    y_new: Any
    f_new: Any  # f(t + h, y_new): the next step's first stage (None when not computed)
    K: Any
    local: np.ndarray | None  # per unknown: the local error estimate; None if not finite or not asked
    norm: float = np.inf

    @property
    def error(self) -> float:
        """The largest unknown's local error (inf when not finite)."""
        return float(np.max(self.local)) if self.local is not None else np.inf


class ExplicitRungeKutta:
    """An explicit embedded Runge-Kutta pair with FSAL stage and polynomial dense output.

    The default error is ``h ||sum_j E_j K_j||`` per unknown over the ``n_stages + 1`` stages (the
    last is ``f(t + h, y_new)``); the default dense output is scipy's ``RkDenseOutput``,
    ``y(t + x h) = y + h sum_j K_j sum_k P_jk x^(k+1)``. A pair whose error or dense output
    differs (:class:`pgdcli.algorithms.dop853.Dop853`) overrides :meth:`error_weights`,
    :meth:`local_error`, :meth:`dense_stages` and :meth:`dense_weights`.
    """

    name: str = NotImplemented  # the key of solver.integrator
    title: str = NotImplemented  # for messages
    order: int = NotImplemented
    error_estimator_order: int = NotImplemented
    n_stages: int = NotImplemented
    A: np.ndarray = NotImplemented  # (n_stages, n_stages)
    B: np.ndarray = NotImplemented  # (n_stages,)
    C: np.ndarray = NotImplemented  # (n_stages,)
    E: np.ndarray = NotImplemented  # (n_stages + 1,)
    P: np.ndarray = NotImplemented  # (n_stages + 1, degree of the dense output)
    extra_stages: int = 0  # stages the dense output adds after the step's (DOP853: 3)

    @property
    def slots(self) -> int:
        """Stages a step holds: the method's, ``f(t + h, y_new)`` and the dense output's."""
        return self.n_stages + 1 + self.extra_stages

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"

    def step(self, space: StateSpace, t: float, y, f, h: float, estimate: bool = True) -> Trial:
        """The trial step of length ``h`` from ``(t, y)``, ``f = f(t, y)``.

        Without ``estimate`` (a replay of accepted steps) no norm or error is computed and
        ``f(t + h, y_new)`` always is.
        """
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
                    local = self._local_errors(space, K, h)
        except np.linalg.LinAlgError:  # a factorization met the non-finite values of an overflow
            return Trial(None, None, K, None)
        return Trial(y_new, K[n] if local is not None else None, K, local, norm)

    def _local_errors(self, space: StateSpace, K, h: float) -> np.ndarray | None:
        norms = space.error_norms(K, self.n_stages + 1, self.error_weights())
        if not all(np.all(np.isfinite(e)) for e in norms):  # stages overflowed: far too long a step
            return None
        local = self.local_error(h, norms)
        return local if np.all(np.isfinite(local)) else None

    def error_weights(self) -> list[np.ndarray]:
        """The weight vectors over ``K_0 .. K_n_stages`` whose norms :meth:`local_error` combines."""
        return [self.E]

    def local_error(self, h: float, norms: list[np.ndarray]) -> np.ndarray:
        """The local error per unknown from the norms of :meth:`error_weights`' combinations."""
        return h * norms[0]

    def dense_stages(self, space: StateSpace, t: float, h: float, y, K) -> None:
        """Stages the dense output needs beyond the step's, into ``K`` (none by default)."""

    def dense_weights(self, x: float, h: float) -> np.ndarray:
        """The state at ``t + x h`` as weights of ``[y, y_new, K_0 .. K_(slots - 1)]``."""
        w = np.zeros(2 + self.slots)
        w[0] = 1.0
        powers = np.cumprod(np.full(self.P.shape[1], x))
        w[2:3 + self.n_stages] = h * (self.P @ powers)
        return w

    def dense_matrix(self, t: float, h: float, times) -> np.ndarray:
        """:meth:`dense_weights` at ``times`` inside the step from ``t``: shape (len(times), 2 + slots)."""
        return np.array([self.dense_weights((tn - t) / h, h) for tn in times]).reshape(-1, 2 + self.slots)

    def dense_output(self, space: StateSpace, t: float, h: float, y, trial: Trial, outs: list[float],
                     t_new: float, out=None, weights: np.ndarray | None = None):
        """The states at the times ``outs`` inside ``(t, t_new]`` of an accepted step.

        ``weights``: the rows of :meth:`dense_matrix` at the ``outs`` before ``t_new`` (a replay
        computes them once); ``out``: where the space writes the states, if it can.
        """
        inside = sum(1 for tn in outs if tn < t_new)
        W = None
        if inside:
            self.dense_stages(space, t, h, y, trial.K)
            W = self.dense_matrix(t, h, outs[:inside]) if weights is None else weights
        return space.dense(y, trial.y_new, trial.K, W, len(outs), out)

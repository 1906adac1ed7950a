"""The interface of the time march's steppers: what a stepper is, and what it needs of a state.

A :class:`Stepper` advances a state by one trial step and says how good the step was (an
embedded error estimate per unknown) and what the state is inside it (a dense output linear in
the step's start ``y``, its end ``y_new`` and its stages ``K``). It never touches a state: every
sum ``y + h sum_j a_j K_j``, every right-hand side and every norm goes through the
:class:`StateSpace` it is given. The grid's array of nodal values
(:class:`pgdcli.algorithms.grid_steps.ArraySpace`) and a tensor train per unknown rounded to its
error budget (:class:`pgdcli.algorithms.train_steps.TrainSpace`) are the two spaces; the one
adaptive march over either is :func:`pgdcli.algorithms.march_loop.march_steps`.

Explicit Runge-Kutta pairs are tableaus (:class:`pgdcli.algorithms.runge_kutta.ExplicitRungeKutta`);
a linearly implicit (Rosenbrock) stepper also solves with ``shift I - J`` (``J`` the Jacobian of the
right-hand side): it names ``"jacobian"`` in :attr:`Stepper.requires`, and a space that provides
:meth:`StateSpace.jacobian` can march it. Every stepper is an entry of
:data:`pgdcli.algorithms.steppers.METHODS`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np

__all__ = ["StateSpace", "Jacobian", "Trial", "Stepper"]


class Jacobian(Protocol):
    """The Jacobian ``J = df/dy`` of the right-hand side at one ``(t, y)``, for linearly implicit steppers."""

    def solve(self, shift: float, b: Any) -> Any:
        """``x`` with ``(shift I - J) x = b`` (``b`` and ``x`` states of the space)."""


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

    # optional, for linearly implicit steppers (Stepper.requires = ("jacobian",)):
    # def jacobian(self, t: float, y: Any) -> Jacobian: ...


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


class Stepper:
    """A one-step method with an embedded error estimate and a dense output linear in its stages.

    Subclasses set the attributes and implement :meth:`step`, :meth:`error_weights` and
    :meth:`dense_weights`; the error of a step is :meth:`local_error` of the norms of
    :meth:`error_weights`' combinations of the step's stages (for an explicit pair ``K_0 ..
    K_n_stages``, the last ``f(t + h, y_new)``, the next step's first).
    """

    name: str = NotImplemented  # the key of solver.integrator
    title: str = NotImplemented  # for messages
    order: int = NotImplemented
    error_estimator_order: int = NotImplemented  # p: the local error is O(h^(p+1))
    n_stages: int = NotImplemented
    extra_stages: int = 0  # stages the dense output adds after the step's (DOP853: 3)
    requires: tuple[str, ...] = ()  # optional StateSpace methods the stepper calls ("jacobian")
    explicit: bool = True  # held to a stability limit on stiff problems (the march watches for it)
    error_per_step: bool = False  # bound the error per step, not per unit step (StepControl)
    stability_limit: float = 0.0  # explicit: the stable h |lambda| on the negative real axis
    detect_stiffness: bool = False  # solver.integrator: auto (pgdcli.algorithms.stiffness)

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
        raise NotImplementedError

    def local_errors(self, space: StateSpace, K, h: float) -> np.ndarray | None:
        """The local error per unknown, None when not finite (stages that overflowed)."""
        weights = self.error_weights()
        norms = space.error_norms(K, len(weights[0]), weights)
        if not all(np.all(np.isfinite(e)) for e in norms):
            return None
        local = self.local_error(h, norms)
        return local if np.all(np.isfinite(local)) else None

    def error_weights(self) -> list[np.ndarray]:
        """The weight vectors over the first slots of ``K`` whose norms :meth:`local_error` combines."""
        raise NotImplementedError

    def local_error(self, h: float, norms: list[np.ndarray]) -> np.ndarray:
        """The local error per unknown from the norms of :meth:`error_weights`' combinations."""
        return h * norms[0]

    def dense_stages(self, space: StateSpace, t: float, h: float, y, K) -> None:
        """Stages the dense output needs beyond the step's, into ``K`` (none by default)."""

    def dense_weights(self, x: float, h: float) -> np.ndarray:
        """The state at ``t + x h`` as weights of ``[y, y_new, K_0 .. K_(slots - 1)]``."""
        raise NotImplementedError

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

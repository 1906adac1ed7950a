"""Arrays of parameter nodes as the march's state: the adaptive march and its replay on other nodes.

The state is the array ``Y`` of shape (unknowns, P) of the unknowns at P parameter nodes: every
node of the grid (:mod:`pgdcli.algorithms.grid_march`) or a batch of chosen multi-indices
(:mod:`pgdcli.algorithms.cross_march`). :func:`advance` marches it with a stepper
(:data:`pgdcli.algorithms.steppers.METHODS`) and the train march's step control (the embedded
estimate of each unknown in the root-mean-square norm over the nodes may be
``LOCAL_FRACTION * tolerance * h / span``) and hands the values at the time nodes to a ``keep``
callable; it returns the :class:`~pgdcli.algorithms.march_loop.Schedule` of its accepted steps.
:func:`replay` marches other nodes with that schedule, step for step (no step control): on nodes
drawn from the same grid it computes what :func:`advance` would have computed there.
"""

from __future__ import annotations

import numpy as np

from ..tensors.cross import tt_point_function, tt_values_at
from .jacobian import ArrayJacobian, autonomous, jacobian_at, stiffest_rate, time_derivative
from .march_loop import Schedule, march_steps
from .polynomial_rhs import NonlinearSystem
from .stepping import Stepper, Trial
from .step_control import LOCAL_FRACTION
from .switch_location import SwitchLocator, past_switch
from .steppers import stepper as named_stepper

__all__ = ["GridRhs", "NodeFunctions", "GridMarchFailure", "ArraySpace", "Schedule", "advance", "replay",
           "replay_batch", "initial_values"]


class GridMarchFailure(Exception):
    """The march on arrays stopped (blow-up, step-size underflow, max_steps); ``time``, ``values`` (m, P),
    ``indices`` (P, d: the nodes' multi-indices; None for the whole grid) and ``blowup_time`` say where."""

    def __init__(self, message: str, time: float, values: np.ndarray, blowup_time: float | None = None,
                 indices: np.ndarray | None = None):
        super().__init__(message)
        self.time, self.values, self.blowup_time, self.indices = time, values, blowup_time, indices


def _timed(coef) -> bool:
    """Whether a coefficient of the compiled system depends on time."""
    return any(f is not None for f in coef.time_funcs) or any(
        j.time_func is not None or j.train.timed for j in coef.joints)


def _constant(train) -> float | None:
    """The value of a rank-one train with constant cores (a constant coefficient), else None."""
    if all(r == 1 for r in train.ranks) and all(np.all(c == c.flat[0]) for c in train.cores):
        return float(np.prod([c.flat[0] for c in train.cores]))
    return None


class NodeFunctions:
    """A system's time-free coefficients and initial values as functions of node multi-indices, built once
    for the many batches of a cross (:func:`pgdcli.tensors.cross.tt_point_function`; a constant as a float).
    """

    def __init__(self, system: NonlinearSystem):
        self.system = system
        self.coefficients: dict = {}
        for s, monomials in enumerate(system.rhs):
            for m, (coef, _) in enumerate(monomials):
                if not _timed(coef):
                    train = coef.at(0.0)
                    value = _constant(train)
                    self.coefficients[s, m] = tt_point_function(train) if value is None else value
        self.initial = [tt_point_function(u) for u in system.initial]


class GridRhs:
    """``f_s(t, p, u)`` on arrays: ``Y`` of shape (unknowns, P) -> same shape.

    Parameters
    ----------
    system : NonlinearSystem
    indices : ndarray of int, shape (P, d), optional
        The parameter multi-indices of the P nodes; None: the whole grid (C order).
    functions : NodeFunctions, optional
        The system's coefficients as functions of the indices (built here when not given).

    Coefficients that do not depend on time are evaluated at the nodes once.
    """

    def __init__(self, system: NonlinearSystem, indices: np.ndarray | None = None,
                 functions: NodeFunctions | None = None):
        self.system, self.indices = system, indices
        self.stats: dict = {}
        self.shape = system.shape
        self.fixed: dict = {}
        if indices is not None:
            functions = functions or NodeFunctions(system)
            for key, value in functions.coefficients.items():
                self.fixed[key] = value if isinstance(value, float) else _one_value(value(indices))
            return
        for s, monomials in enumerate(system.rhs):
            for m, (coef, _) in enumerate(monomials):
                if not _timed(coef):
                    self.fixed[s, m] = self._at_nodes(coef.at(0.0))

    def _at_nodes(self, train) -> np.ndarray | float:
        """The train's values at the nodes; one float when they are all equal (a constant coefficient)."""
        value = _constant(train)
        if value is not None:
            return value
        return _one_value(train.full().reshape(-1) if self.indices is None else tt_values_at(train, self.indices))

    def coefficient(self, s: int, m: int, t: float) -> np.ndarray | float:
        """The coefficient of monomial ``m`` of equation ``s`` at the nodes at time ``t``."""
        term = self.fixed.get((s, m))
        return self._at_nodes(self.system.rhs[s][m][0].at(t)) if term is None else term

    def __call__(self, t: float, Y: np.ndarray) -> np.ndarray:
        out = np.zeros_like(Y)
        for s, monomials in enumerate(self.system.rhs):
            for m, (coef, factors) in enumerate(monomials):
                term = self.fixed.get((s, m))
                if term is None:
                    term = self._at_nodes(coef.at(t))
                if factors:
                    term = term * Y[factors[0]]
                    for i in factors[1:]:
                        term *= Y[i]
                out[s] += term
            part = self.system.general[s] if self.system.general else None
            if part is not None:
                if self.indices is None:
                    arrays = {name: Y[i].reshape(self.shape) for name, i in part.needed}
                    values = part.grid_values(t, arrays).reshape(-1)
                else:
                    values = part.point_values(t, self.indices, {name: Y[i] for name, i in part.needed})
                if not np.all(np.isfinite(values)) and np.all(np.isfinite(Y)):  # sqrt(-1), 1/0: for the message
                    self.stats["cross_nonfinite"] = self.stats.get("cross_nonfinite", 0) + 1
                out[s] += values
        return out


def _one_value(values: np.ndarray) -> np.ndarray | float:
    """The values, or one float when they are all equal."""
    if values.size and np.all(values == values[0]):
        return float(values[0])
    return values


def initial_values(system: NonlinearSystem, indices: np.ndarray | None = None,
                   functions: NodeFunctions | None = None) -> np.ndarray:
    """The initial state (unknowns, P) at the nodes (None: the whole grid)."""
    if indices is None:
        return np.stack([u.full().reshape(-1) for u in system.initial])
    if functions is not None:
        return np.stack([f(indices) for f in functions.initial])
    return np.stack([tt_values_at(u, indices) for u in system.initial])


class ArraySpace:
    """The array (unknowns, P) of nodal values as the state of a stepper
    (:class:`pgdcli.algorithms.stepping.StateSpace`), in one buffer ``[y, y_new, K_0 ...]``.

    Nothing is rounded. The buffer holds the state between steps (``buffer[0]``), every trial's new
    state (``buffer[1]``, written by :meth:`state`) and the stages, so the dense output at a step's
    nodes is one matrix product. Norms are maxima of absolute values; error norms root-mean-squares
    over the nodes.
    """

    failure = GridMarchFailure
    kind = "the grid's array of nodal values"

    def __init__(self, rhs: GridRhs, y: np.ndarray, slots: int, locate: bool = True):
        self.rhs, self.system, self.stats = rhs, rhs.system, rhs.stats
        nodes = self.system.time_basis.nodes
        self.span = float(nodes[-1] - nodes[0])
        self.buffer = np.empty((2 + slots,) + y.shape)
        self.buffer[0] = y
        system, self.locate = rhs.system, locate  # a replay takes the steps it is given: it locates none
        self.locator = None
        if system.switches:
            self.locator = SwitchLocator(system.switches, system.params,
                                         {p: system.bases[p].nodes for p in system.params}, rhs.indices,
                                         system.time, self.span, len(system.unknowns))

    def switch_cut(self, t: float, h: float) -> float | None:
        """Where a step from t of length h must end, just before a switch at some node (None: at t + h)."""
        return self.locator.cut(t, h) if self.locate and self.locator is not None else None

    def past_switch(self, t: float, y: np.ndarray, f: np.ndarray) -> np.ndarray:
        """The right-hand side at the start of the step after a switch."""
        return past_switch(self.rhs, t, y, f, self.span)

    def start(self, y: np.ndarray) -> np.ndarray:
        return self.buffer[0]

    def stages(self, f: np.ndarray, slots: int) -> np.ndarray:
        K = self.buffer[2:]
        K[0] = f
        return K

    def stage(self, y: np.ndarray, K: np.ndarray, a: np.ndarray, h: float) -> np.ndarray:
        return y + h * _combination(a, K)

    def state(self, y: np.ndarray, K: np.ndarray, b: np.ndarray, h: float) -> np.ndarray:
        return np.add(y, h * _combination(b, K), out=self.buffer[1])

    def norm(self, y: np.ndarray) -> float:
        return float(np.max(np.abs(y)))

    largest = norm

    def error_norms(self, K: np.ndarray, count: int, weights: list[np.ndarray]) -> list[np.ndarray]:
        return [np.sqrt(np.mean(np.tensordot(w, K[:count], axes=1) ** 2, axis=1)) for w in weights]

    def dense(self, y: np.ndarray, y_new: np.ndarray, K: np.ndarray, W: np.ndarray | None, count: int,
              out: np.ndarray | None = None) -> np.ndarray:
        """All rows of ``W`` in one product with the buffer (``y_new`` is ``buffer[1]``, :meth:`state`)."""
        out = np.empty((count,) + y.shape) if out is None else out
        inside = 0 if W is None else len(W)
        if inside:
            with np.errstate(all="ignore"):  # an overflowed node: the caller refuses its values
                np.matmul(W, self.buffer.reshape(len(self.buffer), -1), out=out[:inside].reshape(inside, -1))
        out[inside:] = y_new
        return out

    def accept(self, trial: Trial, copy: bool = True) -> tuple[np.ndarray, np.ndarray]:
        """The accepted state, into ``buffer[0]``, and ``f`` there (a copy: a rejected trial overwrites
        the stages before the next one reads it; a replay rejects none)."""
        self.buffer[0] = trial.y_new
        return self.buffer[0], trial.f_new.copy() if copy else trial.f_new

    def jacobian(self, t: float, y: np.ndarray) -> ArrayJacobian:
        """``df/du`` (exact) and ``df/dt`` at the nodes, for linearly implicit steppers."""
        if self.locator is None or autonomous(self.rhs):
            return ArrayJacobian(jacobian_at(self.rhs, t, y), time_derivative(self.rhs, t, y, self.span))
        return ArrayJacobian(jacobian_at(self.rhs, t, y), self.locator.time_derivative(self.rhs, t, y))

    def decay_rate(self, t: float, y: np.ndarray) -> float:
        """The fastest decay rate of the exact Jacobian at (up to 256 of) the nodes (stiffness detection)."""
        return stiffest_rate(jacobian_at(self.rhs, t, y))

    def rounding(self, h: float) -> float:
        return 0.0

    def after_stage_noise(self, h: float) -> float:
        """No roundings to tighten: halve the step."""
        return 0.5 * h

    def check(self, trial: Trial, t: float, y: np.ndarray) -> None:
        pass

    def ranks(self, y: np.ndarray) -> list:
        return []


def _combination(weights: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``sum_s weights[s] K[s]`` for stages K of shape (s, unknowns, P): one matrix-vector product."""
    return (weights @ K[:len(weights)].reshape(len(weights), -1)).reshape(K.shape[1:])


def advance(system: NonlinearSystem, rhs: GridRhs, y: np.ndarray, tolerance: float, keep, *,
            max_steps: int = 20000, callback=None, slab_nodes: int | None = None,
            stepper: Stepper | None = None) -> Schedule:
    """March ``y`` (unknowns, P) to the end of the time domain with a stepper and step control.

    Parameters
    ----------
    system : NonlinearSystem
    rhs : GridRhs
    y : ndarray, shape (unknowns, P)
        The initial state at the nodes.
    tolerance : float
        Root-mean-square over the nodes, per unknown, of the local errors added up over the march.
    keep : callable
        ``keep(list of ndarray (unknowns, P))``: the state at the stored times, in order (the initial
        state first).
    max_steps : int
    callback : callable, optional
        After every accepted step: a :class:`~pgdcli.progress.MarchStep` (ranks empty).
    slab_nodes : int, optional
        Automatic slabs (see :func:`pgdcli.algorithms.march.march`).
    stepper : Stepper, optional
        Default DOP853.

    Raises
    ------
    GridMarchFailure
    """
    stepper = stepper or named_stepper()
    return march_steps(ArraySpace(rhs, y, stepper.slots), stepper, y, system.time_basis.nodes,
                       LOCAL_FRACTION * tolerance, keep, max_steps=max_steps, callback=callback,
                       slab_nodes=slab_nodes)


def replay(rhs: GridRhs, y: np.ndarray, schedule: Schedule) -> np.ndarray:
    """March ``y`` (unknowns, P) with the accepted steps of ``schedule``: the stored states.

    The same arithmetic as :func:`advance`, whose dense output at a step's nodes is one matrix
    product written into the result.

    Returns
    -------
    ndarray, shape (stored times, unknowns, P)
        Non-finite where a node's march overflowed (the caller refuses it).
    """
    stepper = schedule.stepper
    out = np.empty((len(schedule.times),) + y.shape)
    out[0] = y
    space = ArraySpace(rhs, y, stepper.slots, locate=False)
    f = rhs(schedule.times[0], y)
    y = space.start(y)
    j = 1
    for k, (t, h, t_new, outs) in enumerate(schedule.steps):
        trial = stepper.step(space, t, y, f, h, estimate=False)
        stepper.dense_output(space, t, h, y, trial, outs, t_new, out=out[j:j + len(outs)],
                             weights=schedule.output_weights(k))
        j += len(outs)
        y, f = space.accept(trial, copy=False)  # the next trial copies f into its first stage first
        if k in schedule.switched:  # as the march: the next step starts past the switch it ended at
            f = space.past_switch(t_new, y, f)
    return out


def replay_batch(schedule: Schedule, functions: NodeFunctions, indices: np.ndarray) -> np.ndarray:
    """The stored states (times, unknowns, P) at the grid multi-indices ``indices`` (P, d), marched with
    the steps of ``schedule``: a function of its arguments only, to be mapped over batches of nodes."""
    system = functions.system
    return replay(GridRhs(system, indices, functions), initial_values(system, indices, functions), schedule)

"""DOP853 on arrays of parameter nodes: the adaptive march and its replay on other nodes.

The state is the array ``Y`` of shape (unknowns, P) of the unknowns at P parameter nodes: every
node of the grid (:mod:`pgdcli.algorithms.grid_march`) or a batch of chosen multi-indices
(:mod:`pgdcli.algorithms.cross_march`). :func:`advance` marches it with scipy's DOP853 pair and
the train march's step control (the embedded estimate of each unknown in the root-mean-square
norm over the nodes may be ``LOCAL_FRACTION * tolerance * h / span``) and hands the values at the
time nodes to a ``keep`` callable; it returns the :class:`Schedule` of its accepted steps.
:func:`replay` marches other nodes with that schedule, step for step (no step control): on nodes
drawn from the same grid it computes what :func:`advance` would have computed there.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.integrate import DOP853

from ..progress import MarchStep, emit
from ..tensors.cross import tt_point_function, tt_values_at
from .blowup import BlowupWatch
from .dop853_stepper import dense_weights
from .general_rhs import underflow_hint
from .polynomial_rhs import NonlinearSystem
from .step_control import LOCAL_FRACTION, MAX_GROWTH_OF_NORM, StepControl, output_times, step_refusal

__all__ = ["GridRhs", "NodeFunctions", "GridMarchFailure", "Schedule", "advance", "replay", "initial_values", "trial_step",
           "dense_values", "extra_stages"]


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


@dataclass
class Schedule:
    """The accepted steps of :func:`advance`: ``(t, h, t_new, outs)`` each (``outs``: the stored times in
    ``(t, t_new]``), and what the march did."""

    steps: list = field(default_factory=list)
    times: list = field(default_factory=list)  # every stored time, the initial one first
    rejected: int = 0
    local_sum: np.ndarray | None = None  # per unknown: the accepted local error estimates added up
    weights: dict = field(default_factory=dict, repr=False)  # step -> its dense-output weights (replays)

    @property
    def step_sizes(self) -> list[float]:
        return [h for _, h, _, _ in self.steps]

    def output_weights(self, k: int) -> np.ndarray:
        """The dense-output weights (nodes strictly inside, 18) of step ``k``, computed once for all replays."""
        if k not in self.weights:
            t, h, t_new, outs = self.steps[k]
            self.weights[k] = _output_weights(t, h, t_new, outs)
        return self.weights[k]

    def breakpoints(self) -> np.ndarray:
        """The start and the end of every step: the slabs' breakpoints (automatic slabs)."""
        return np.array([self.times[0]] + [t_new for _, _, t_new, _ in self.steps])


def advance(system: NonlinearSystem, rhs: GridRhs, y: np.ndarray, tolerance: float, keep, *,
            max_steps: int = 20000, callback=None, slab_nodes: int | None = None, largest=None) -> Schedule:
    """March ``y`` (unknowns, P) to the end of the time domain with DOP853 and step control.

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
    largest : callable, optional
        ``largest(y) -> float``, the blow-up watch's measure of the state (default max abs).

    Raises
    ------
    GridMarchFailure
    """
    nodes = system.time_basis.nodes
    t, t_final = float(nodes[0]), float(nodes[-1])
    span = t_final - t
    scale0 = max(1.0, float(np.max(np.abs(y))))
    control = StepControl(span, LOCAL_FRACTION * tolerance)
    stats = rhs.stats  # "cross_nonfinite": right-hand sides not finite at finite stage values (underflow_hint)
    f = rhs(t, y)
    keep([y])
    schedule = Schedule(times=[t], local_sum=np.zeros(len(y)))
    h = 0.1 * span
    watch = BlowupWatch(system, y, t_final, largest=largest or _largest)
    buffer = _step_buffer(y)  # [y, y_new, K_0 .. K_15]
    y = buffer[0]
    while t < t_final:
        h = min(h, t_final - t)
        refusal = step_refusal(len(schedule.steps), schedule.rejected, max_steps, h, span,
                               lambda: underflow_hint(system.general, stats))
        if refusal:
            raise GridMarchFailure(refusal, t, y)
        y_new, K, local = trial_step(rhs, t, y, f, h, stages=buffer[2:])
        error = float(np.max(local)) if local is not None else np.inf
        ratio = control.ratio(error, h)
        if ratio > 1.0:
            schedule.rejected += 1
            # None means stage-rounding noise in the train march; without roundings, halve the step
            h = control.rejected(t, h, ratio) or 0.5 * h
            continue
        if float(np.max(np.abs(y_new))) > MAX_GROWTH_OF_NORM * scale0:
            raise GridMarchFailure("the solution blows up", t, y)
        t_new = t_final if abs(t + h - t_final) <= 1e-14 * max(1.0, abs(t_final)) else t + h
        outs = output_times(t, h, t_new, nodes, schedule.times[-1], slab_nodes)
        buffer[1] = y_new
        keep(list(dense_values(rhs, t, h, buffer, outs, t_new)))
        schedule.times.extend(outs)
        schedule.steps.append((t, h, t_new, outs))
        schedule.local_sum += local
        y[:] = y_new  # buffer[0]
        t, f = t_new, K[DOP853.n_stages].copy()  # a copy: a rejected trial overwrites the stages
        h = control.accepted(h, ratio)
        emit(callback, MarchStep(t, t_final, len(schedule.steps), [], float(nodes[0])))
        if t < t_final:
            blowup = watch(t, schedule.step_sizes, y)
            if blowup is not None:
                raise GridMarchFailure("the solution blows up", t, y, blowup)
    return schedule


def replay(rhs: GridRhs, y: np.ndarray, schedule: Schedule) -> np.ndarray:
    """March ``y`` (unknowns, P) with the accepted steps of ``schedule``: the stored states.

    The same arithmetic as :func:`advance`, in one buffer ``[y, y_new, K_0 .. K_15]`` whose dense output
    at a step's nodes is one matrix product written into the result.

    Returns
    -------
    ndarray, shape (stored times, unknowns, P)
        Non-finite where a node's march overflowed (the caller refuses it).
    """
    out = np.empty((len(schedule.times),) + y.shape)
    out[0] = y
    buffer = _step_buffer(y)
    stages = buffer[2:]
    f = rhs(schedule.times[0], y)
    j = 1
    for k, (t, h, t_new, outs) in enumerate(schedule.steps):
        buffer[1], _, _ = trial_step(rhs, t, buffer[0], f, h, estimate=False, stages=stages)
        dense_values(rhs, t, h, buffer, outs, t_new, out=out[j:j + len(outs)], weights=schedule.output_weights(k))
        j += len(outs)
        buffer[0] = buffer[1]
        f = stages[DOP853.n_stages]  # the next trial copies it into its first stage before overwriting it
    return out


def _step_buffer(y: np.ndarray) -> np.ndarray:
    """``[y, y_new, K_0 .. K_15]`` for states like ``y`` (unknowns, P), ``y`` in the first row."""
    buffer = np.empty((2 + DOP853.n_stages + 1 + len(DOP853.C_EXTRA),) + y.shape)
    buffer[0] = y
    return buffer


def _largest(y: np.ndarray) -> float:
    return float(np.max(np.abs(y)))


def _combination(weights: np.ndarray, K: np.ndarray) -> np.ndarray:
    """``sum_s weights[s] K[s]`` for stages K of shape (s, unknowns, P): one matrix-vector product."""
    return (weights @ K[:len(weights)].reshape(len(weights), -1)).reshape(K.shape[1:])


def trial_step(rhs: GridRhs, t: float, y: np.ndarray, f: np.ndarray, h: float, estimate: bool = True,
               stages: np.ndarray | None = None):
    """One DOP853 trial step: ``(y_new, K, local)``; K holds the 12 stages and f(t + h, y_new), local
    the elementwise error estimate (None after a non-finite value, or when ``estimate`` is False).
    ``stages``: an array of shape (16, unknowns, P) to hold K (else a new one)."""
    A, B, C, E3, E5, n = DOP853.A, DOP853.B, DOP853.C, DOP853.E3, DOP853.E5, DOP853.n_stages
    K = np.empty((n + 1 + len(DOP853.C_EXTRA),) + y.shape) if stages is None else stages
    K[0] = f
    with np.errstate(all="ignore"):
        for s in range(1, n):
            K[s] = rhs(t + C[s] * h, y + h * _combination(A[s, :s], K))
        y_new = y + h * _combination(B, K)
        K[n] = rhs(t + h, y_new)  # the next step's first stage, and the dense output's
        if not estimate or not np.all(np.isfinite(y_new)):
            return y_new, K, None
        # scipy's DOP853 estimate per unknown from the root-mean-square over the nodes (the train march's norm)
        e5 = np.sqrt(np.mean(np.tensordot(E5, K[:n + 1], axes=1) ** 2, axis=1))
        e3 = np.sqrt(np.mean(np.tensordot(E3, K[:n + 1], axes=1) ** 2, axis=1))
        if not (np.all(np.isfinite(e5)) and np.all(np.isfinite(e3))):  # stages overflowed: far too long a step
            return y_new, K, None
        denom = np.sqrt(e5 * e5 + 0.01 * e3 * e3)
        local = np.where(denom > 0.0, h * e5 * e5 / np.where(denom > 0.0, denom, 1.0), 0.0)
    return y_new, K, local if np.all(np.isfinite(local)) else None


def dense_values(rhs: GridRhs, t: float, h: float, buffer: np.ndarray, outs: list[float], t_new: float,
                 out: np.ndarray | None = None, weights: np.ndarray | None = None) -> np.ndarray:
    """The states at the times ``outs`` inside ``(t, t_new]``: scipy's order-7 dense output of DOP853.

    Parameters
    ----------
    buffer : ndarray, shape (18, unknowns, P)
        ``[y, y_new, K_0 .. K_15]`` after a step (three extra stages are computed into it when a node lies
        strictly inside the step).
    out : ndarray, shape (len(outs), unknowns, P), optional
        Where to write them (else a new array).
    weights : ndarray, optional
        The step's dense-output weights (:meth:`Schedule.output_weights`), else computed here.
    """
    out = np.empty((len(outs),) + buffer.shape[1:]) if out is None else out
    inside = sum(1 for tn in outs if tn < t_new)
    if inside:  # all the step's nodes in one product: weights (nodes, 18) of [y, y_new, K_0 .. K_15]
        extra_stages(rhs, t, h, buffer[0], buffer[2:])
        w = _output_weights(t, h, t_new, outs) if weights is None else weights
        with np.errstate(all="ignore"):  # an overflowed node: the caller refuses its values
            np.matmul(w, buffer.reshape(len(buffer), -1), out=out[:inside].reshape(inside, -1))
    out[inside:] = buffer[1]
    return out


def _output_weights(t: float, h: float, t_new: float, outs: list[float]) -> np.ndarray:
    """Weights (nodes strictly inside the step, 18) of ``[y, y_new, K_0 .. K_15]`` at those nodes."""
    return np.array([dense_weights((tn - t) / h, h, DOP853.D) for tn in outs if tn < t_new]).reshape(-1, 18)


def extra_stages(rhs: GridRhs, t: float, h: float, y: np.ndarray, K: np.ndarray) -> None:
    """The three stages of DOP853's dense output, into ``K[13:16]`` (after a step's 13)."""
    with np.errstate(all="ignore"):
        for s, (a, c) in enumerate(zip(DOP853.A_EXTRA, DOP853.C_EXTRA), start=DOP853.n_stages + 1):
            K[s] = rhs(t + c * h, y + h * _combination(a[:s], K))

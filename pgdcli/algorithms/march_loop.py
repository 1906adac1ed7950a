"""The adaptive time march: one loop for every stepper and every kind of state.

:func:`march_steps` advances a state from the first to the last time node with a stepper
(:data:`pgdcli.algorithms.steppers.METHODS`) and the step control of
:mod:`pgdcli.algorithms.step_control`, and hands the state at every stored time to a ``store``
callable; the state lives in a space (:class:`pgdcli.algorithms.stepping.StateSpace`) that
also provides what a march needs beyond a step:

- ``system``, ``stats``: the compiled system and the counters its right-hand sides keep;
- ``failure``: the exception class a stopped march raises, as ``failure(message, t, y, blowup)``;
- ``start(y)``, ``accept(trial) -> (y, f)``: where the state is kept between steps;
- ``rounding(h)``: the rounding error a step of length ``h`` adds (0 for exact arithmetic);
- ``after_stage_noise(h) -> h``: what to do when the error estimate is the stages' noise;
- ``check(trial, t, y)``: refuse an accepted step (a rank cap);
- ``largest(y)``: the largest nodal value (the blow-up watch), ``ranks(y)``: for progress;
- ``kind``: what the state is, for messages;
- optionally ``jacobian(t, y)`` (linearly implicit steppers) and ``decay_rate(t, y)`` (stiffness
  detection, :mod:`pgdcli.algorithms.stiffness`).

The grid's array (:class:`pgdcli.algorithms.grid_steps.ArraySpace`) and the tensor trains
(:class:`pgdcli.algorithms.train_steps.TrainSpace`) are the two spaces. The returned
:class:`Schedule` of accepted steps lets other nodes be marched with the same steps
(:func:`pgdcli.algorithms.grid_steps.replay`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SolverError
from ..progress import MarchStep, emit
from .blowup import BlowupWatch
from .general_rhs import switching_terms, underflow_hint
from .stepping import Stepper
from .stiffness import StiffnessDetected, StiffnessWatch
from .step_control import MAX_GROWTH_OF_NORM, MIN_STEP, StepControl, output_times, step_refusal

__all__ = ["Schedule", "march_steps", "FLOOR_GROWTH"]

#: ``solver.integrator: auto`` takes an explicit step below the floor for a stiff or multiscale problem
#: (and marches again with the stiff stepper) only while the state is at most this many times its initial size.
FLOOR_GROWTH = 2.0


@dataclass
class Schedule:
    """The accepted steps of a march: ``(t, h, t_new, outs)`` each (``outs``: the stored times in
    ``(t, t_new]``), the stepper that took them, and what the march did."""

    stepper: Stepper
    steps: list = field(default_factory=list)
    times: list = field(default_factory=list)  # every stored time, the initial one first
    rejected: int = 0
    local_sum: np.ndarray | None = None  # per unknown: the accepted local error estimates added up
    estimate: float = 0.0  # per step, the largest unknown's local error and the state's rounding, added up (max: per-step control)
    step_sizes: list = field(default_factory=list)
    weights: dict = field(default_factory=dict, repr=False)  # step -> its dense-output weights (replays)
    switched: set = field(default_factory=set)  # steps that ended at a switch: f is taken past it (replays)

    def output_weights(self, k: int) -> np.ndarray:
        """The dense-output weights (nodes strictly inside, 2 + slots) of step ``k``, computed once."""
        if k not in self.weights:
            t, h, t_new, outs = self.steps[k]
            self.weights[k] = self.stepper.dense_matrix(t, h, [tn for tn in outs if tn < t_new])
        return self.weights[k]

    def breakpoints(self) -> np.ndarray:
        """The start and the end of every step: the slabs' breakpoints (automatic slabs)."""
        return np.array([self.times[0]] + [t_new for _, _, t_new, _ in self.steps])


def march_steps(space, stepper: Stepper, y, nodes: np.ndarray, local_tol: float, store, *,
                max_steps: int = 20000, callback=None, slab_nodes: int | None = None) -> Schedule:
    """March ``y`` from ``nodes[0]`` to ``nodes[-1]`` with ``stepper`` and step control.

    Parameters
    ----------
    space : StateSpace
        The state's arithmetic and what the march needs of it (module docstring).
    stepper : Stepper
    y : state
        The initial state.
    nodes : ndarray
        The time basis's nodes: the domain, and the stored times without ``slab_nodes``.
    local_tol : float
        The space's norm of the local errors added up over the march (per unknown).
    store : callable
        ``store(list of states)``: the states at the stored times, in order (the initial one first).
    max_steps : int
    callback : callable, optional
        After every accepted step: a :class:`~pgdcli.progress.MarchStep` (ranks from ``space.ranks``).
    slab_nodes : int, optional
        Automatic slabs: every accepted step is a slab and the state is stored at its
        ``slab_nodes`` Chebyshev-Lobatto nodes; without it, at the time nodes.

    Raises
    ------
    space.failure
        Blow-up, step-size underflow, ``max_steps``, or what ``space.check`` refuses.
    SolverError
        The stepper needs what the space does not provide (``Stepper.requires``).
    StiffnessDetected
        An explicit stepper with ``detect_stiffness`` was held at its stability limit.
    """
    _check_requires(space, stepper)
    t, t_final = float(nodes[0]), float(nodes[-1])
    span = t_final - t
    control = StepControl(span, local_tol, stepper.error_estimator_order, stepper.error_per_step)
    stiffness = StiffnessWatch(stepper, t_final) if stepper.detect_stiffness and hasattr(space, "decay_rate") else None
    scale0 = max(1.0, space.norm(y))
    f = space.rhs(t, y)
    store([y])
    y = space.start(y)  # where the space keeps the state between steps (after the store: it may be overwritten)
    schedule = Schedule(stepper, times=[t], local_sum=np.zeros(len(y)))
    h, resume = 0.1 * span, None
    watch = BlowupWatch(space.system, y, t_final, largest=space.largest)
    while t < t_final:
        # the last step takes what is left, also a remainder below the step-size floor
        h = t_final - t if h > t_final - t - MIN_STEP * span else h
        # a step below the floor with the state still of its initial size: a fast transient, not a blow-up
        _refuse(space, stepper, schedule, t, y, h, span, max_steps,
                stiffness is not None and space.largest(y) <= FLOOR_GROWTH * scale0)
        h, resume = _cut_at_switch(space, t, h, resume)
        trial = stepper.step(space, t, y, f, h)
        ratio = control.ratio(trial.error, h)
        if ratio > 1.0:
            schedule.rejected += 1
            resume = None
            h_next = control.rejected(t, h, ratio)  # None: the estimate is the stages' noise
            h = space.after_stage_noise(h) if h_next is None else h_next
            continue
        space.check(trial, t, y)
        if trial.norm > MAX_GROWTH_OF_NORM * scale0:
            raise space.failure("the solution blows up", t, y)
        t_new = t_final if abs(t + h - t_final) <= 1e-14 * max(1.0, abs(t_final)) else t + h
        outs = output_times(t, h, t_new, nodes, schedule.times[-1], slab_nodes)
        store(stepper.dense_output(space, t, h, y, trial, outs, t_new))
        _record(schedule, space, trial, t, h, t_new, outs)
        t, (y, f) = t_new, space.accept(trial)
        h = control.accepted(h, ratio)
        if resume is not None:  # the step ended at a switch: the next starts past it, at the step it would have had
            f, h, resume = space.past_switch(t, y, f), max(h, resume), None
            schedule.switched.add(len(schedule.steps) - 1)
        emit(callback, MarchStep(t, t_final, len(schedule.steps), space.ranks(y), float(nodes[0])))
        if t < t_final:
            _watch(space, watch, stiffness, schedule, t, y, h)
    return schedule


def _cut_at_switch(space, t: float, h: float, resume: float | None) -> tuple[float, float | None]:
    """The step ended just before a switch of time at some node inside ``(t, t + h)``
    (:mod:`pgdcli.algorithms.switch_location`), and the step to resume with after it."""
    cut = space.switch_cut(t, h) if hasattr(space, "switch_cut") else None
    if cut is None:
        return h, resume
    return cut - t, resume or h


def _refuse(space, stepper: Stepper, schedule: Schedule, t: float, y, h: float, span: float, max_steps: int,
            switch: bool) -> None:
    """Raise when the march cannot try a step of length ``h`` (the caps): ``space.failure``, or with ``switch``
    (``solver.integrator: auto``) :class:`StiffnessDetected` for an explicit step below the floor, or at
    ``max_steps`` far from the end (not at a kink of a switching term: that one is named)."""
    refusal = step_refusal(len(schedule.steps), schedule.rejected, max_steps, h, span,
                           lambda: underflow_hint(space.system.general, space.stats), stepper.title,
                           stepper.order, stepper.explicit)
    if not refusal:
        return
    if switch and not _at_a_kink(space, t, y, span):
        if h < MIN_STEP * span:
            raise StiffnessDetected.floor(stepper.title, t, MIN_STEP * span)
        if stepper.explicit and h * max_steps < span:  # at the cap, far from the end
            raise StiffnessDetected.capped(stepper.title, t, h, max_steps, span)
    raise space.failure(refusal, t, y)


def _at_a_kink(space, t: float, y, span: float) -> bool:
    """Steps below the floor at a switch of the unknowns (a general term's kink or jump), not in a transient
    faster than the floor: the Jacobian, which a transient that fast shows as a decay rate above
    ``1 / floor``, decays slower. The march then stops and names the switching term."""
    return bool(switching_terms(space.system.general)) and space.decay_rate(t, y) * MIN_STEP * span < 1.0


def _watch(space, blowup_watch: BlowupWatch, stiffness: StiffnessWatch | None, schedule: Schedule, t: float, y,
           h: float) -> None:
    """After an accepted step: stiffness (when watched) and a coming blow-up end the march."""
    if stiffness is not None:
        stiffness(space, t, y, h, len(schedule.steps))
    blowup = blowup_watch(t, schedule.step_sizes, y)
    if blowup is not None:
        raise space.failure("the solution blows up", t, y, blowup)


def _check_requires(space, stepper: Stepper) -> None:
    """Refuse a stepper that needs an optional method the space lacks (a Jacobian of tensor trains)."""
    missing = [name for name in stepper.requires if not callable(getattr(space, name, None))]
    if missing:
        raise SolverError(f"solver.integrator: {stepper.name!r} needs the {' and '.join(missing)} of the right-hand "
                          f"side, which the march on {space.kind} does not provide; use another integrator or "
                          f"solver.march: grid or cross")


def _record(schedule: Schedule, space, trial, t: float, h: float, t_new: float, outs: list[float]) -> None:
    """Add an accepted step to the schedule."""
    schedule.times.extend(outs)
    schedule.steps.append((t, h, t_new, outs))
    schedule.step_sizes.append(h)
    schedule.local_sum += trial.local
    if schedule.stepper.error_per_step:  # a stiff problem damps its local errors: the largest, not their sum
        schedule.estimate = max(schedule.estimate, trial.error + space.rounding(h))
    else:
        schedule.estimate += trial.error + space.rounding(h)

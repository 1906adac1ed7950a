"""Large parameter grids: trajectories at the multi-indices a tensor-train cross asks for.

On a grid of millions to billions of nodes (six initial conditions with 10 nodes each, and three
body coefficients beside them) the array of the grid march does not fit, and the tensor-train
march pays for rounded sums of rank-100 trains at every stage. A codebook's train of rank r over
d modes of n nodes is determined by about ``d n r^2`` of its fibres, and a fibre through the
time mode is one trajectory. So:

1. a pilot march (:func:`pgdcli.algorithms.grid_steps.advance`) over :data:`PILOT_POINTS` random
   nodes and the grid's corners chooses the steps, with the grid march's step control (the
   root-mean-square over the pilot's nodes estimates the one over the grid) and its stored times;
2. :func:`pgdcli.tensors.fiber_cross.vector_cross` asks for the trajectories at the nodes its
   index sets name, and every batch of them is marched with the pilot's steps
   (:func:`pgdcli.algorithms.grid_steps.replay`): the values the grid march would have stored
   there. The batches are independent: the executor in effect (:mod:`pgdcli.executors`) runs them,
   here or on the workers of a Dask cluster, and the train does not depend on which. The cross stops when its train is within ``CROSS_SHARE * tolerance`` of fresh
   trajectories at random nodes;
3. the train (unknowns x stored times first) is split by unknown and rounded to ``delta``.

A node where the pilot's steps overflow (a region the pilot did not see) joins the pilot and the
steps are chosen again, at most :data:`RETRIES` times. The user's tolerance is enforced by the
error gate after the march (``pgdcli.driver``), as for every march.
"""

from __future__ import annotations

from dataclasses import dataclass
from itertools import product

import numpy as np

from .. import executors
from ..progress import CrossSweep
from ..tensors.fiber_cross import vector_cross
from ..tensors.tt import TT, tt_round_shared
from .grid_steps import GridMarchFailure, GridRhs, NodeFunctions, advance, initial_values, replay_batch
from .march_loop import Schedule
from .polynomial_rhs import NonlinearSystem
from .stepping import Stepper

__all__ = ["CrossMarchResult", "march_by_cross", "PILOT_POINTS", "CROSS_SHARE"]

#: Random grid nodes of the pilot march (beside the corners).
PILOT_POINTS = 2048
#: Corners of the grid in the pilot at most (all of them up to 10 modes).
PILOT_CORNERS = 1024
#: The cross's root-mean-square difference from trajectories at random nodes, as a share of the tolerance
#: (the grid march's compression gets the same share, in the Frobenius norm).
CROSS_SHARE = 0.1
#: The cross's largest difference there, as a share of the tolerance.
CROSS_LARGEST = 0.5
#: Nodes marched together at most: their stages stay in the cache (per node, batches of this size were
#: measured twice as fast as four times larger ones).
REPLAY_POINTS = 16384
#: Times the pilot is marched again with the nodes where its steps overflowed.
RETRIES = 2


@dataclass
class CrossMarchResult:
    """The codebook's space-time trains and what the pilot and the cross did."""

    trains: list[TT]  # per unknown: time nodes first, then the grid's modes
    times: np.ndarray
    schedule: Schedule
    converged: bool
    message: str
    evaluations: int  # trajectories marched for the cross (its checks included)
    sweeps: int
    cross_error: float
    pilot_points: int
    breakpoints: np.ndarray | None  # the steps' ends (automatic slabs), else None

    @property
    def steps(self) -> int:
        return len(self.schedule.steps)

    @property
    def rejected(self) -> int:
        return self.schedule.rejected

    @property
    def step_sizes(self) -> list[float]:
        return self.schedule.step_sizes

    @property
    def error_estimate(self) -> float:
        """The pilot's accepted local error estimates added up (RMS over its nodes, largest unknown)."""
        return float(np.max(self.schedule.local_sum))


def march_by_cross(system: NonlinearSystem, tolerance: float, delta: float, *, max_rank: int = 400,
                   max_steps: int = 20000, callback=None, slab_nodes: int | None = None,
                   budget: int | None = None, stepper: Stepper | None = None) -> CrossMarchResult:
    """Pilot march, cross of the trajectories, split and round (module docstring).

    Parameters
    ----------
    system : NonlinearSystem
    tolerance : float
        The march's tolerance (step control as :func:`pgdcli.algorithms.grid_march.march_on_grid`).
    delta : float
        Frobenius bound of each unknown's rounding.
    max_rank : int
    max_steps : int
    callback : callable, optional
        After every accepted pilot step (a :class:`~pgdcli.progress.MarchStep`) and every half sweep of
        the cross (a :class:`~pgdcli.progress.CrossSweep`).
    slab_nodes : int, optional
        Automatic slabs (see :func:`pgdcli.algorithms.march.march`).
    budget : int, optional
        Trajectories the cross may ask for (``converged`` False beyond them).
    stepper : Stepper, optional
        The pilot's (and so the trajectories') stepper; default DOP853.

    Raises
    ------
    GridMarchFailure
        The pilot march failed (blow-up, step-size underflow, max_steps), or its steps overflowed at
        nodes of the grid after :data:`RETRIES` new pilots.
    """
    rng = np.random.default_rng(17)  # same spec, same codebook
    pilot = _pilot_indices(system.shape, rng)
    functions = NodeFunctions(system)
    for attempt in range(RETRIES + 1):
        try:
            schedule = advance(system, GridRhs(system, pilot, functions), initial_values(system, pilot, functions),
                               tolerance, lambda values: None, max_steps=max_steps, callback=callback,
                               slab_nodes=slab_nodes, stepper=stepper)
        except GridMarchFailure as failure:
            failure.indices = pilot
            raise
        try:
            found = vector_cross(_Trajectories(system, schedule, functions), len(system.unknowns) * len(schedule.times),
                                 system.shape, CROSS_SHARE * tolerance, largest=CROSS_LARGEST * tolerance, rng=rng,
                                 max_rank=max_rank, callback=_sweep_progress(callback, CROSS_SHARE * tolerance),
                                 max_evaluations=budget, map=executors.current().map)
            break
        except _Overflow as overflow:
            if attempt == RETRIES:
                raise GridMarchFailure(f"the pilot march's steps overflow at {len(overflow.indices)} grid nodes "
                                       f"after {RETRIES} new pilots with them (the solution blows up or is stiff "
                                       f"there)", float(schedule.times[-1]), overflow.values,
                                       indices=overflow.indices) from None
            pilot = np.unique(np.vstack([pilot, overflow.indices[:256]]), axis=0)
    trains = _split(found.train, len(system.unknowns), len(schedule.times), delta)
    return CrossMarchResult(trains, np.array(schedule.times), schedule, found.converged, found.message,
                            found.evaluations, found.sweeps, found.error, len(pilot),
                            schedule.breakpoints() if slab_nodes else None)


class _Overflow(Exception):
    def __init__(self, indices: np.ndarray, values: np.ndarray):
        super().__init__("non-finite trajectories")
        self.indices, self.values = indices, values

    def __reduce__(self):  # raised on a worker, re-raised here
        return _Overflow, (self.indices, self.values)


def _sweep_progress(callback, target: float):
    """The cross's half sweeps as progress: a :class:`~pgdcli.progress.CrossSweep` each."""
    if callback is None:
        return None
    return lambda info: callback(CrossSweep(info["sweep"], info["error"], target, info["evaluations"],
                                            info["ranks"]))


def _pilot_indices(shape: tuple[int, ...], rng: np.random.Generator) -> np.ndarray:
    """Random nodes and corners of the grid, without repeats: shape (P, d)."""
    d = len(shape)
    corners = np.array(list(product(*[(0, n - 1) for n in shape])), dtype=int).reshape(-1, d)
    if len(corners) > PILOT_CORNERS:
        corners = corners[rng.choice(len(corners), PILOT_CORNERS, replace=False)]
    random = np.stack([rng.integers(0, n, size=PILOT_POINTS) for n in shape], axis=1)
    return np.unique(np.vstack([corners, random]), axis=0)


class _Trajectories:
    """``F(indices)``: the stored states at grid multi-indices (P, d), as (times x unknowns, P).

    Sent to an executor's workers once per schedule: it pickles as the system and the schedule, and
    builds the node functions again where it is unpickled.
    """

    def __init__(self, system: NonlinearSystem, schedule: Schedule, functions: NodeFunctions | None = None):
        self.system, self.schedule = system, schedule
        self.functions = NodeFunctions(system) if functions is None else functions

    def __reduce__(self):
        return _Trajectories, (self.system, self.schedule)

    def _replayed(self, chosen: np.ndarray) -> np.ndarray:  # (times, m, P), finite
        values = replay_batch(self.schedule, self.functions, chosen)
        _refuse_overflow(chosen, values)
        return values

    def __call__(self, indices: np.ndarray) -> np.ndarray:
        if len(indices) <= REPLAY_POINTS:  # one replay: its array is the answer (no copy)
            return self._replayed(indices).reshape(-1, len(indices))
        out = np.empty((len(self.schedule.times), len(self.system.unknowns), len(indices)))
        for start in range(0, len(indices), REPLAY_POINTS):
            out[:, :, start:start + REPLAY_POINTS] = self._replayed(indices[start:start + REPLAY_POINTS])
        return out.reshape(-1, len(indices))


def _refuse_overflow(indices: np.ndarray, values: np.ndarray) -> None:
    """Raise :class:`_Overflow` with the nodes whose replayed values (times, m, P) are not all finite."""
    with np.errstate(all="ignore"):  # inf - inf in the sum is a non-finite value too
        if np.isfinite(values.sum()):
            return
    bad = ~np.all(np.isfinite(values), axis=(0, 1))
    raise _Overflow(indices[bad], values[:, :, bad][-1])


def _split(train: TT, unknowns: int, times: int, delta: float) -> list[TT]:
    """The train of shape (times x unknowns, grid) as one train per unknown, each rounded to ``delta``
    with the bonds' shares of it that keep the fewest values (the codebook's size and query cost)."""
    first = train.cores[0].reshape(times, unknowns, -1)
    return tt_round_shared([first[:, s][None] for s in range(unknowns)], train.cores[1:], absolute=delta,
                           allocate=True)

"""Small parameter grids: the time march on the whole array of grid values, compressed once.

On a grid of a few thousand to a few hundred thousand nodes (three initial conditions
with 20-40 nodes each, six with 8) every separated operation of the tensor-train march
(:mod:`pgdcli.algorithms.march`: roundings, QR, crosses) costs more than the
whole array does: one right-hand side on the array is a few elementwise products.
There the state is kept as the array of its values at all grid nodes, advanced by
the same stepper and step control, stored at the same time nodes, and the
space-time array of each unknown is compressed once by TT-SVD (measured randomized ranges,
:mod:`pgdcli.tensors.tt_svd`) to the same share of the tolerance as the train march's
space-time rounding; a long march by runs of at most :data:`CHUNK_FLOATS` floats, joined at
the end. The codebook is the same kind (one tensor train per unknown, time first); the cost
is about that of one vectorized ``solve_ivp`` over the grid plus the TT-SVD
(benchmarks/build_speed.py).

The error control is the train march's: the embedded estimate of each unknown in the
root-mean-square norm over the grid nodes may be ``LOCAL_FRACTION * tolerance * h / span``
(the local errors add up to that share of the tolerance); the user's tolerance, a max abs
error, is enforced by the error gate after the march (:mod:`pgdcli.driver.refinement`).

:data:`GRID_LIMIT` decides which march a problem gets (:func:`fits_grid`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import SolverError
from ..tensors.tt_svd import tt_from_full_sketched
from ..tensors.tt import TT
from .grid_steps import GridMarchFailure, GridRhs, advance, initial_values
from .polynomial_rhs import SINGLE_POINT, NonlinearSystem
from .stepping import Stepper
from .space_time import join_and_round

__all__ = ["GRID_LIMIT", "GRID_MAX", "CHUNK_FLOATS", "fits_grid", "check_forced_grid", "GridRhs", "GridMarchResult", "march_on_grid",
           "grid_region", "GridMarchFailure"]

#: Largest number of state values (grid nodes x unknowns) marched as one array; 0 sends every problem to
#: the train march. Up to it the grid march is faster than the train march on the shipped problems, and
#: its memory (~20 arrays of the state) stays near a gigabyte (benchmarks/build_speed.py).
GRID_LIMIT = 2 ** 21


#: Most state values ``solver.march: grid`` accepts: the march holds ~20 arrays of the state (DOP853's 16
#: stages among them), ~5 GB at this size; above it the error names ``solver.march``.
GRID_MAX = 2 ** 25

#: Floats of stored values (time nodes x unknowns x grid nodes) compressed together: 256 MB. A long march
#: (thousands of time nodes) is compressed by runs and joined (:func:`pgdcli.algorithms.space_time.join_and_round`).
CHUNK_FLOATS = 2 ** 25


def fits_grid(system: NonlinearSystem) -> bool:
    """Whether the system's state (grid nodes x unknowns) has at most :data:`GRID_LIMIT` values."""
    return int(np.prod(system.shape)) * len(system.unknowns) <= GRID_LIMIT


def check_forced_grid(problem) -> None:
    """Refuse ``solver.march: grid`` on a state above :data:`GRID_MAX` values (the spec's node counts)."""
    if getattr(problem.solver, "march", "auto") != "grid":
        return
    values = len(problem.unknowns)
    for c in problem.coordinates:
        if c.name != problem.time:
            values *= c.nodes
    if values > GRID_MAX:
        raise SolverError(f"{problem.source}: solver.march: 'grid' holds ~20 arrays of the state, which has "
                          f"{values:,} values (grid nodes x unknowns; at most {GRID_MAX:,}): use 'auto' or "
                          f"'train' (a tensor train), or fewer nodes")


@dataclass
class GridMarchResult:
    """The codebook's space-time trains and what the march did."""

    trains: list[TT]  # per unknown: the space-time train (time nodes first, then the grid's modes)
    times: np.ndarray
    steps: int
    rejected: int
    error_estimate: float  # the accepted local error estimates added up (RMS over the grid, largest unknown)
    step_sizes: list[float] = field(default_factory=list)
    breakpoints: np.ndarray | None = None
    chunks: int = 1  # runs of time nodes compressed on their own (memory) before the join


class _Store:
    """The values at the time nodes, compressed by runs of at most :data:`CHUNK_FLOATS` floats.

    A single run is compressed once with the whole budget ``delta``; with several, run ``c`` gets
    ``delta / 2 * 2^(-(c + 1) / 2)`` (the runs are orthogonal blocks of the time mode: their errors
    add in quadrature, to at most ``delta / 2``) and the rounding of their join the rest of
    ``delta`` (the two errors add).
    """

    def __init__(self, shape: tuple[int, ...], delta: float):
        self.shape, self.delta = shape, delta
        self.buffer: list[np.ndarray] = []
        self.floats = 0  # in the buffer
        self.pieces: list[list[TT]] = []
        self.spent = 0.0  # squared Frobenius budget given to the runs
        self.rng = np.random.default_rng(7)  # the sketches' seed: same spec, same codebook

    def extend(self, values: list[np.ndarray]) -> None:
        self.buffer.extend(values)
        self.floats += sum(v.size for v in values)
        if self.floats > CHUNK_FLOATS:
            self._close_run()

    def _close_run(self) -> None:
        """Compress the buffer as the next run, with its share of the budget."""
        budget = 0.5 * self.delta * np.sqrt(0.5 ** (len(self.pieces) + 1))
        self.spent += budget * budget
        self.pieces.append(self._compress(budget))

    def _compress(self, delta: float) -> list[TT]:
        stacked = np.stack(self.buffer)  # (time nodes, unknowns, grid nodes)
        self.buffer, self.floats = [], 0
        trains: list[TT] = []
        guesses = self.pieces[-1] if self.pieces else []
        for i in range(stacked.shape[1]):  # sketches sized from the ranks of the unknown (run) before
            values = np.ascontiguousarray(stacked[:, i]).reshape((stacked.shape[0],) + self.shape)
            guess = trains[-1].ranks if trains else (guesses[i].ranks if guesses else ())
            trains.append(tt_from_full_sketched(values, delta, self.rng, guess))
        return trains

    def trains(self) -> list[TT]:
        """The space-time train of every unknown, within ``delta`` of the stored values."""
        if not self.pieces:
            return self._compress(self.delta)
        if self.buffer:
            self._close_run()
        groups = [[piece[i] for piece in self.pieces] for i in range(len(self.pieces[0]))]
        return join_and_round(groups, self.delta - np.sqrt(self.spent), self.rng, batched=False, lifted=True)


def march_on_grid(system: NonlinearSystem, tolerance: float, delta: float, *, max_steps: int = 20000,
                  callback=None, slab_nodes: int | None = None,
                  stepper: Stepper | None = None) -> GridMarchResult:
    """March the whole grid array with a stepper to the end of the time domain; compress it to trains.

    Parameters
    ----------
    system : NonlinearSystem
    tolerance : float
        Root-mean-square over the grid nodes, per unknown, of the local errors added up over the march.
    delta : float
        Frobenius bound of the compression of each unknown's space-time array.
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
    rhs = GridRhs(system)
    store = _Store(system.shape, delta)
    schedule = advance(system, rhs, initial_values(system), tolerance, store.extend, max_steps=max_steps,
                       callback=callback, slab_nodes=slab_nodes, stepper=stepper)
    trains = store.trains()
    return GridMarchResult(trains, np.array(schedule.times), len(schedule.steps), schedule.rejected,
                           float(np.max(schedule.local_sum)), schedule.step_sizes,
                           schedule.breakpoints() if slab_nodes else None,
                           max(1, len(store.pieces)))


def grid_region(system: NonlinearSystem, values: np.ndarray, indices: np.ndarray | None = None) -> str:
    """Where the values (unknowns, nodes) are largest, as 'a=0, b=1' ('' for one trajectory or none).

    ``indices`` (nodes, d) are the nodes' multi-indices; None: the nodes are the whole grid (C order).
    """
    if system.params == [SINGLE_POINT] or values.size == 0:
        return ""
    size = np.where(np.isfinite(values), np.abs(values), np.inf)
    node = int(np.argmax(np.max(size, axis=0)))
    idx = indices[node] if indices is not None else np.unravel_index(node, system.shape)
    return ", ".join(f"{p}={system.bases[p].nodes[i]:.4g}" for p, i in zip(system.params, idx))

"""Tensor-train cross of a vector-valued function of a multi-index, the vector taken whole.

``F(i_1, ..., i_d)`` is a vector of length M (a trajectory: unknowns x stored times) at every node
of a grid ``n_1 x ... x n_d``; one call gives the whole vector, so the vector is the first mode of
a tensor train of shape ``(M, n_1, ..., n_d)`` and every fibre through it costs one evaluation.

The train is built by the alternating one-site cross (Oseledets & Tyrtyshnikov 2010): left index
sets ``L_k`` (the vector's index and the modes before k) and right index sets ``R_k`` (the modes
from k on) define the fibres ``F[L_k, i_k, R_{k+1}]`` of core k, ``r_k n_k r_{k+1}`` values from
at most that many evaluations. Sweeping left to right, the column space of each fibre matrix gives
the core in interpolation form ``Q Q[rows]^-1`` and the maximum-volume rows (:func:`maxvol`) the next
left set; right to left, the same with rows and columns exchanged. Ranks adapt: the truncated SVD of
a fibre matrix gives the rank its values need, and a fibre matrix whose every column counts
(its rank is the size of the index set beside it, which may be too small) doubles its rank
with random columns, as the kick of Dolgov & Savostyanov's AMEn-cross; ranks that need less shrink.
The truncation drops at most a share of the tolerance from each fibre matrix; interpolation
amplifies it, so a half sweep that does not halve the error of the last one in its direction makes
that share 2x smaller.

The function is deterministic, so every vector it returned is kept (up to :data:`MEMO_FLOATS`
values) and a multi-index asked again is answered from memory: the sweeps ask for the same fibres
again once the index sets settle.

Convergence is measured, not assumed: after every half sweep the train is compared with ``F`` at
fresh random multi-indices (the whole vector each), and the cross stops when the largest
difference is at most the tolerance. A rank that reaches ``max_rank`` or a sweep budget that
runs out is reported (``converged`` False, ``message``), never hidden.

This module imports numpy, scipy.linalg, :mod:`pgdcli.tensors` and :mod:`pgdcli.pages` only.
"""

from __future__ import annotations

import builtins
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.linalg import qr

from ..pages import small_page_array
from ..tuning import BATCH_FLOATS, MEMO_FLOATS, SMALL_PAGES_ABOVE
from .cross import maxvol
from .tt import TT
from .tt_svd import truncation_rank

__all__ = ["VectorCrossResult", "vector_cross", "tt_vectors_at"]

#: Share of the tolerance, as a root-mean-square over its values, that a fibre matrix's truncation may drop.
TRUNCATION_SHARE = 0.01
#: A half sweep whose error is above this share of the last one in the same direction tightens the
#: truncation 2x.
STALLED = 0.5
#: Random columns added to every fibre matrix's basis (the kick), beside the growth of a full one.
KICK = 4
# BATCH_FLOATS: values (points x vector length) asked of the function in one call; MEMO_FLOATS:
# values of evaluated vectors kept to answer a multi-index asked again (the sweeps ask for many
# fibres again as the index sets settle, and a later half sweep's check points may have been
# fibres); a memo of more than SMALL_PAGES_ABOVE values is kept in small pages (``_fresh_array``).


@dataclass
class VectorCrossResult:
    """What :func:`vector_cross` produced and how it got there.

    Attributes
    ----------
    train : TT
        Shape ``(M, n_1, ..., n_d)``.
    converged : bool
    error : float
        Root-mean-square difference from ``F`` at the last half sweep's check points (all M values of each).
    largest : float
        Largest difference there.
    evaluations : int
        Multi-indices evaluated (each a whole vector), check points included; one asked again and
        answered from memory counts once.
    sweeps : int
        Half sweeps done.
    message : str
    """

    train: TT
    converged: bool
    error: float
    largest: float
    evaluations: int
    sweeps: int
    message: str


def tt_vectors_at(train: TT, indices: np.ndarray) -> np.ndarray:
    """The vectors of a train of shape (M, n_1, ..., n_d) at multi-indices (P, d): shape (P, M).

    Contracted from the last core, one product per node of each mode for the points at that node (a
    gather of the cores' slices at every point would copy ``P r^2`` values per core).
    """
    w = train.cores[-1][:, indices[:, -1], 0].T  # (P, r_d)
    for k in range(train.order - 2, 0, -1):
        core, column = train.cores[k], indices[:, k - 1]
        out = np.empty((len(indices), core.shape[0]))
        for node in range(core.shape[1]):
            at = column == node
            out[at] = w[at] @ core[:, node, :].T
        w = out
    return w @ train.cores[0][0].T


def vector_cross(function: Callable[[np.ndarray], np.ndarray], outputs: int, shape: Sequence[int],
                 tolerance: float, *, largest: float | None = None, rng: np.random.Generator, max_rank: int = 400,
                 initial_rank: int = 16, check_points: int = 256, max_sweeps: int = 16,
                 callback: Callable[[dict], None] | None = None,
                 max_evaluations: int | None = None, map: Callable | None = None) -> VectorCrossResult:
    """A tensor train of shape ``(outputs,) + shape`` within ``tolerance`` of ``F`` at random checks.

    Parameters
    ----------
    function : callable
        ``function(indices)``: multi-indices of shape (P, d) -> values of shape (outputs, P), the vector of
        each multi-index a column.
    outputs : int
        M, the length of every vector.
    shape : sequence of int
        The grid ``(n_1, ..., n_d)``, d >= 1.
    tolerance : float
        Root-mean-square difference allowed at the check points (over all their values).
    largest : float, optional
        Largest absolute difference allowed there (default: no bound beyond ``tolerance``).
    rng : numpy.random.Generator
        Initial index sets, kicks and check points (same seed, same train).
    max_rank : int
    initial_rank : int
        Size of the random initial right index sets.
    check_points : int
        Random multi-indices compared after every half sweep.
    max_sweeps : int
        Half sweeps at most.
    callback : callable, optional
        After every half sweep: ``{"sweep", "error", "largest", "ranks", "evaluations"}``.
    max_evaluations : int, optional
        Stop (not converged) after the half sweep that passes this many evaluations.
    map : callable, optional
        ``map(function, batches)``: ``function`` of every batch of multi-indices, in order (an executor's
        map, which may run the batches elsewhere at once); default the builtin. The batches are the
        same whatever runs them, and so is the train.
    """
    shape = tuple(int(n) for n in shape)
    if not shape or min(shape) < 1 or outputs < 1:
        raise ValueError(f"vector_cross needs outputs >= 1 and a grid of d >= 1 modes, got {outputs}, {shape}")
    cross = _VectorCross(function, outputs, shape, tolerance, rng, max_rank, initial_rank)
    if map is not None:
        cross.map = map
    return cross.run(check_points, max_sweeps, np.inf if largest is None else largest, callback,
                     np.inf if max_evaluations is None else max_evaluations)


class _VectorCross:
    """The index sets and sweeps of :func:`vector_cross` (mode 0 is the vector, mode k >= 1 is ``n_k``)."""

    def __init__(self, function, outputs: int, shape: tuple, tolerance: float, rng, max_rank: int,
                 initial_rank: int):
        self.function, self.outputs, self.shape = function, outputs, shape
        self.tolerance, self.rng, self.max_rank = tolerance, rng, max_rank
        self.d = len(shape)
        self.evaluations = 0
        self.capped = False
        self.share = TRUNCATION_SHARE
        # right[k], k = 1..d: rows of (i_k, ..., i_d) (0-based modes k-1..d-1 of the grid); right[d+1] empty
        self.right = [None] + [self._random_indices(shape[k - 1:], initial_rank) for k in range(1, self.d + 1)]
        self.right.append(np.zeros((1, 0), dtype=int))
        self.left: list = [None] * (self.d + 1)  # left[k], k = 1..d: rows of (vector index, i_1, ..., i_{k-1})
        self.edge = None  # (mode, fibres) computed last, reused by the next half sweep's first core
        self.memo = _Memo.of(shape, outputs)
        self.map = builtins.map  # of the function over batches (vector_cross's ``map``)

    def _random_indices(self, modes: tuple, count: int) -> np.ndarray:
        count = min(count, int(np.prod(modes, dtype=float)))
        return np.stack([self.rng.integers(0, n, size=count) for n in modes], axis=1)

    def run(self, check_points: int, max_sweeps: int, largest: float, callback, budget: float) -> VectorCrossResult:
        error = worst = np.inf
        errors: list[float] = []
        message = f"no sweep met the tolerance in {max_sweeps} half sweeps"
        train = None
        for sweep in range(1, max_sweeps + 1):
            self.capped = False
            train = self._left_to_right() if sweep % 2 else self._right_to_left()
            error, worst = self._check(train, check_points)
            errors.append(error)
            if callback is not None:
                callback({"sweep": sweep, "error": error, "largest": worst, "ranks": list(train.ranks),
                          "evaluations": self.evaluations})
            if len(errors) > 2 and error > STALLED * errors[-3]:  # against the last sweep the same way
                self.share *= 0.5  # the ranks the truncation allows are too small for the tolerance
            found = f"root-mean-square difference {error:.3g}, largest {worst:.3g} at {check_points} random multi-indices"
            if error <= self.tolerance and worst <= largest:
                return VectorCrossResult(train, True, error, worst, self.evaluations, sweep, f"converged: {found}")
            if self.capped:
                message = f"a tensor-train rank reached max_rank={self.max_rank} ({found})"
                break
            if self.evaluations > budget:
                message = f"{self.evaluations:,} evaluations, more than the budget of {budget:,} ({found})"
                break
        else:
            sweep = max_sweeps
            message += f" ({found})"
        return VectorCrossResult(train, False, error, worst, self.evaluations, sweep, message)

    # ------------------------------------------------------------------ sweeps
    def _left_to_right(self) -> TT:
        cores = []
        for k in range(self.d):
            fibres = self._fibres(k)  # (r_k, n_k, r_{k+1}); mode 0: (1, M, r_1)
            r, n, c = fibres.shape
            q, rows = self._basis(fibres.reshape(r * n, c))
            cores.append(self._interpolating(q, rows).reshape(r, n, -1))
            a, i = np.divmod(rows, n)
            self.left[k + 1] = i[:, None] if k == 0 else np.hstack([self.left[k][a], i[:, None]])
        last = self._fibres(self.d)
        self.edge = (self.d, last)
        return TT(cores + [last])

    def _right_to_left(self) -> TT:
        cores = []
        for k in range(self.d, 0, -1):
            fibres = self._fibres(k)
            r, n, c = fibres.shape
            q, rows = self._basis(fibres.reshape(r, n * c).T)
            cores.append(self._interpolating(q, rows).T.reshape(-1, n, c))
            i, b = np.divmod(rows, c)
            self.right[k] = np.hstack([i[:, None], self.right[k + 1][b]])
        first = self._fibres(0)
        self.edge = (0, first)
        return TT([first] + cores[::-1])

    def _basis(self, matrix: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """An orthonormal basis of the fibre matrix's (kicked) column space and its maxvol rows."""
        rows, cols = matrix.shape
        u, s, _ = np.linalg.svd(matrix, full_matrices=False)
        delta = self.share * self.tolerance * np.sqrt(rows * cols)
        rank = truncation_rank(s, delta)
        grow = max(KICK, rank) if rank >= cols else KICK  # every column counts: the set beside is too small
        wanted = rank + grow
        if rank >= self.max_rank:
            self.capped = True
        size = min(rows, wanted, self.max_rank)
        basis = u[:, :min(rank, size)]
        if size > basis.shape[1]:  # random columns, orthogonalized against the basis twice (then by QR)
            kick = self.rng.standard_normal((rows, size - basis.shape[1]))
            for _ in range(2):
                kick -= basis @ (basis.T @ kick)
            basis = np.hstack([basis, qr(kick, mode="economic")[0]])
        return basis, maxvol(basis)

    @staticmethod
    def _interpolating(q: np.ndarray, rows: np.ndarray) -> np.ndarray:
        """``q q[rows]^-1``: the core that reproduces the fibres at the chosen rows."""
        return np.linalg.solve(q[rows].T, q.T).T

    # ------------------------------------------------------------------ evaluations
    def _fibres(self, k: int) -> np.ndarray:
        """``F[L_k, i_k, R_{k+1}]`` of shape (r_k, n_k, r_{k+1}); mode 0: ``F[R_1]^T`` as (1, M, r_1)."""
        if self.edge is not None and self.edge[0] == k:
            fibres, self.edge = self.edge[1], None
            return fibres
        if k == 0:
            return self._evaluate(self.right[1])[None]
        left, right, n = self.left[k], self.right[k + 1], self.shape[k - 1]
        if k == 1:
            prefixes, inverse = np.zeros((1, 0), dtype=int), np.zeros(len(left), dtype=int)
        else:
            prefixes, inverse = np.unique(left[:, 1:], axis=0, return_inverse=True)
            inverse = inverse.reshape(-1)
        u, c = len(prefixes), len(right)
        points = np.hstack([np.repeat(prefixes, n * c, axis=0), np.tile(np.repeat(np.arange(n), c), u)[:, None],
                            np.tile(right, (u * n, 1))])
        # entry (a, i, b) is output left[a, 0] of point (inverse[a], i, b)
        point_of = ((inverse[:, None, None] * n + np.arange(n)[None, :, None]) * c + np.arange(c)[None, None, :])
        output_of = np.broadcast_to(left[:, 0][:, None, None], point_of.shape)
        return self._pick(points, point_of.reshape(-1), output_of.reshape(-1)).reshape(len(left), n, c)

    @property
    def _batch(self) -> int:
        """Points per call of the function: at most :data:`BATCH_FLOATS` values."""
        return max(1, BATCH_FLOATS // self.outputs)

    def _evaluate(self, points: np.ndarray) -> np.ndarray:
        """All M values at the points, shape (M, P), in calls of at most :data:`BATCH_FLOATS` values."""
        slots = self._kept(points)
        if slots is not None:
            return self.memo.values[:, slots]
        batch = self._batch
        self.evaluations += len(points)
        return np.concatenate(list(self.map(self.function, _batches(points, batch))), axis=1)

    def _pick(self, points: np.ndarray, point_of: np.ndarray, output_of: np.ndarray) -> np.ndarray:
        """The values ``F(points[point_of[e]])[output_of[e]]``, evaluating the points by batches."""
        slots = self._kept(points)
        if slots is not None:  # only the values asked for are read, not whole vectors
            return self.memo.values[output_of, slots[point_of]]
        batch = self._batch
        order = np.argsort(point_of, kind="stable")
        sorted_points = point_of[order]
        out = np.empty(point_of.size)
        self.evaluations += len(points)
        for s, values in zip(range(0, len(points), batch), self.map(self.function, _batches(points, batch))):
            lo, hi = np.searchsorted(sorted_points, [s, s + batch])
            entries = order[lo:hi]
            out[entries] = values[output_of[entries], point_of[entries] - s]
        return out

    def _kept(self, points: np.ndarray) -> np.ndarray | None:
        """The memo's columns of the points (P,), evaluating and keeping the ones not kept yet.

        A full memo is cleared first (the sweeps after this one ask most for its points). None: no
        memo, or more distinct points than it holds.
        """
        if self.memo is None:
            return None
        keys = self.memo.keys_of(points)
        known, slots = self.memo.find(keys)
        if known.all():
            return slots
        new, first, inverse = np.unique(keys[~known], return_index=True, return_inverse=True)
        capacity = self.memo.values.shape[1]
        if self.memo.count + len(new) > capacity:  # full: forget it, keep these points
            known[:] = False
            new, first, inverse = np.unique(keys, return_index=True, return_inverse=True)
            if len(new) > capacity:
                return None
            self.memo.clear()
        fresh, start, batch = points[~known][first], self.memo.count, self._batch
        for s, values in zip(range(0, len(fresh), batch), self.map(self.function, _batches(fresh, batch))):
            self.memo.values[:, start + s:start + s + values.shape[1]] = values
        self.evaluations += len(new)
        self.memo.insert(new, start)
        slots[~known] = start + inverse.reshape(-1)
        return slots

    def _check(self, train: TT, count: int) -> tuple[float, float]:
        """Root-mean-square and largest difference from ``F`` at fresh random multi-indices."""
        points = self._random_indices(self.shape, count)
        difference = tt_vectors_at(train, points) - self._evaluate(points).T
        return float(np.sqrt(np.mean(difference * difference))), float(np.max(np.abs(difference)))


def _batches(points: np.ndarray, batch: int):
    """Consecutive slices of ``batch`` points (the last one shorter)."""
    return (points[s:s + batch] for s in range(0, len(points), batch))


class _Memo:
    """The vectors of the multi-indices evaluated so far: column ``columns[j]`` of ``values`` is the
    vector of the multi-index of linear index ``keys[j]`` (keys sorted).

    Vectors are columns, as the function returns them: stored without a transposed copy, which a
    row layout would need at every sweep.
    """

    def __init__(self, shape: tuple, capacity: int, outputs: int):
        self.shape = shape
        self.keys = np.empty(0, dtype=np.int64)
        self.columns = np.empty(0, dtype=np.int64)
        self.values = _fresh_array(outputs, capacity)
        self.count = 0

    @classmethod
    def of(cls, shape: tuple, outputs: int) -> "_Memo | None":
        """A memo for the grid, or None where no vector fits or linear indices would not fit 63 bits."""
        nodes = float(np.prod(shape, dtype=float))
        capacity = min(nodes, MEMO_FLOATS // outputs)
        if capacity < 1 or nodes >= 2.0 ** 62:
            return None
        return cls(shape, int(capacity), outputs)

    def keys_of(self, points: np.ndarray) -> np.ndarray:
        """Linear indices of multi-indices (P, d): shape (P,)."""
        return np.ravel_multi_index(tuple(points.T), self.shape)

    def find(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which keys are kept (P,) bool, and their columns of ``values`` (P,) (meaningful where kept)."""
        if not len(self.keys):
            return np.zeros(len(keys), dtype=bool), np.zeros(len(keys), dtype=np.int64)
        at = np.minimum(np.searchsorted(self.keys, keys), len(self.keys) - 1)
        return self.keys[at] == keys, self.columns[at]

    def clear(self) -> None:
        """Forget every vector (their columns are written again)."""
        self.keys, self.columns, self.count = self.keys[:0], self.columns[:0], 0

    def insert(self, keys: np.ndarray, start: int) -> None:
        """Record new sorted, distinct ``keys`` whose vectors were written to columns ``start, start + 1, ...``."""
        at = np.searchsorted(self.keys, keys)
        self.keys = np.insert(self.keys, at, keys)
        self.columns = np.insert(self.columns, at, np.arange(start, start + len(keys)))
        self.count = start + len(keys)


def _fresh_array(rows: int, columns: int) -> np.ndarray:
    """An uninitialized float array (rows, columns) whose pages the kernel maps as they are written.

    numpy asks the kernel for huge pages for any large array. For a memo of up to
    :data:`SMALL_PAGES_ABOVE` values that is faster; above it, a memo whose every few thousand new
    columns touch a page in each of its rows waits on the kernel's compaction for each of those huge
    pages (the 7-D rigid body's cross, 525 MB: 2.0 s with small pages against 2.4-3.3 s), so a larger
    one is in small pages.
    """
    if rows * columns <= SMALL_PAGES_ABOVE:
        return np.empty((rows, columns))
    return small_page_array(rows, columns)

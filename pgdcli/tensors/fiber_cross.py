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

A fibre of an interior core needs one value of each vector it evaluates (the output its left
index names), so the function's values are picked where they are computed (:class:`_Picked`, the
task an executor runs) and only those travel back: on a cluster, the whole vectors of a 10-D build
are gigabytes, their picks a few hundred megabytes. Each point (prefix, node, column) is evaluated
once per fibre matrix, in batches of whole prefixes. The function is deterministic, so each core's
fibres are kept (up to :data:`MEMO_FLOATS` values) and its next visit evaluates only the rows and
columns its index sets did not have: the sweeps ask for the same fibres again once the index sets
settle. The batches do not depend on what runs the tasks, so neither does the train.

Convergence is measured, not assumed: after every half sweep the train is compared with ``F`` at
fresh random multi-indices (the whole vector each), and the cross stops when the largest
difference is at most the tolerance. A rank that reaches ``max_rank`` or a sweep budget that
runs out is reported (``converged`` False, ``message``), never hidden.

This module imports numpy, scipy.linalg and :mod:`pgdcli.tensors` only.
"""

from __future__ import annotations

import builtins
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
from scipy.linalg import qr

from ..tuning import BATCH_FLOATS, MEMO_FLOATS
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
# picked values kept to answer one asked again (the sweeps ask for many fibres again as the index
# sets settle).


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
        Multi-indices evaluated (each a whole vector), check points included; a value asked again and
        answered from memory costs none.
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
        self.index = np.min_scalar_type(max(shape) - 1)  # the smallest integer the tasks' points fit
        self.evaluations = 0
        self.capped = False
        self.share = TRUNCATION_SHARE
        # right[k], k = 1..d: rows of (i_k, ..., i_d) (0-based modes k-1..d-1 of the grid); right[d+1] empty
        self.right = [None] + [self._random_indices(shape[k - 1:], initial_rank) for k in range(1, self.d + 1)]
        self.right.append(np.zeros((1, 0), dtype=int))
        self.left: list = [None] * (self.d + 1)  # left[k], k = 1..d: rows of (vector index, i_1, ..., i_{k-1})
        self.edge = None  # (mode, fibres) computed last, reused by the next half sweep's first core
        self.memo = _Memo.of()
        self.picker = _Picked(function)
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
        """``F[L_k, i_k, R_{k+1}]`` of shape (r_k, n_k, r_{k+1}); mode 0: ``F[R_1]^T`` as (1, M, r_1).

        The fibres of rows and columns the core's last visit had are taken from the memo: only new
        rows (with every column) and new columns (with the other rows) are evaluated."""
        if self.edge is not None and self.edge[0] == k:
            fibres, self.edge = self.edge[1], None
            return fibres
        if k == 0:
            return self._evaluate(self.right[1])[None]
        left, right = self.left[k], self.right[k + 1]
        last = self.memo.last(k) if self.memo is not None else None
        if last is None:
            fibres = self._block(k, left, right)
        else:
            rows, columns = _matches(left, last[0]), _matches(right, last[1])
            fibres = np.empty((len(left), self.shape[k - 1], len(right)))
            old_rows, old_columns = rows >= 0, columns >= 0
            fibres[np.ix_(old_rows, np.ones(fibres.shape[1], bool), old_columns)] = \
                last[2][np.ix_(rows[old_rows], np.arange(fibres.shape[1]), columns[old_columns])]
            if not old_rows.all():
                fibres[~old_rows] = self._block(k, left[~old_rows], right)
            if not old_columns.all() and old_rows.any():
                fibres[np.ix_(old_rows, np.ones(fibres.shape[1], bool), ~old_columns)] = \
                    self._block(k, left[old_rows], right[~old_columns])
        if self.memo is not None:
            self.memo.keep(k, left, right, fibres)
        return fibres

    def _block(self, k: int, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """``F[left, i_k, right]`` (rows of L_k, all nodes of mode k, rows of R_{k+1}): (r, n_k, c).

        Each distinct point (prefix of a row, node, column) is evaluated once, in batches of whole
        prefixes (or of slices of one prefix's points where they exceed a batch), and each batch's
        task sends back only the values its rows name."""
        left, row = _distinct(left)
        right, column = _distinct(right)
        n, c = self.shape[k - 1], len(right)
        prefixes, group = _distinct(left[:, 1:])
        order = np.argsort(group, kind="stable")  # rows grouped by prefix
        starts = np.searchsorted(group[order], np.arange(len(prefixes) + 1))
        tail = np.hstack([np.repeat(np.arange(n), c)[:, None], np.tile(right, (n, 1))])  # (n c, d - k + 1)
        step = max(1, self._batch // len(tail))  # prefixes a batch
        width = len(tail) if step > 1 or len(tail) <= self._batch else self._batch
        spans = [(u, min(u + step, len(prefixes)), j, min(j + width, len(tail)))
                 for u in range(0, len(prefixes), step) for j in range(0, len(tail), width)]
        prefixes, tail = prefixes.astype(self.index), tail.astype(self.index)
        items = [(prefixes[u0:u1], tail[j0:j1], left[order[starts[u0]:starts[u1]], 0],
                  group[order[starts[u0]:starts[u1]]] - u0) for u0, u1, j0, j1 in spans]  # a list: sent in runs
        out = np.empty((len(left), len(tail)))
        for (u0, u1, j0, j1), values in zip(spans, self.map(self.picker, items)):
            out[order[starts[u0]:starts[u1]], j0:j1] = values
        self.evaluations += len(prefixes) * len(tail)
        return out.reshape(len(left), n, c)[row][:, :, column]

    @property
    def _batch(self) -> int:
        """Points per call of the function: at most :data:`BATCH_FLOATS` values."""
        return max(1, BATCH_FLOATS // self.outputs)

    def _evaluate(self, points: np.ndarray) -> np.ndarray:
        """All M values at the points, shape (M, P), in calls of at most :data:`BATCH_FLOATS` values."""
        self.evaluations += len(points)
        batches = [(batch, None, None, None) for batch in _batches(points.astype(self.index), self._batch)]
        return np.concatenate(list(self.map(self.picker, batches)), axis=1)

    def _check(self, train: TT, count: int) -> tuple[float, float]:
        """Root-mean-square and largest difference from ``F`` at fresh random multi-indices."""
        points = self._random_indices(self.shape, count)
        difference = tt_vectors_at(train, points) - self._evaluate(points).T
        return float(np.sqrt(np.mean(difference * difference))), float(np.max(np.abs(difference)))


def _distinct(rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct rows of an index set (r, m) in their first order, and each row's place among them."""
    if rows.shape[1] == 0:
        return rows[:1], np.zeros(len(rows), dtype=int)
    _, first, inverse = np.unique(rows, axis=0, return_index=True, return_inverse=True)
    keep = np.sort(first)
    place = np.empty(len(first), dtype=int)
    place[np.argsort(first)] = np.arange(len(first))
    return rows[keep], place[inverse.reshape(-1)]


def _matches(rows: np.ndarray, old: np.ndarray) -> np.ndarray:
    """For every row of an index set, its place in ``old`` (another index set), or -1."""
    where = {row.tobytes(): i for i, row in enumerate(old)}
    return np.array([where.get(row.tobytes(), -1) for row in rows], dtype=int)


def _batches(points: np.ndarray, batch: int):
    """Consecutive slices of ``batch`` points (the last one shorter)."""
    return (points[s:s + batch] for s in range(0, len(points), batch))


def batch_points(prefixes: np.ndarray, tail: np.ndarray | None) -> np.ndarray:
    """The points of a batch: each of the prefixes (U, a) followed by each of the J tails (J, b) in turn,
    shape (U J, a + b); ``prefixes`` themselves when ``tail`` is None."""
    if tail is None:
        return prefixes
    return np.hstack([np.repeat(prefixes, len(tail), axis=0), np.tile(tail, (len(prefixes), 1))])


class _Picked:
    """The task of a batch ``(prefixes, tail, outputs, groups)``: ``F`` at its points
    (:func:`batch_points`), whole (``outputs`` None), else its values (A, J) at outputs ``outputs`` (A,)
    of the J points of prefix ``groups`` (A,). A task forms its points itself: a batch travels as its
    prefixes and tails, not their product. One per cross, so an executor sends ``F`` once."""

    def __init__(self, function: Callable[[np.ndarray], np.ndarray]):
        self.function = function

    def __call__(self, item: tuple) -> np.ndarray:
        prefixes, tail, outputs, groups = item
        values = self.function(batch_points(prefixes, tail).astype(np.intp))  # sent in the smallest integers
        if outputs is None:
            return values
        return values.reshape(values.shape[0], -1, len(tail))[outputs, groups]


class _Memo:
    """Each core's index sets and fibres at its last visit: the next visit of the core asks for most of
    them again once the index sets settle. At most :data:`MEMO_FLOATS` values in all: the cores
    visited longest ago are forgotten first."""

    def __init__(self, capacity: int):
        self.capacity = capacity
        self.cores: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}  # core -> left, right, fibres

    @classmethod
    def of(cls) -> "_Memo | None":
        return cls(int(MEMO_FLOATS)) if MEMO_FLOATS >= 1 else None

    @property
    def count(self) -> int:
        return sum(fibres.size for _, _, fibres in self.cores.values())

    def last(self, core: int):
        """(left, right, fibres) of the core's last visit, or None."""
        return self.cores.get(core)

    def keep(self, core: int, left: np.ndarray, right: np.ndarray, fibres: np.ndarray) -> None:
        """This visit of the core, in place of its last one."""
        self.cores.pop(core, None)
        if fibres.size > self.capacity:
            return
        while self.count + fibres.size > self.capacity:
            del self.cores[next(iter(self.cores))]  # the core visited longest ago
        self.cores[core] = (left, right, fibres)

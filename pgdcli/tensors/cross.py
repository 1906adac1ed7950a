"""Tensor-train cross approximation: a tensor from the values at a few chosen fibres.

A function ``F(i_1, ..., i_d)`` on a tensor grid that can only be evaluated
entry by entry (here: a function of the march's tensor-train state, such as
``sin(th)``, whose values at any index come from the state's cores) is
approximated in tensor-train form by the two-site DMRG cross of Savostyanov &
Oseledets (2011): left index sets ``I_k`` (rows of multi-indices for modes
``< k``) and right index sets ``J_k`` (modes ``>= k``) define, for a pair of
modes ``(k, k+1)``, the *supercore* ``F[I_k, i_k, i_{k+1}, J_{k+2}]`` of
``r_k n_k n_{k+1} r_{k+2}`` values. Its truncated SVD gives the new rank (rank
adaptivity: ranks grow or shrink to what the tolerance needs) and the
maximum-volume rows of its left factor (:func:`maxvol`) the new ``I_{k+1}``
(sweeping left to right; right to left the columns give ``J_{k+1}``). The
cores are the interpolation form ``U U[rows]^-1``, so the train reproduces
``F`` exactly at the chosen crosses.

Convergence is measured, not assumed: after every sweep the new train is
compared with the previous one over the whole grid (the root mean square of
their difference, computed in tensor-train form), and the cross stops when the
change falls below the tolerance twice in a row. A rank that reaches
``max_rank`` or a sweep budget that runs out is reported (``converged`` False,
``message``), never hidden; callers decide what to do with the train
(the march keeps it and the error gate judges the codebook).

For grids of at most ``dense_limit`` points the tensor is evaluated whole and
compressed by TT-SVD (:func:`tt_from_full`), which is cheaper than any cross.

This module imports numpy, scipy.linalg and :mod:`pgdcli.tensors.tt` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
from scipy.linalg import qr

from .tt import TT, tt_round, tt_sum
from .tt_svd import truncation_rank, tt_from_full

__all__ = ["CrossResult", "tt_cross", "tt_from_full", "maxvol", "tt_values_at", "tt_point_function"]

#: Rows whose coefficient in the basis of the chosen rows exceeds this are swapped in (maxvol).
MAXVOL_TOLERANCE = 1.05
#: Nodes of the modes a train varies along up to which :func:`tt_point_function` tabulates it.
TABLE_LIMIT = 2 ** 16
#: Share of the tolerance given to the truncation of each supercore.
TRUNCATION_SHARE = 0.5


@dataclass
class CrossResult:
    """What :func:`tt_cross` produced and how it got there.

    Attributes
    ----------
    train : TT
    converged : bool
        The root-mean-square change of the last sweep(s) met the tolerance without
        reaching the rank cap.
    change : float
        Root-mean-square change over the grid of the last sweep.
    evaluations : int
        Values of the function asked for.
    sweeps : int
    message : str
        Why it stopped.
    right_sets : list of ndarray
        The final right index sets (a warm start for a similar function).
    """

    train: TT
    converged: bool
    change: float
    evaluations: int
    sweeps: int
    message: str
    right_sets: list = field(default_factory=list)


def tt_values_at(train: TT, indices: np.ndarray) -> np.ndarray:
    """Entries of a train at multi-indices.

    Parameters
    ----------
    train : TT, order d
    indices : ndarray of int, shape (P, d)

    Returns
    -------
    ndarray, shape (P,)
    """
    return tt_point_function(train)(indices)


def tt_point_function(train: TT):
    """``indices (P, d) -> entries (P,)`` of a train, for many calls.

    The modes whose slices are the same at every node (a coefficient free of that coordinate) are
    multiplied together once, here; when the other modes span at most :data:`TABLE_LIMIT` nodes, the
    train's entries over them are tabulated once and each call is one gather (a coefficient of one to
    three coordinates: much cheaper than contracting the cores at every call).
    """
    steps, pending = [], np.ones((1, 1))
    for k, core in enumerate(train.cores):
        # equal slices up to rounding (a separated constant's unit vectors): folded, an error of ~1e-16
        if np.max(np.ptp(core, axis=1), initial=0.0) <= 1e-14 * np.max(np.abs(core), initial=0.0):
            pending = pending @ core[:, 0, :]
        else:
            steps.append((pending, k, core))
            pending = np.eye(core.shape[2])
    last = pending
    modes = [k for _, k, _ in steps]
    dims = tuple(train.cores[k].shape[1] for k in modes)
    if int(np.prod(dims, dtype=float)) <= TABLE_LIMIT:
        cores = [np.tensordot(matrix, core, axes=(1, 0)) for matrix, _, core in steps]
        if not cores:
            return lambda indices: np.full(len(indices), float(last[0, 0]))
        cores[-1] = np.tensordot(cores[-1], last, axes=(2, 0))
        table = TT(cores).full().reshape(-1)
        return lambda indices: table[np.ravel_multi_index(tuple(indices[:, modes].T), dims)]

    def values(indices: np.ndarray) -> np.ndarray:
        v = np.ones((len(indices), 1))
        for matrix, k, core in steps:
            v = v @ matrix
            if core.shape[0] == 1 and core.shape[2] == 1:  # rank one here: one gather
                v = v * core[0, indices[:, k], 0][:, None]
            else:
                v = np.einsum("pa,apb->pb", v, core[:, indices[:, k], :])
        return (v @ last)[:, 0]

    return values


def maxvol(a: np.ndarray, tolerance: float = MAXVOL_TOLERANCE, max_iterations: int = 200) -> np.ndarray:
    """Rows of a tall matrix spanning a submatrix of (locally) maximum volume.

    Parameters
    ----------
    a : ndarray, shape (n, r), n >= r, full column rank
    tolerance : float
        Stop when every coefficient of ``a`` in the basis of the chosen rows is at most this.

    Returns
    -------
    ndarray of int, shape (r,)
        Distinct row indices; ``a @ inv(a[rows])`` has entries bounded by ``tolerance``.
    """
    n, r = a.shape
    if n <= r:
        return np.arange(n)
    # a column-pivoted QR of a^T picks well-conditioned rows to start from (Goreinov et al.)
    _, _, pivots = qr(a.T, mode="economic", pivoting=True)
    rows = np.array(pivots[:r])
    b = np.linalg.solve(a[rows].T, a.T).T  # (n, r): coefficients in the chosen rows
    for _ in range(max_iterations):
        i, j = np.unravel_index(np.argmax(np.abs(b)), b.shape)
        if abs(b[i, j]) <= tolerance:
            break
        # swap row rows[j] for row i: rank-one update of the coefficients (Sherman-Morrison)
        bj = b[:, j].copy()
        bi = b[i, :].copy()
        bi[j] -= 1.0
        b -= np.outer(bj, bi / b[i, j])
        rows[j] = i
    return rows


def _random_right_sets(shape: Sequence[int], rank: int, rng: np.random.Generator) -> list[np.ndarray]:
    """``J_k`` for k = 1..d (``J_d`` empty): random multi-indices of modes k..d-1, ``rank`` rows each."""
    d = len(shape)
    sets = [None] * (d + 1)
    sets[d] = np.zeros((1, 0), dtype=int)
    for k in range(d - 1, 0, -1):
        r = min(rank, int(np.prod(shape[k:], dtype=float)))
        sets[k] = np.stack([rng.integers(0, n, size=r) for n in shape[k:]], axis=1)
    return sets


def _supercore_indices(left: np.ndarray, n1: int, n2: int, right: np.ndarray) -> np.ndarray:
    """All multi-indices ``(I, i, j, J)`` of a supercore, in C order of (left row, i, j, right row)."""
    r0, r1 = left.shape[0], right.shape[0]
    a, i, j, b = np.meshgrid(np.arange(r0), np.arange(n1), np.arange(n2), np.arange(r1), indexing="ij")
    return np.concatenate([left[a.ravel()], i.reshape(-1, 1), j.reshape(-1, 1), right[b.ravel()]], axis=1)


def tt_cross(function: Callable[[np.ndarray], np.ndarray], shape: Sequence[int], tolerance: float, *,
             max_rank: int = 200, max_sweeps: int = 12, rng: np.random.Generator | None = None,
             right_sets: list | None = None, dense_limit: int = 4096,
             full: Callable[[], np.ndarray] | None = None) -> CrossResult:
    """Tensor-train approximation of a function on a grid from values at chosen fibres.

    Parameters
    ----------
    function : callable
        ``function(indices)`` with ``indices`` an int array of shape (P, d) returns the P
        values (float array of shape (P,)); non-finite values make the cross fail.
    shape : sequence of int
        Grid ``(n_1, ..., n_d)``.
    tolerance : float
        Root-mean-square accuracy over the grid (absolute).
    max_rank : int
        Cap on every rank: reaching it ends the cross, not converged.
    max_sweeps : int
        Cap on half-sweeps (left to right or right to left).
    rng : numpy Generator, optional
        For the starting index sets.
    right_sets : list of ndarray, optional
        Right index sets of an earlier cross of a similar function (warm start).
    dense_limit : int
        Grids of at most this many points are evaluated whole (TT-SVD).
    full : callable, optional
        ``full()`` returns the whole tensor, shape ``shape`` (a faster way than ``function`` on
        every index, used by the whole-grid path).

    Returns
    -------
    CrossResult
    """
    shape = tuple(int(n) for n in shape)
    d = len(shape)
    size = int(np.prod(shape, dtype=float))
    if d == 1 or size <= dense_limit:
        if full is not None:
            values = np.asarray(full(), dtype=float).reshape(shape)
        else:
            grid = np.stack([g.ravel() for g in np.meshgrid(*[np.arange(n) for n in shape], indexing="ij")], axis=1)
            values = np.asarray(function(grid), dtype=float).reshape(shape)
        if not np.all(np.isfinite(values)):
            return CrossResult(TT([np.zeros((1, n, 1)) for n in shape]), False, np.inf, size, 0,
                               "the function is not finite at some grid points")
        train = tt_from_full(values, tolerance * np.sqrt(size))
        if max(train.ranks, default=1) > max_rank:
            return CrossResult(tt_round(train, absolute=0.0, max_rank=max_rank), False, np.inf, size, 0,
                               f"rank {max(train.ranks)} above the cap {max_rank}")
        return CrossResult(train, True, 0.0, size, 0, "evaluated on the whole grid")
    return _DmrgCross(function, shape, tolerance, max_rank, rng or np.random.default_rng(0), right_sets).run(max_sweeps)


class _DmrgCross:
    """One two-site DMRG cross (see the module docstring)."""

    def __init__(self, function, shape, tolerance, max_rank, rng, right_sets):
        self.function, self.shape, self.max_rank = function, shape, max_rank
        self.d = d = len(shape)
        self.size = float(np.prod(shape, dtype=float))
        self.tolerance = tolerance
        valid = right_sets is not None and len(right_sets) == d + 1 and all(
            s is not None and s.shape[1] == d - k for k, s in enumerate(right_sets) if k > 0)
        self.right = list(right_sets) if valid else _random_right_sets(shape, 2, rng)
        self.left = [np.zeros((1, 0), dtype=int)] + [None] * d
        self.evaluations = 0
        self.capped = False

    def supercore(self, k: int) -> np.ndarray:
        """``F[I_k, i_k, i_{k+1}, J_{k+2}]``, shape (r_k, n_k, n_{k+1}, r_{k+2})."""
        left, right = self.left[k], self.right[k + 2]
        idx = _supercore_indices(left, self.shape[k], self.shape[k + 1], right)
        values = np.asarray(self.function(idx), dtype=float)
        self.evaluations += values.size
        if not np.all(np.isfinite(values)):
            raise FloatingPointError("the function is not finite at some grid points")
        return values.reshape(left.shape[0], self.shape[k], self.shape[k + 1], right.shape[0])

    def split(self, block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Truncated SVD of a supercore unfolded (r_k n_k) x (n_{k+1} r_{k+2})."""
        r0, n1, n2, r1 = block.shape
        u, s, vt = np.linalg.svd(block.reshape(r0 * n1, n2 * r1), full_matrices=False)
        # the supercore samples r0 n1 n2 r1 of the grid's entries: an RMS tolerance per entry, half
        # of it, so that two sweeps truncated differently (left, right) differ by less than the tolerance
        rank = truncation_rank(s, TRUNCATION_SHARE * self.tolerance * np.sqrt(block.size / (self.d - 1)))
        if rank > self.max_rank:
            self.capped = True
            rank = self.max_rank
        return u[:, :rank], s[:rank], vt[:rank]

    def sweep_right(self) -> list[np.ndarray]:
        cores = [None] * self.d
        for k in range(self.d - 1):
            block = self.supercore(k)
            r0, n1, n2, r1 = block.shape
            u, s, vt = self.split(block)
            rows = maxvol(u)
            cores[k] = np.linalg.solve(u[rows].T, u.T).T.reshape(r0, n1, -1)
            a, i = np.divmod(rows, n1)
            self.left[k + 1] = np.concatenate([self.left[k][a], i.reshape(-1, 1)], axis=1)
            if k == self.d - 2:
                cores[k + 1] = ((u[rows] * s) @ vt).reshape(-1, n2, r1)
        return cores

    def sweep_left(self) -> list[np.ndarray]:
        cores = [None] * self.d
        for k in range(self.d - 2, -1, -1):
            block = self.supercore(k)
            r0, n1, n2, r1 = block.shape
            u, s, vt = self.split(block)
            v = vt.T  # (n2 r1, rank)
            cols = maxvol(v)
            cores[k + 1] = np.linalg.solve(v[cols].T, v.T).reshape(-1, n2, r1)
            j, b = np.divmod(cols, r1)
            self.right[k + 1] = np.concatenate([j.reshape(-1, 1), self.right[k + 2][b]], axis=1)
            if k == 0:
                cores[0] = (u * s @ v[cols].T).reshape(r0, n1, -1)
        return cores

    def run(self, max_sweeps: int) -> CrossResult:
        previous = None
        change = np.inf
        quiet = 0
        sweeps = 0
        message = f"no convergence in {max_sweeps} sweeps"
        try:
            for sweeps in range(1, max_sweeps + 1):
                cores = self.sweep_right() if sweeps % 2 == 1 else self.sweep_left()
                train = TT(cores)
                if previous is not None:
                    change = tt_sum([train, previous], [1.0, -1.0]).norm() / np.sqrt(self.size)
                    quiet = quiet + 1 if change <= self.tolerance else 0
                previous = train
                if self.capped:
                    message = f"a rank reached the cap {self.max_rank}"
                    break
                if quiet >= 2 or (quiet == 1 and change <= 1e-3 * self.tolerance):
                    message = f"converged in {sweeps} sweeps"
                    break
        except FloatingPointError as exc:
            zeros = TT([np.zeros((1, n, 1)) for n in self.shape])
            return CrossResult(zeros, False, np.inf, self.evaluations, sweeps, str(exc))
        converged = quiet >= 1 and not self.capped and message.startswith("converged")
        return CrossResult(previous, converged, change, self.evaluations, sweeps, message, list(self.right))

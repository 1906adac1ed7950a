"""Numerical separation of non-separable coefficients on the nodes of their coordinates.

A coefficient such as ``sin(w*t)``, ``exp(-k*x*t)`` or ``1/(1 + a*b)`` is not a
sum of products of one-coordinate functions, but on the nodes of the
coordinates it depends on it is a small tensor ``G[i_1, ..., i_m]`` that is
numerically of low rank when the function is smooth. This module approximates
that tensor to an absolute bound ``delta`` on its entries:

* two coordinates: the truncated SVD (Eckart-Young: the best rank-r
  approximation in the Frobenius norm, which bounds every entry);
* three or more: the TT-SVD of the node tensor (Oseledets 2011, each unfolding
  truncated to ``delta / sqrt(m - 1)`` so the total Frobenius error is at most
  ``delta``) when the tensor has at most :data:`DENSE_LIMIT` entries; beyond, a
  TT-cross approximation (:func:`tt_cross`: alternating maxvol-chosen fibres,
  Oseledets & Tyrtyshnikov 2010) that evaluates the function at a few fibres only.

The enrichment solver needs a canonical (CP) sum of Kronecker products: a tensor
train is expanded exactly into ``prod(ranks)`` rank-one terms (:func:`cp_from_tt`).
The march takes the tensor train itself.

Functions here only see arrays and callables; :mod:`pgdcli.discretization.coefficients` is the glue from
parsed coefficients (:class:`pgdcli.problem.expressions.Joint`) to node values.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

__all__ = ["DENSE_LIMIT", "MAX_SEPARATION_RANK", "Separation", "SeparationRankError", "tt_svd", "tt_cross",
           "cp_from_tt", "separate_function"]

#: Node tensors up to this many entries are separated from their full values (TT-SVD).
DENSE_LIMIT = 2_000_000
#: Cap on every rank of a separation (and ``solver.max_rank`` if lower): beyond it the coefficient
#: is refused, naming the rank reached.
MAX_SEPARATION_RANK = 100
class SeparationRankError(Exception):
    """A tensor that needs a rank above the cap; ``rank`` is the rank reached, ``error`` the bound left."""

    def __init__(self, rank: int, error: float):
        super().__init__(f"rank {rank} reached with error {error:.3g}")
        self.rank, self.error = rank, error


@dataclass
class Separation:
    """A node tensor in tensor-train form.

    Attributes
    ----------
    cores : list of ndarray
        ``cores[k]`` of shape (r_{k-1}, n_k, r_k), r_0 = r_m = 1.
    error : float
        Max abs error at the nodes (measured on the full tensor when it was formed, else the
        cross's estimate at its check points).
    method : str
        ``'svd'``, ``'tt-svd'`` or ``'tt-cross'``.
    """

    cores: list
    error: float
    method: str

    @property
    def ranks(self) -> tuple[int, ...]:
        return tuple(c.shape[2] for c in self.cores[:-1])

    @property
    def terms(self) -> int:
        """Rank-one terms of the canonical expansion (:func:`cp_from_tt`)."""
        return int(np.prod(self.ranks)) if self.ranks else 1


def _truncation_rank(s: np.ndarray, delta: float) -> int:
    """Smallest r with ``sqrt(sum_{i >= r} s_i^2) <= delta`` (at least 1)."""
    tail = np.sqrt(np.cumsum((s ** 2)[::-1]))[::-1]  # tail[r] = norm of s[r:]
    r = int(np.count_nonzero(tail > delta))
    return max(r, 1)


def tt_svd(tensor: np.ndarray, delta: float, max_rank: int = MAX_SEPARATION_RANK) -> list[np.ndarray]:
    """Tensor train of a full tensor with Frobenius error at most ``delta`` (TT-SVD).

    Parameters
    ----------
    tensor : ndarray, shape (n_1, ..., n_m)
    delta : float
        Absolute bound on the Frobenius norm of the error (so on every entry).
    max_rank : int

    Returns
    -------
    list of ndarray
        Cores (r_{k-1}, n_k, r_k).

    Raises
    ------
    SeparationRankError
        When an unfolding needs a rank above ``max_rank``.
    """
    shape = tensor.shape
    m = len(shape)
    if m == 1:
        return [tensor.reshape(1, -1, 1).astype(float)]
    local = delta / math.sqrt(m - 1)
    cores = []
    rest = np.asarray(tensor, dtype=float).reshape(1, -1)
    r = 1
    for k in range(m - 1):
        rest = rest.reshape(r * shape[k], -1)
        u, s, vt = np.linalg.svd(rest, full_matrices=False)
        rank = _truncation_rank(s, local)
        if rank > max_rank:
            raise SeparationRankError(max_rank, float(np.sqrt(np.sum(s[max_rank:] ** 2))))
        cores.append(u[:, :rank].reshape(r, shape[k], rank))
        rest = s[:rank, None] * vt[:rank]
        r = rank
    cores.append(rest.reshape(r, shape[-1], 1))
    return cores


def cp_from_tt(cores: Sequence[np.ndarray]) -> list[list[np.ndarray]]:
    """The exact canonical expansion of a tensor train: one rank-one term per multi-index of ranks.

    Parameters
    ----------
    cores : sequence of ndarray, shapes (r_{k-1}, n_k, r_k)

    Returns
    -------
    list of list of ndarray
        ``terms[i][k]`` of shape (n_k,): ``sum_i outer(terms[i][0], ..., terms[i][m-1])`` equals the train.
    """
    ranks = [c.shape[2] for c in cores[:-1]]
    terms = []
    for index in itertools.product(*(range(r) for r in ranks)):
        left = (0,) + index
        right = index + (0,)
        terms.append([np.array(c[a, :, b]) for c, a, b in zip(cores, left, right)])
    return terms


def _full(cores: Sequence[np.ndarray]) -> np.ndarray:
    out = cores[0][0]
    for c in cores[1:]:
        out = np.tensordot(out, c, axes=(-1, 0))
    return out[..., 0]


def _maxvol(a: np.ndarray, iterations: int = 100, tau: float = 1.05) -> np.ndarray:
    """Rows of a tall (n, r) matrix whose r x r submatrix has a locally maximal volume."""
    n, r = a.shape
    if n <= r:
        return np.arange(n)
    _, _, piv = _qr_pivoted(a.T)
    rows = piv[:r].copy()
    for _ in range(iterations):
        b = np.linalg.solve(a[rows].T, a.T).T  # (n, r): a = b a[rows]
        i, j = np.unravel_index(np.argmax(np.abs(b)), b.shape)
        if abs(b[i, j]) <= tau:
            break
        rows[j] = i
    return rows


def _qr_pivoted(a: np.ndarray):
    import scipy.linalg

    return scipy.linalg.qr(a, mode="economic", pivoting=True)


def tt_cross(function: Callable[[np.ndarray], np.ndarray], shape: Sequence[int], delta: float, *,
             max_rank: int = MAX_SEPARATION_RANK, seed: int = 0, sweeps: int = 16) -> Separation:
    """A tensor train of ``function`` on an index grid from a few of its fibres (TT-cross).

    Left-to-right sweeps: at each mode the function is evaluated on the fibres
    ``(left indices) x (all n_k) x (right indices)``, the unfolding is factored by a truncated
    SVD, the core is the interpolating ``Q Q[rows]^-1`` on the maxvol rows of its left factor,
    and those rows are the next mode's left indices (a skeleton decomposition per mode:
    Oseledets & Tyrtyshnikov 2010). The right index sets are random fibres, doubled wherever an
    unfolding shows no small singular value, until the train agrees with the function at 1000
    random entries to ``delta``.

    Parameters
    ----------
    function : callable
        ``function(index)`` with ``index`` an int array (N, m) of grid indices -> (N,) values.
    shape : sequence of int
    delta : float
        Target max abs error.
    max_rank, seed, sweeps : int

    Returns
    -------
    Separation
        ``error`` is the max abs error measured at the 1000 random entries.

    Raises
    ------
    SeparationRankError
        When the rank would exceed ``max_rank`` or the sweeps do not reach ``delta``.
    """
    rng = np.random.default_rng(seed)
    m = len(shape)
    check = np.column_stack([rng.integers(0, n, 1000) for n in shape])
    exact = function(check)
    # left[k]: index sets (r, k) of modes < k; right[k]: (r, m - k) of modes >= k
    left = [np.zeros((1, 0), dtype=int)] + [None] * m
    right = [None] * m + [np.zeros((1, 0), dtype=int)]
    for k in range(m - 1, 0, -1):
        right[k] = np.column_stack([rng.integers(0, n, KICK) for n in shape[k:]])
    error, rank_reached = math.inf, 1
    for _ in range(sweeps):
        cores = []
        for k in range(m):  # left to right: cores and new left sets
            values = _fibres(function, left[k], shape[k], right[k + 1])
            rl, n, rr = values.shape
            if k == m - 1:
                cores.append(values)
                break
            q, rank = _range(values.reshape(rl * n, rr), delta / math.sqrt(m), max_rank)
            rank_reached = max(rank_reached, rank)
            rows = _maxvol(q)
            cores.append(np.linalg.solve(q[rows].T, q.T).T.reshape(rl, n, q.shape[1]))
            left[k + 1] = np.concatenate([left[k][rows // n], (rows % n)[:, None]], axis=1)
        error = float(np.max(np.abs(_evaluate_at(cores, check) - exact)))
        if error <= delta:
            return Separation(cores, error, "tt-cross")
        for k in range(m - 1, 0, -1):  # right to left: new right sets
            values = _fibres(function, left[k], shape[k], right[k + 1])
            rl, n, rr = values.shape
            q, rank = _range(values.reshape(rl, n * rr).T, delta / math.sqrt(m), max_rank)
            rank_reached = max(rank_reached, rank)
            rows = _maxvol(q)
            right[k] = _kicked(np.concatenate([(rows // rr)[:, None], right[k + 1][rows % rr]], axis=1), shape[k:],
                               rng)
    raise SeparationRankError(rank_reached, error)


#: Random indices added to every index set of a cross sweep, so that ranks can grow.
KICK = 3


def _fibres(function, left: np.ndarray, n: int, right: np.ndarray) -> np.ndarray:
    """``function`` on (left sets) x (all n) x (right sets): shape (r_left, n, r_right)."""
    rl, rr = left.shape[0], right.shape[0]
    grid = np.concatenate([
        np.repeat(left, n * rr, axis=0),
        np.tile(np.repeat(np.arange(n), rr), rl)[:, None],
        np.tile(right, (rl * n, 1)),
    ], axis=1)
    return function(grid).reshape(rl, n, rr)


def _range(a: np.ndarray, delta: float, max_rank: int) -> tuple[np.ndarray, int]:
    """Orthonormal basis of the numerical range of ``a`` (truncated SVD) and its rank."""
    u, s, _ = np.linalg.svd(a, full_matrices=False)
    rank = _truncation_rank(s, delta)
    if rank > max_rank:
        raise SeparationRankError(max_rank, float(np.sqrt(np.sum(s[max_rank:] ** 2))))
    return u[:, :rank], rank


def _kicked(sets: np.ndarray, shape: Sequence[int], rng: np.random.Generator) -> np.ndarray:
    """Index sets plus :data:`KICK` random ones (duplicates removed)."""
    extra = np.column_stack([rng.integers(0, n, KICK) for n in shape])
    return np.unique(np.concatenate([sets, extra]), axis=0)


def _evaluate_at(cores: Sequence[np.ndarray], index: np.ndarray) -> np.ndarray:
    """Entries of a train at integer indices (N, m)."""
    out = cores[0][0][index[:, 0]]  # (N, r_1)
    for k in range(1, len(cores)):
        out = np.einsum("na,anb->nb", out, cores[k][:, index[:, k], :])
    return out[:, 0]


def separate_function(function: Callable[[Mapping[str, np.ndarray]], np.ndarray], nodes: Mapping[str, np.ndarray],
                      delta: float, max_rank: int = MAX_SEPARATION_RANK) -> Separation:
    """Separate ``function`` (of coordinate name -> node values, vectorized) on the grid of ``nodes``.

    Parameters
    ----------
    function : callable
        Values at broadcast arrays of coordinates.
    nodes : mapping of str to ndarray (n_k,)
        The coordinates in the order of the train.
    delta : float
        Target max abs error at the nodes.

    Raises
    ------
    SeparationRankError
    FloatingPointError
        When the function is not finite at some node.
    """
    names = list(nodes)
    shape = tuple(nodes[c].size for c in names)
    if int(np.prod(shape)) <= DENSE_LIMIT:
        grids = np.meshgrid(*(nodes[c] for c in names), indexing="ij")
        with np.errstate(all="ignore"):
            full = np.broadcast_to(function(dict(zip(names, grids))), shape).astype(float)
        if not np.all(np.isfinite(full)):
            raise FloatingPointError("not finite at some nodes")
        cores = tt_svd(full, delta, max_rank)
        error = float(np.max(np.abs(_full(cores) - full)))
        return Separation(cores, error, "svd" if len(names) == 2 else "tt-svd")

    def at_index(index: np.ndarray) -> np.ndarray:
        with np.errstate(all="ignore"):
            values = np.asarray(function({c: nodes[c][index[:, k]] for k, c in enumerate(names)}), dtype=float)
        values = np.broadcast_to(values, (index.shape[0],))
        if not np.all(np.isfinite(values)):
            raise FloatingPointError("not finite at some nodes")
        return values

    return tt_cross(at_index, shape, delta, max_rank=max_rank)

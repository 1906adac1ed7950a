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
  ``delta``) when the tensor has at most :data:`DENSE_LIMIT` entries; beyond, the
  DMRG cross of :mod:`pgdcli.tensors.cross` (the march's, for functions of the
  unknowns) from a few fibres, its max error measured at random entries.

Both come from :mod:`pgdcli.tensors.cross`; this module adds the rank cap, the
max-error measurement and the refusal (:class:`SeparationRankError`).

The enrichment solver needs a canonical (CP) sum of Kronecker products: a tensor
train is expanded exactly into ``prod(ranks)`` rank-one terms (:func:`cp_from_tt`).
The march takes the tensor train itself.

Functions here only see arrays and callables; :mod:`pgdcli.discretization.coefficients` is the glue from
parsed coefficients (:class:`pgdcli.problem.expressions.Joint`) to node values.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import numpy as np

from ..tensors.cross import tt_cross as cross_approximation
from ..tensors.cross import tt_from_full, tt_values_at
from ..tensors.tt import TT, tt_round

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
        When an unfolding needs a rank above ``max_rank``: the rank is the cap, the error the
        largest entry left by the train truncated to it.
    """
    tensor = np.asarray(tensor, dtype=float)
    train = tt_from_full(tensor, delta)
    if max(train.ranks, default=1) > max_rank:
        capped = tt_round(train, absolute=0.0, max_rank=max_rank)
        raise SeparationRankError(max_rank, float(np.max(np.abs(capped.full() - tensor))))
    return list(train.cores)


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
    return TT(cores).full()


#: Random entries at which a cross's max error is measured (not its own fibres).
CHECK_ENTRIES = 1000
#: Crosses of one function at ever tighter root-mean-square targets before the refusal.
CROSS_ATTEMPTS = 3


def tt_cross(function: Callable[[np.ndarray], np.ndarray], shape: Sequence[int], delta: float, *,
             max_rank: int = MAX_SEPARATION_RANK, seed: int = 0) -> Separation:
    """A tensor train of ``function`` on an index grid from a few of its fibres, to a max error ``delta``.

    The DMRG cross of :func:`pgdcli.tensors.cross.tt_cross` converges in the
    root-mean-square over the grid; a separation promises a max abs error, so
    the train is measured at :data:`CHECK_ENTRIES` random entries and the cross
    repeated with a target ten times tighter while it misses (at most
    :data:`CROSS_ATTEMPTS` crosses, the last one's index sets as the next start).

    Parameters
    ----------
    function : callable
        ``function(index)`` with ``index`` an int array (N, m) of grid indices -> (N,) values.
    shape : sequence of int
    delta : float
        Target max abs error.
    max_rank, seed : int

    Returns
    -------
    Separation
        ``error`` is the max abs error measured at the random entries.

    Raises
    ------
    SeparationRankError
        When the rank reaches ``max_rank`` or the crosses do not reach ``delta``.
    """
    rng = np.random.default_rng(seed)
    check = np.column_stack([rng.integers(0, n, CHECK_ENTRIES) for n in shape])
    exact = function(check)
    target, right_sets, error, rank = 0.5 * delta, None, np.inf, 1
    for _ in range(CROSS_ATTEMPTS):
        result = cross_approximation(function, shape, target, max_rank=max_rank, rng=rng, right_sets=right_sets,
                                     dense_limit=0)
        rank = max(result.train.ranks, default=1)
        error = float(np.max(np.abs(tt_values_at(result.train, check) - exact)))
        if error <= delta and rank <= max_rank and result.converged:
            return Separation(list(result.train.cores), error, "tt-cross")
        if rank >= max_rank:
            break
        target, right_sets = target / 10.0, result.right_sets
    raise SeparationRankError(rank, error)


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

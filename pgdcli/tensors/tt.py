"""Tensor trains: the rank-adaptive separated format of the nonlinear solver.

A tensor train (TT) of order ``d`` stores a function on a tensor grid as

    X[i_1, ..., i_d] = G_1[:, i_1, :] @ G_2[:, i_2, :] @ ... @ G_d[:, i_d, :]

with cores ``G_k`` of shape ``(r_{k-1}, n_k, r_k)`` and ``r_0 = r_d = 1``.
Sums concatenate cores (ranks add), Hadamard products take Kronecker products
of core slices (ranks multiply) and :func:`round` brings the ranks back down
with a QR sweep followed by truncated SVDs (Oseledets 2011), which is
SVD-robust and rank-adaptive: the truncation error is bounded by the
requested relative tolerance in the Frobenius norm. The sweeps themselves, on plain
lists of cores, are in :mod:`pgdcli.tensors.tt_sweeps`.

This module imports numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .tt_allocate import truncate_allocated
from .tt_sweeps import orthogonalize_left, orthogonalize_right, pad_ranks, round_stacked, truncate_sweep

__all__ = ["TT", "tt_round", "tt_round_shared", "tt_round_many", "tt_sum", "tt_hadamard", "tt_rank_one",
           "tt_constant", "tt_ones", "tt_centre_cores", "tt_concatenate", "is_ones"]


_IDENTITY: dict[int, tuple[int, ...]] = {}


def _identity(d: int) -> tuple[int, ...]:
    order = _IDENTITY.get(d)
    if order is None:
        order = _IDENTITY.setdefault(d, tuple(range(d)))
    return order


@dataclass(frozen=True, eq=False)
class TT:
    """A tensor train.

    Parameters
    ----------
    cores : sequence of ndarray
        ``cores[k]`` has shape ``(r_{k-1}, n_k, r_k)`` with ``r_0 = r_d = 1``.
    mode_order : sequence of int, optional
        The mode (coordinate) of each core, a permutation of ``range(d)``; default: core ``k``
        is mode ``k``. A codebook's train keeps its time coordinate's core first whatever the
        coordinates' order; :attr:`shape`, :meth:`full` and :meth:`evaluate` are in mode order.
    """

    cores: tuple[np.ndarray, ...]
    mode_order: tuple[int, ...]

    def __init__(self, cores: Sequence[np.ndarray], mode_order: Sequence[int] | None = None):
        cs = tuple(np.asarray(c, dtype=float) for c in cores)
        if not cs:
            raise ValueError("a tensor train needs at least one core")
        for k, c in enumerate(cs):
            if c.ndim != 3:
                raise ValueError(f"core {k} must be 3D (r_{k}, n_{k + 1}, r_{k + 1}), got shape {c.shape}")
            if k and c.shape[0] != cs[k - 1].shape[2]:
                raise ValueError(f"core {k} has left rank {c.shape[0]}, core {k - 1} right rank {cs[k - 1].shape[2]}")
        if cs[0].shape[0] != 1 or cs[-1].shape[2] != 1:
            raise ValueError("the first core's left rank and the last core's right rank must be 1")
        if mode_order is None:
            order = _identity(len(cs))
        else:
            order = tuple(int(j) for j in mode_order)
            if sorted(order) != list(range(len(cs))):
                raise ValueError(f"mode order {list(order)} is not a permutation of the {len(cs)} cores' modes "
                                 f"0..{len(cs) - 1}")
        object.__setattr__(self, "cores", cs)
        object.__setattr__(self, "mode_order", order)

    @property
    def order(self) -> int:
        return len(self.cores)

    @property
    def shape(self) -> tuple[int, ...]:
        """Nodes per mode, in mode order (``shape[mode_order[k]]`` is core ``k``'s middle size)."""
        out = [0] * len(self.cores)
        for c, j in zip(self.cores, self.mode_order):
            out[j] = c.shape[1]
        return tuple(out)

    @property
    def ranks(self) -> tuple[int, ...]:
        """Inner ranks ``(r_1, ..., r_{d-1})``."""
        return tuple(c.shape[2] for c in self.cores[:-1])

    @property
    def rank(self) -> int:
        """Largest inner rank (1 for one core): what a codebook reports as the train's modes."""
        return int(max(self.ranks, default=1))

    @property
    def size(self) -> int:
        """Number of stored floats."""
        return int(sum(c.size for c in self.cores))

    def full(self) -> np.ndarray:
        """The full tensor in mode order (small tensors only: tests, plots)."""
        out = self.cores[0][0]
        for c in self.cores[1:]:
            out = np.tensordot(out, c, axes=(-1, 0))
        out = out[..., 0]
        if self.mode_order == _identity(len(self.cores)):
            return out
        return np.transpose(out, np.argsort(self.mode_order))

    def evaluate(self, matrices: Sequence[np.ndarray]) -> np.ndarray:
        """Contract every mode with a matrix of rows, point by point: the reference contraction.

        ``v_p = prod_k sum_i M_{j_k}[p, i] G_k[:, i, :]`` with ``j_k = mode_order[k]``. With the
        cardinal (interpolation) rows of points it gives the train's values there, with derivative
        rows in one mode's place a derivative. Simple rather than fast; the codebook's evaluation
        paths are tested against it.

        Parameters
        ----------
        matrices : sequence of ndarray, each shape (P, n_j)
            One per mode, in mode order.

        Returns
        -------
        ndarray, shape (P,)
        """
        if len(matrices) != self.order:
            raise ValueError(f"{len(matrices)} row matrices for a tensor train of order {self.order}")
        v = None
        for c, j in zip(self.cores, self.mode_order):
            m = matrices[j]
            if np.shape(m)[1:] != (c.shape[1],):
                raise ValueError(f"row matrix {j} has shape {np.shape(m)}, expected (P, {c.shape[1]})")
            s = np.einsum("pi,aib->pab", m, c)  # (P, r_{k-1}, r_k): each point's core slice
            v = s[:, 0, :] if v is None else np.einsum("pa,pab->pb", v, s)
        return v[:, 0]

    def __add__(self, other: "TT") -> "TT":
        return tt_sum([self, other])

    def __mul__(self, other) -> "TT":
        if isinstance(other, TT):
            return tt_hadamard(self, other)
        return self.scaled(float(other))

    __rmul__ = __mul__

    def scaled(self, s: float) -> "TT":
        cores = list(self.cores)
        cores[0] = cores[0] * s
        return TT(cores, self.mode_order)

    def norm(self) -> float:
        """Frobenius norm via orthogonalization (accurate to rounding, no Gram cancellation)."""
        cores = orthogonalize_left(list(self.cores))
        return float(np.linalg.norm(cores[-1]))


def tt_constant(value: float, shape: Sequence[int]) -> TT:
    """The constant tensor ``value`` (rank 1)."""
    cores = [np.ones((1, n, 1)) for n in shape]
    cores[0] = cores[0] * value
    return TT(cores)


def tt_rank_one(vectors: Sequence[np.ndarray], weight: float = 1.0) -> TT:
    """``weight * v_1 (x) ... (x) v_d``."""
    cores = [np.asarray(v, dtype=float).reshape(1, -1, 1) for v in vectors]
    cores[0] = cores[0] * weight
    return TT(cores)


def _common_order(trains: Sequence[TT]) -> tuple[int, ...]:
    """The mode order of every train (ValueError naming the first train with another)."""
    order = trains[0].mode_order
    for i, t in enumerate(trains):
        if t.mode_order != order:
            raise ValueError(f"train {i} has mode order {list(t.mode_order)}, train 0 {list(order)}")
    return order


def tt_sum(terms: Sequence[TT], weights: Sequence[float] | None = None) -> TT:
    """``sum_i w_i X_i`` with block cores (ranks add; round afterwards)."""
    terms = list(terms)
    if weights is None:
        weights = [1.0] * len(terms)
    if len(terms) == 1:
        return terms[0].scaled(weights[0])
    order = _common_order(terms)
    d = terms[0].order
    cores = []
    for k in range(d):
        if d == 1:
            cores.append(sum(w * t.cores[0] for w, t in zip(weights, terms)))
            continue
        if k == 0:
            cores.append(np.concatenate([w * t.cores[0] for w, t in zip(weights, terms)], axis=2))
        elif k == d - 1:
            cores.append(np.concatenate([t.cores[k] for t in terms], axis=0))
        else:
            left = sum(t.cores[k].shape[0] for t in terms)
            right = sum(t.cores[k].shape[2] for t in terms)
            c = np.zeros((left, terms[0].cores[k].shape[1], right))
            a = b = 0
            for t in terms:
                ra, n, rb = t.cores[k].shape
                c[a:a + ra, :, b:b + rb] = t.cores[k]
                a += ra
                b += rb
            cores.append(c)
    return TT(cores, order)


def tt_hadamard(x: TT, y: TT) -> TT:
    """Elementwise product (ranks multiply; round afterwards)."""
    order = _common_order([x, y])
    cores = []
    for a, b in zip(x.cores, y.cores):
        ra, n, rb = a.shape
        sa, _, sb = b.shape
        cores.append((a[:, None, :, :, None] * b[None, :, :, None, :]).reshape(ra * sa, n, rb * sb))
    return TT(cores, order)


def tt_round(x: TT, tolerance: float = 0.0, *, absolute: float | None = None,
             max_rank: int | None = None, allocate: bool = False) -> TT:
    """Recompress to the smallest ranks within a Frobenius error bound.

    Right-to-left QR orthogonalization, then left-to-right truncated SVDs
    with per-step threshold ``delta / sqrt(d - 1)`` (TT-SVD rounding), where
    ``delta = tolerance * ||X||`` (relative) or ``absolute`` when given. The
    result differs from ``x`` by at most ``delta`` in the Frobenius norm, which
    bounds the largest entry error too. ``max_rank`` caps every rank (the
    bound then no longer holds; callers measure it). ``allocate``: the bonds'
    shares of ``delta`` chosen to keep the fewest values
    (:func:`pgdcli.tensors.tt_allocate.truncate_allocated`; no ``max_rank``).
    """
    d, order = x.order, x.mode_order
    cores = list(x.cores)
    if d == 1:
        return TT(cores, order)
    cores = orthogonalize_right(cores)
    norm = np.linalg.norm(cores[0])
    if norm == 0.0:
        return TT([np.zeros((1, c.shape[1], 1)) for c in cores], order)
    delta = tolerance * norm if absolute is None else absolute
    if allocate:
        if max_rank is not None:
            raise ValueError("tt_round: allocate does not take a max_rank")
        return TT(truncate_allocated(cores, delta), order)
    return TT(truncate_sweep(cores, delta / np.sqrt(d - 1), max_rank), order)


def tt_round_shared(firsts: Sequence[np.ndarray], shared: Sequence[np.ndarray], *, absolute: float,
                    allocate: bool = False) -> list[TT]:
    """:func:`tt_round` of the trains ``[first] + shared`` for every first core, ``shared`` orthogonalized once.

    Parameters
    ----------
    firsts : sequence of ndarray, each of shape (1, n_0, r_1)
    shared : sequence of ndarray
        Cores 1..d-1, common to all the trains (d >= 2).
    absolute : float
        Frobenius bound of each train's rounding.
    allocate : bool
        As :func:`tt_round`'s.
    """
    cores = orthogonalize_right([np.eye(shared[0].shape[0])[None]] + list(shared))
    carried = cores[0][0]  # (r_1, r_1'): what the orthogonalization moved into the first core
    trains = ([np.tensordot(first, carried, axes=(2, 0))] + cores[1:] for first in firsts)
    if allocate:
        return [TT(truncate_allocated(train, absolute)) for train in trains]
    return [TT(truncate_sweep(train, absolute / np.sqrt(len(shared)), None)) for train in trains]


def tt_round_many(trains: Sequence[TT], *, absolute: float, max_rank: int | None = None) -> list[TT]:
    """:func:`tt_round` of several trains of the same shape at once (batched linear algebra).

    The trains are zero-padded to common ranks and rounded together; each
    train keeps the largest rank any of them needs at a bond, so every
    train's error stays within ``absolute`` (Frobenius). One batched QR/SVD
    per bond replaces one call per train: the march spends its time here.
    """
    trains = list(trains)
    if len(trains) == 1:
        return [tt_round(trains[0], absolute=absolute, max_rank=max_rank)]
    d = trains[0].order
    if d == 1:
        return [tt_round(t, absolute=absolute, max_rank=max_rank) for t in trains]
    order = _common_order(trains)
    ranks = [1] + [max(t.cores[k].shape[2] for t in trains) for k in range(d - 1)] + [1]
    cores = [np.stack(cs) for cs in zip(*[pad_ranks(list(t.cores), ranks) for t in trains])]  # (B, r0, n, r1)
    cores = round_stacked(cores, absolute / np.sqrt(d - 1), max_rank)
    return [TT([c[i] for c in cores], order) for i in range(len(trains))]


def tt_concatenate(trains: Sequence[TT]) -> TT:
    """Concatenate trains along their first core's mode (ranks add; round afterwards).

    ``X[(m, i_1), i_2, ...] = trains[m][i_1, i_2, ...]``: block-row first core,
    block-diagonal inner cores, stacked last core.
    """
    trains = list(trains)
    d, order = trains[0].order, _common_order(trains)
    if d == 1:
        return TT([np.concatenate([t.cores[0] for t in trains], axis=1)], order)
    r1 = [t.cores[0].shape[2] for t in trains]
    first = np.zeros((1, sum(t.cores[0].shape[1] for t in trains), sum(r1)))
    row = col = 0
    for t, r in zip(trains, r1):
        n = t.cores[0].shape[1]
        first[0, row:row + n, col:col + r] = t.cores[0][0]
        row += n
        col += r
    cores = [first]
    for k in range(1, d - 1):
        rl = [t.cores[k].shape[0] for t in trains]
        rr = [t.cores[k].shape[2] for t in trains]
        c = np.zeros((sum(rl), trains[0].cores[k].shape[1], sum(rr)))
        a = b = 0
        for t, x, y in zip(trains, rl, rr):
            c[a:a + x, :, b:b + y] = t.cores[k]
            a += x
            b += y
        cores.append(c)
    cores.append(np.concatenate([t.cores[-1] for t in trains], axis=0))
    return TT(cores, order)


def tt_centre_cores(cores: Sequence[np.ndarray]) -> list[np.ndarray]:
    """For each position k, core k of the train orthogonalized around k.

    With the cores left of k left-orthogonal and those right of k
    right-orthogonal, the unfolding of the tensor along mode k is core k
    (reshaped to (n_k, r_{k-1} r_k)) times a matrix with orthonormal rows: its
    norms, SVD and Chebyshev tails are those of the whole tensor. One QR sweep
    each way, O(d) factorizations in all.
    """
    d = len(cores)
    right = orthogonalize_right([np.asarray(x, dtype=float) for x in cores])
    centres = [right[0]]
    for k in range(d - 1):
        r0, n, r1 = centres[-1].shape
        _, r = np.linalg.qr(centres[-1].reshape(r0 * n, r1))
        centres.append(np.tensordot(r, right[k + 1], axes=(1, 0)))
    return centres


_ONES: dict[tuple[int, ...], TT] = {}


def tt_ones(shape: Sequence[int]) -> TT:
    """The all-ones tensor (rank 1), the neutral factor of a Hadamard product.

    One shared instance per shape (trains are immutable), so :func:`is_ones`
    recognises it by identity: the march asks thousands of times per solve.
    """
    shape = tuple(int(n) for n in shape)
    ones = _ONES.get(shape)
    if ones is None:
        if len(_ONES) >= 64:
            _ONES.clear()
        ones = tt_constant(1.0, shape)
        for core in ones.cores:  # shared: an in-place change would raise, not corrupt it
            core.flags.writeable = False
        ones = _ONES.setdefault(shape, ones)
    return ones


def is_ones(t: TT) -> bool:
    if _ONES.get(t.shape) is t:
        return True
    return all(c.shape[0] == 1 and c.shape[2] == 1 and np.all(c == 1.0) for c in t.cores)


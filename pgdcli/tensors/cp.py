"""Separated (canonical polyadic) tensors and operators.

A separated tensor of order ``d`` is

    X = sum_r  w_r  x_r^(1) (x) x_r^(2) (x) ... (x) x_r^(d)

stored as weights ``w`` (shape (R,)) and one factor matrix per mode
(shape (n_j, R)), like TensorLy's ``CPTensor``. A separated operator is an
affine sum of Kronecker products of 1D matrices (pyMOR's ``LincombOperator``).
Nothing here ever forms a full tensor, except :meth:`CPTensor.full` which the
tests use on small examples.

Norms are computed by an orthogonal sweep (successive QR of Khatri-Rao
products) rather than from Gram matrices: a Gram product squares the
cancellation, so ``sqrt(w^T (G_1 * ... * G_d) w)`` cannot resolve a residual
below about 1e-8 of the size of its terms, while the sweep resolves it to
rounding level.
"""

from __future__ import annotations

import math

from dataclasses import dataclass
from functools import cached_property, lru_cache
from typing import Sequence

import numpy as np
import scipy.linalg

__all__ = ["CPTensor", "SeparatedOperator", "orthogonal_sweep", "separated_norm", "sweep_step", "sweep_order", "khatri_rao_rows"]


_GEQRF = scipy.linalg.get_lapack_funcs("geqrf", dtype=np.float64)


def _read_only(a: np.ndarray) -> np.ndarray:
    a.flags.writeable = False
    return a


def _as_factor(index: int, factor, rank: int | None) -> np.ndarray:
    f = np.asarray(factor, dtype=float)
    if f.ndim != 2:
        raise ValueError(f"factor {index} must be a 2D array (n_{index}, rank), got shape {f.shape}")
    if rank is not None and f.shape[1] != rank:
        raise ValueError(f"factor {index} has {f.shape[1]} columns, expected rank {rank} (from the weights)")
    return f


@dataclass(frozen=True, eq=False)
class CPTensor:
    """Weights and factor matrices of a separated tensor.

    Parameters
    ----------
    weights : array_like, shape (R,)
    factors : sequence of array_like, each shape (n_j, R)
    """

    weights: np.ndarray
    factors: tuple[np.ndarray, ...]

    def __init__(self, weights, factors: Sequence):
        w = np.asarray(weights, dtype=float).reshape(-1)
        fs = tuple(_as_factor(j, f, w.size) for j, f in enumerate(factors))
        if not fs:
            raise ValueError("a CPTensor needs at least one factor matrix")
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "factors", fs)

    @property
    def rank(self) -> int:
        return self.weights.size

    @property
    def shape(self) -> tuple[int, ...]:
        return tuple(f.shape[0] for f in self.factors)

    @property
    def order(self) -> int:
        return len(self.factors)

    def full(self) -> np.ndarray:
        """The full tensor, shape ``self.shape`` (small tensors only: tests)."""
        out = np.zeros(self.shape)
        for r in range(self.rank):
            term = np.array(self.weights[r])
            for f in self.factors:
                term = np.multiply.outer(term, f[:, r])
            out += term
        return out

    def norm(self) -> float:
        """Frobenius norm, accurate to rounding relative to the terms (orthogonal sweep)."""
        return separated_norm(self.weights, self.factors)

    def __add__(self, other: "CPTensor") -> "CPTensor":
        return CPTensor(
            np.concatenate([self.weights, other.weights]),
            [np.hstack([a, b]) for a, b in zip(self.factors, other.factors)],
        )

    def scaled(self, s: float) -> "CPTensor":
        return CPTensor(self.weights * s, self.factors)


def khatri_rao_rows(z: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Column-wise Kronecker product: ``out[(a, i), c] = z[a, c] * x[i, c]``.

    Parameters
    ----------
    z : ndarray, shape (r, C)
    x : ndarray, shape (n, C)

    Returns
    -------
    ndarray, shape (r * n, C)
    """
    return (z[:, None, :] * x[None, :, :]).reshape(-1, z.shape[1])


def sweep_step(z: np.ndarray | None, x: np.ndarray) -> np.ndarray:
    """One step of the orthogonal sweep: append mode ``x`` to the swept modes ``z``.

    Parameters
    ----------
    z : ndarray, shape (r, C), or None
        Result of the sweep over the previous modes (None: no mode yet).
    x : ndarray, shape (n, C)
        The next mode's factor matrix.

    Returns
    -------
    ndarray, shape (min(r n, C), C)
        The triangular factor of ``khatri_rao_rows(z, x)``, or that product
        itself while it has no more rows than columns (a QR would not shrink it).
    """
    if z is None:
        k, scratch = x, False
    else:
        k, scratch = _khatri_rao_fortran(z, x), True
    columns = k.shape[1]
    if k.shape[0] <= columns:
        return k
    # LAPACK directly on a Fortran-ordered product: numpy's qr would copy it and its wrapper
    # costs about a third of these (a few hundred rows by C) factorizations
    qr, _, _, info = _GEQRF(k, overwrite_a=scratch)
    if info != 0:
        raise np.linalg.LinAlgError(f"geqrf failed (info {info})")
    return np.triu(qr[:columns])


def _khatri_rao_fortran(z: np.ndarray, x: np.ndarray) -> np.ndarray:
    """:func:`khatri_rao_rows` in Fortran order (a view of a fresh array), for LAPACK."""
    out = np.empty((z.shape[1], z.shape[0], x.shape[0]))
    np.multiply(z.T[:, :, None], x.T[:, None, :], out=out)
    return out.reshape(z.shape[1], -1).T


def sweep_order(sizes: Sequence[int]) -> list[int]:
    """The modes in the order :func:`orthogonal_sweep` visits them: largest first.

    Once the row count saturates at C every step costs O(n_j C^3), so the
    small modes should come last.
    """
    return sorted(range(len(sizes)), key=lambda j: -sizes[j])


def orthogonal_sweep(factors: Sequence[np.ndarray]) -> np.ndarray:
    """Small matrix ``Z`` with ``vec(term_c) = Q @ Z[:, c]`` for an orthonormal ``Q``.

    Each column ``c`` of the factor matrices describes one rank-one term
    ``x_c^(1) (x) ... (x) x_c^(d)``. The sweep orthogonalizes mode by mode
    (QR of the Khatri-Rao product of the previous triangular factor with the
    next factor matrix, :func:`sweep_step`), so inner products and norms of
    any linear combination of the terms are those of the columns of ``Z``,
    computed with backward-stable Householder QR instead of Gram products.
    The modes may be visited in any order: ``Z`` is unique up to an
    orthogonal transformation on the left.

    Parameters
    ----------
    factors : sequence of ndarray, each shape (n_j, C)

    Returns
    -------
    ndarray, shape (r, C) with ``r <= C``
    """
    z = None
    for j in sweep_order([f.shape[0] for f in factors]):
        z = sweep_step(z, factors[j])
    return z


def _sweep_cost(sizes: Sequence[int], columns: int) -> int:
    """Rows factorized by a sweep over modes of these sizes in :func:`sweep_order` (QR flops / C^2)."""
    cost, rows = 0, 1
    for j in sweep_order(sizes):
        rows *= sizes[j]
        if rows > columns:
            cost += rows
            rows = columns
    return cost


@lru_cache(maxsize=256)
def _norm_split(sizes: tuple[int, ...], columns: int) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The split of the modes into two groups with the cheapest pair of sweeps (all splits tried)."""
    d = len(sizes)
    best = (_sweep_cost(sizes, columns), tuple(range(d)), ())
    for first, second in _candidate_splits(sizes):
        cost = (_sweep_cost([sizes[j] for j in first], columns)
                + _sweep_cost([sizes[j] for j in second], columns))
        if cost < best[0]:
            best = (cost, first, second)
    return best[1], best[2]


#: Modes up to which every split is tried (2^(d-1) of them); beyond, balanced splits only.
EXHAUSTIVE_SPLIT_MODES = 12


def _candidate_splits(sizes: tuple[int, ...]):
    """Pairs (first, second) of mode groups: every split for few modes, else a few balanced ones.

    The number of splits doubles with each mode, so beyond :data:`EXHAUSTIVE_SPLIT_MODES` only
    splits that balance the groups' products are tried (largest modes first, each to the group
    with the smaller product, from each of the first few modes as the seed of the second group).
    """
    d = len(sizes)
    if d <= EXHAUSTIVE_SPLIT_MODES:
        for mask in range(1, 2 ** (d - 1)):  # mode d - 1 always in the first group: each split once
            yield (tuple(j for j in range(d) if not mask >> j & 1), tuple(j for j in range(d) if mask >> j & 1))
        return
    order = sweep_order(sizes)
    logs = [math.log(max(n, 1)) for n in sizes]
    for seed in order[:4]:
        groups, weight = ([], [seed]), [0.0, logs[seed]]
        for j in order:
            if j != seed:
                k = 0 if weight[0] <= weight[1] else 1
                groups[k].append(j)
                weight[k] += logs[j]
        yield tuple(sorted(groups[0])), tuple(sorted(groups[1]))


def separated_norm(weights: np.ndarray, factors: Sequence[np.ndarray]) -> float:
    """Frobenius norm of ``sum_c w_c x_c^(1) (x) ... (x) x_c^(d)``, accurate to rounding.

    The modes are split into two groups, each reduced by an orthogonal sweep
    to coefficients ``Z_A`` (r_A, C) and ``Z_B`` (r_B, C) in orthonormal
    bases; the norm is then that of the (r_A, r_B) matrix
    ``Z_A diag(w) Z_B^T``, whose rounding error is that of the last step of a
    single sweep (a weighted sum of the terms). Two sweeps that each stop
    before the row count saturates at C cost far less than one that carries
    C rows through every remaining mode: for the 2D heat problem's six modes
    (23, 20, 20, 18, 2, 2) with C = 110, about a quarter of the QR work.

    Parameters
    ----------
    weights : ndarray, shape (C,)
    factors : sequence of ndarray, each shape (n_j, C)

    Returns
    -------
    float
    """
    if weights.size == 0:
        return 0.0
    first, second = _norm_split(tuple(f.shape[0] for f in factors), weights.size)
    za = orthogonal_sweep([factors[j] for j in first])
    if not second:
        return float(np.linalg.norm(za @ weights))
    zb = orthogonal_sweep([factors[j] for j in second])
    return float(np.linalg.norm((za * weights) @ zb.T))


@dataclass(frozen=True, eq=False)
class SeparatedOperator:
    """Sum of Kronecker products of square 1D matrices.

    ``A = sum_k  A_k^(1) (x) ... (x) A_k^(d)``; scalar coefficients are folded
    into the matrices.

    Parameters
    ----------
    terms : tuple of tuple of ndarray
        ``terms[k][j]`` has shape (m_j, n_j) (test size by trial size).
    """

    terms: tuple[tuple[np.ndarray, ...], ...]

    def __post_init__(self):
        if not self.terms:
            raise ValueError("a separated operator needs at least one term")
        d = len(self.terms[0])
        for k, term in enumerate(self.terms):
            if len(term) != d:
                raise ValueError(f"operator term {k} has {len(term)} modes, expected {d}")
            for j, m in enumerate(term):
                if np.ndim(m) != 2:
                    raise ValueError(f"operator term {k}, mode {j}: expected a matrix, got shape {np.shape(m)}")
                if m.shape != self.terms[0][j].shape:
                    raise ValueError(
                        f"operator term {k}, mode {j}: shape {m.shape} differs from term 0's {self.terms[0][j].shape}"
                    )

    @property
    def order(self) -> int:
        return len(self.terms[0])

    @property
    def n_terms(self) -> int:
        return len(self.terms)

    def mode_stack(self, j: int) -> np.ndarray:
        """All matrices of mode ``j``, shape (K, m_j, n_j) (computed once, read-only)."""
        return self._stacks[j]

    def mode_gram(self, j: int) -> np.ndarray:
        """``A_kj^T A_lj`` for every pair of terms, shape (K, K, n_j, n_j) (computed once, read-only)."""
        return self._grams[j]

    def mode_is_diagonal(self, j: int) -> bool:
        """True when every matrix of mode ``j`` is square and diagonal."""
        return self._diagonal[j]

    # The solver asks for these thousands of times per build: cached on the (immutable) operator.
    @cached_property
    def _stacks(self) -> tuple[np.ndarray, ...]:
        return tuple(_read_only(np.stack([term[j] for term in self.terms])) for j in range(self.order))

    @cached_property
    def _grams(self) -> tuple[np.ndarray, ...]:
        return tuple(_read_only(np.einsum("kam,lan->klmn", s, s)) for s in self._stacks)

    @cached_property
    def _diagonal(self) -> tuple[bool, ...]:
        out = []
        for s in self._stacks:
            off = s.copy()
            if s.shape[1] == s.shape[2]:
                idx = np.arange(s.shape[1])
                off[:, idx, idx] = 0.0
            out.append(s.shape[1] == s.shape[2] and not off.any())
        return tuple(out)

    def apply(self, x: CPTensor) -> CPTensor:
        """``A x`` as a separated tensor of rank ``K * x.rank`` (term-major columns)."""
        factors = [np.hstack([term[j] @ x.factors[j] for term in self.terms]) for j in range(self.order)]
        return CPTensor(np.tile(x.weights, self.n_terms), factors)

    def full(self) -> np.ndarray:
        """The full matrix (tests only): rows and columns in C order of the modes."""
        out = 0.0
        for term in self.terms:
            m = np.array([[1.0]])
            for a in term:
                m = np.kron(m, a)
            out = out + m
        return out

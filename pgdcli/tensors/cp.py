"""Separated (canonical polyadic) tensors and operators.

A separated tensor of order ``d`` is

    X = sum_r  w_r  x_r^(1) (x) x_r^(2) (x) ... (x) x_r^(d)

stored as weights ``w`` (shape (R,)) and one factor matrix per mode
(shape (n_j, R)), like TensorLy's ``CPTensor``. A separated operator is an
affine sum of Kronecker products of 1D matrices (pyMOR's ``LincombOperator``).
Nothing here ever forms a full tensor, except :meth:`CPTensor.full` (small
examples: tests, plots). :meth:`CPTensor.evaluate` is the reference contraction
at points that every fast evaluation of a codebook is tested against.

numpy only: a codebook's unknowns are these tensors, and ``pgd query`` never
imports scipy. Norms (orthogonal sweeps, LAPACK through scipy) are
:mod:`pgdcli.tensors.cp_sweep`'s.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Sequence

import numpy as np

__all__ = ["CPTensor", "SeparatedOperator"]


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

    @property
    def size(self) -> int:
        """Number of stored floats (the weights and the factors')."""
        return int(self.weights.size + sum(f.size for f in self.factors))

    def full(self) -> np.ndarray:
        """The full tensor, shape ``self.shape`` (small tensors only: tests, plots)."""
        letters = "abcdefghijklmnopqrstuvwxyz"[: self.order]
        expr = ",".join(f"{letter}r" for letter in letters) + ",r->" + letters
        out = np.zeros(self.shape)
        out += np.einsum(expr, *self.factors, self.weights)
        return out

    def evaluate(self, matrices: Sequence[np.ndarray]) -> np.ndarray:
        """Contract every mode with a matrix of rows, point by point: ``sum_r w_r prod_j (M_j F_j)[p, r]``.

        The reference contraction: with the cardinal (interpolation) rows of points it gives the
        tensor's values there, with derivative rows in one mode's place a derivative. Simple rather
        than fast; the codebook's evaluation paths are tested against it.

        Parameters
        ----------
        matrices : sequence of ndarray, each shape (P, n_j)
            One per mode.

        Returns
        -------
        ndarray, shape (P,)
        """
        if len(matrices) != self.order:
            raise ValueError(f"{len(matrices)} row matrices for a CPTensor of order {self.order}")
        product = np.ones((np.shape(matrices[0])[0], self.rank))
        for j, (m, f) in enumerate(zip(matrices, self.factors)):
            if np.shape(m)[1:] != (f.shape[0],):
                raise ValueError(f"row matrix {j} has shape {np.shape(m)}, expected (P, {f.shape[0]})")
            product = product * (m @ f)
        return product @ self.weights

    def norm(self) -> float:
        """Frobenius norm, accurate to rounding relative to the terms (orthogonal sweep)."""
        from .cp_sweep import separated_norm  # scipy: not at import (the query path uses this class)

        return separated_norm(self.weights, self.factors)

    def __add__(self, other: "CPTensor") -> "CPTensor":
        return CPTensor(
            np.concatenate([self.weights, other.weights]),
            [np.hstack([a, b]) for a, b in zip(self.factors, other.factors)],
        )

    def scaled(self, s: float) -> "CPTensor":
        return CPTensor(self.weights * s, self.factors)


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

"""TT-SVD of full tensors: exact (:func:`tt_from_full`) and with randomized ranges (:func:`tt_from_full_sketched`).

Both sweep left to right, split every unfolding at an absolute Frobenius bound
``absolute / sqrt(d - 1)`` and carry ``S V^T`` on (Oseledets 2011, Algorithm 1). The
sketched one finds each unfolding's column space from its product with a Gaussian
matrix a little wider than the expected rank (Halko, Martinsson, Tropp 2011) and
*measures* the part it misses, ``||M - Q Q^T M||_F``, widening the sketch until that
part fits half the unfolding's bound: the bound is met as surely as by the exact
SVD, at ``~3 m n l`` flops per ``m x n`` unfolding and sketch width ``l`` instead of
``~m n min(m, n)``. Small unfoldings, or sketches that reach 2/3 of the smaller side, go
through the exact SVD.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .cp_sweep import khatri_rao_rows, sweep_step
from .tt import TT
from .tt_allocate import rank_within

__all__ = ["RELATIVE_FLOOR", "tt_from_full", "tt_from_full_sketched", "tt_from_cp", "thin_svd", "truncation_rank"]

#: Relative floor of the singular values kept: exactly low-rank functions come out to rounding level.
RELATIVE_FLOOR = 1e-14
#: The expected rank of a first bond without a guess (a sketch too narrow is redone twice as wide).
FIRST_RANK_GUESS = 16
#: Columns added to the expected rank in a sketch.
OVERSAMPLING = 8
#: Unfoldings with fewer entries take the exact SVD (so do those whose sketch would pass 2/3 of the smaller side).
SKETCH_MIN_SIZE = 200_000


def tt_from_full(values: np.ndarray, absolute: float) -> TT:
    """The TT-SVD of a full tensor, within an absolute Frobenius error.

    Parameters
    ----------
    values : ndarray, shape (n_1, ..., n_d)
    absolute : float

    Returns
    -------
    TT
    """
    return _sweep(values, absolute, lambda unfolding, delta, guess: None, ())


def tt_from_cp(weights: np.ndarray, factors: Sequence[np.ndarray], absolute: float) -> TT:
    """The TT-SVD of a separated (CP) tensor, within an absolute Frobenius error, never forming it.

    The unfolding between modes k and k+1 is ``Q_L (Z_L (.) F_k) diag(w) Z_R^T Q_R^T`` with
    ``Q_L`` the train's cores so far (orthonormal), ``Z_L`` the terms' coefficients in them, and
    ``Z_R`` the terms of modes k+1.. in an orthonormal basis ``Q_R`` (the orthogonal sweep of
    :func:`pgdcli.tensors.cp.sweep_step`, from the right): its SVD is that of the small middle
    matrix, truncated to ``absolute / sqrt(d - 1)`` as the TT-SVD of a full tensor. No Gram
    product, so cancellation between terms is resolved to rounding (a sum of many terms of a
    small residual).

    Parameters
    ----------
    weights : ndarray, shape (C,)
    factors : sequence of ndarray, each shape (n_k, C)
    absolute : float

    Returns
    -------
    TT
    """
    d = len(factors)
    w = np.asarray(weights, dtype=float)
    if w.size == 0:
        return TT([np.zeros((1, f.shape[0], 1)) for f in factors])
    right: list = [None] * (d + 1)
    for k in range(d - 1, 0, -1):
        right[k] = sweep_step(right[k + 1], factors[k])
    delta = absolute / np.sqrt(max(d - 1, 1))
    left = w[None, :]  # (r_{k-1}, C): the terms' coefficients in the cores so far
    cores = []
    for k in range(d - 1):
        rows = khatri_rao_rows(left, factors[k])  # (r_{k-1} n_k, C)
        u, s, _ = thin_svd(rows @ right[k + 1].T)
        rank = truncation_rank(s, delta)
        basis = u[:, :rank]
        cores.append(basis.reshape(left.shape[0], factors[k].shape[0], rank))
        left = basis.T @ rows
    cores.append((left @ factors[-1].T).reshape(left.shape[0], -1, 1))
    return TT(cores)


def thin_svd(a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``numpy.linalg.svd(a, full_matrices=False)``; a much wider than tall matrix through the QR of its
    transpose first (cheaper for the first unfolding of a space-time array, a few hundred rows by
    thousands of columns)."""
    m, n = a.shape
    if 4 * m > n:
        return np.linalg.svd(a, full_matrices=False)
    q, r = np.linalg.qr(a.T)  # a = r^T q^T
    u, s, wt = np.linalg.svd(r.T)
    return u, s, wt @ q.T


def truncation_rank(s: np.ndarray, delta: float) -> int:
    """Smallest rank whose discarded singular values have norm <= delta (and above the floor)."""
    return rank_within(s, delta, RELATIVE_FLOOR)


def tt_from_full_sketched(values: np.ndarray, absolute: float, rng: np.random.Generator,
                          rank_guesses: Sequence[int] = ()) -> TT:
    """The TT-SVD of a full tensor within an absolute Frobenius error, each large unfolding split in a
    measured randomized range (module docstring).

    Parameters
    ----------
    values : ndarray, shape (n_1, ..., n_d)
    absolute : float
    rng : numpy.random.Generator
    rank_guesses : sequence of int
        The expected ranks of the bonds (e.g. those of a similar tensor); a bond without one starts from
        the rank found at the bond before (:data:`FIRST_RANK_GUESS` at the first).

    Returns
    -------
    TT
    """
    return _sweep(values, absolute, lambda unfolding, delta, guess: _sketched_split(unfolding, delta, rng, guess),
                  rank_guesses)


def _sweep(values: np.ndarray, absolute: float, split, rank_guesses: Sequence[int]) -> TT:
    """The left-to-right TT-SVD; ``split(unfolding, delta, rank_guess)`` gives ``(u, s, vt, rank)`` or None
    for the exact SVD."""
    shape = values.shape
    d = len(shape)
    cores = []
    rest = values.reshape(1, -1)
    delta = absolute / np.sqrt(max(d - 1, 1))
    rank_guess = FIRST_RANK_GUESS
    for k in range(d - 1):
        r0 = rest.shape[0]
        unfolding = rest.reshape(r0 * shape[k], -1)
        rank_guess = rank_guesses[k] if k < len(rank_guesses) else rank_guess
        found = split(unfolding, delta, rank_guess)
        if found is None:
            u, s, vt = thin_svd(unfolding)
            rank = truncation_rank(s, delta)
        else:
            u, s, vt, rank = found
        cores.append(u[:, :rank].reshape(r0, shape[k], rank))
        rest = s[:rank, None] * vt[:rank]
        rank_guess = rank
    cores.append(rest.reshape(rest.shape[0], shape[-1], 1))
    return TT(cores)


def _sketched_split(m: np.ndarray, delta: float, rng: np.random.Generator, rank_guess: int):
    """``(u, s, vt, rank)`` of the unfolding ``m`` from a measured randomized range, or None for the exact SVD."""
    rows, cols = m.shape
    small = min(rows, cols)
    width = rank_guess + OVERSAMPLING
    if m.size < SKETCH_MIN_SIZE:
        return None
    while 3 * width <= 2 * small:
        q, _ = np.linalg.qr(m @ rng.standard_normal((cols, width)))
        b = q.T @ m
        missed = float(np.linalg.norm(m - q @ b))
        if missed <= 0.5 * delta:
            ub, s, vt = thin_svd(b)
            # what the range missed and the discarded singular values add up (orthogonal parts)
            rank = truncation_rank(s, np.sqrt(max(delta * delta - missed * missed, 0.0)))
            return q @ ub, s, vt, rank
        width *= 2
    return None

"""Norms and orthogonal bases of separated (CP) tensors by orthogonal sweeps.

The norm of ``sum_c w_c x_c^(1) (x) ... (x) x_c^(d)`` is computed by an orthogonal sweep
(successive QR of Khatri-Rao products) rather than from Gram matrices: a Gram product squares the
cancellation, so ``sqrt(w^T (G_1 * ... * G_d) w)`` cannot resolve a residual below about 1e-8 of
the size of its terms, while the sweep resolves it to rounding level.

Apart from :mod:`pgdcli.tensors.cp` because it calls LAPACK through scipy, which the codebook's
query path (numpy only) never imports.
"""

from __future__ import annotations

import math
from functools import lru_cache
from typing import Sequence

import numpy as np
import scipy.linalg

__all__ = ["orthogonal_sweep", "separated_norm", "sweep_step", "sweep_order", "khatri_rao_rows"]


_GEQRF = scipy.linalg.get_lapack_funcs("geqrf", dtype=np.float64)


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

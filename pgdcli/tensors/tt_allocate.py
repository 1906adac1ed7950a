"""Rounding a tensor train with the ranks that keep the fewest values within a Frobenius bound.

TT-SVD rounding (:func:`pgdcli.tensors.tt.tt_round`) gives every bond the same share
``delta / sqrt(d - 1)`` of the error. The bound holds for any shares whose squares sum to
``delta^2`` (Oseledets 2011, theorem 2.2: the error of the sequential truncation is at most the
root sum of squares of what each unfolding of the train drops), and the bonds do not cost the
same: a rank dropped at the middle bond of a 7-D train saves ``n (r_left + r_right)`` values
(~900 on the rigid body), one at an end bond a few dozen. So the bonds' singular values are
computed first (one SVD sweep of the right-orthogonalized train) and the values are dropped,
smallest squared singular value per value saved first, while their squares sum to at most
``delta^2``; then one truncating sweep from the right keeps exactly those ranks. Measured on the
rigid body's codebook (problems/rigid_body.yaml): 267,841 values instead of 300,194 (-11%), its
largest bond 61 -> 56, the same largest nodal error (benchmarks/README.md).

numpy only.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["bond_spectra", "allocate_ranks", "truncate_allocated", "rank_within"]


def bond_spectra(cores: list[np.ndarray]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Singular values of every unfolding of a train whose cores 1..d-1 are right-orthogonal.

    Parameters
    ----------
    cores : list of ndarray, shapes (r_{k-1}, n_k, r_k)
        Right-orthogonal after the first (the first carries the norm). Not modified.

    Returns
    -------
    spectra : list of ndarray
        ``spectra[k]``: the singular values (descending) of the unfolding between cores k and k+1.
    left : list of ndarray
        The same tensor with cores 0..d-2 left-orthogonal (the norm in the last core), no rank cut.
    """
    left = list(cores)
    spectra = []
    for k in range(len(left) - 1):
        r0, n, r1 = left[k].shape
        u, s, vt = np.linalg.svd(left[k].reshape(r0 * n, r1), full_matrices=False)
        spectra.append(s)
        left[k] = u.reshape(r0, n, s.size)
        left[k + 1] = np.tensordot(s[:, None] * vt, left[k + 1], axes=(1, 0))
    return spectra, left


def rank_within(s: np.ndarray, delta: float, floor: float = 0.0) -> int:
    """Smallest rank (at least 1) whose dropped singular values (``s`` descending) have norm <= ``delta``,
    every value at most ``floor * s[0]`` dropped too (rounding noise, when ``floor`` is ~1e-14)."""
    dropped = np.sqrt(np.cumsum((s * s)[::-1]))[::-1]  # dropped[r]: the norm of s[r:]
    keep = dropped > delta
    if floor > 0.0 and s.size:
        keep &= s > floor * s[0]
    return max(1, int(np.sum(keep)))


def _values(ranks: Sequence[int], sizes: Sequence[int]) -> int:
    r = [1, *ranks, 1]
    return sum(r[k] * n * r[k + 1] for k, n in enumerate(sizes))


def allocate_ranks(spectra: Sequence[np.ndarray], sizes: Sequence[int], delta: float) -> list[int]:
    """Ranks whose dropped singular values have squares summing to at most ``delta^2``, with few values.

    Greedy: the bond whose next dropped value costs the least squared error per value saved
    goes first. The equal shares of TT-SVD rounding are one admissible choice; the result
    keeps no more values than they do.

    Parameters
    ----------
    spectra : sequence of ndarray
        Per bond (d - 1 of them), its singular values, descending.
    sizes : sequence of int
        The mode sizes ``n_k`` (d of them).
    delta : float
        Frobenius bound of the rounding.

    Returns
    -------
    list of int
        A rank per bond, each at least 1.
    """
    d = len(sizes)
    share = delta / np.sqrt(max(d - 1, 1))
    equal = [rank_within(s, share) for s in spectra]
    ranks = [s.size for s in spectra]
    budget = delta * delta
    while True:
        best, best_score = -1, np.inf
        r = [1, *ranks, 1]
        for k, s in enumerate(spectra):
            if ranks[k] <= 1:
                continue
            cost = s[ranks[k] - 1] ** 2
            if cost > budget:
                continue
            score = cost / (sizes[k] * r[k] + sizes[k + 1] * r[k + 2])
            if score < best_score:
                best, best_score = k, score
        if best < 0:
            break
        budget -= spectra[best][ranks[best] - 1] ** 2
        ranks[best] -= 1
    return ranks if _values(ranks, sizes) <= _values(equal, sizes) else equal


def truncate_allocated(cores: list[np.ndarray], delta: float) -> list[np.ndarray]:
    """Round a train (cores 1..d-1 right-orthogonal) to Frobenius error ``delta`` with allocated ranks.

    :func:`bond_spectra`, :func:`allocate_ranks`, then truncated SVDs from the right: each
    drops at most what the original unfolding drops at that rank (the later truncations are
    projections, which shrink every singular value), so the error is within ``delta``.

    Returns
    -------
    list of ndarray
        The rounded cores (cores 1..d-1 right-orthogonal).
    """
    if len(cores) == 1:
        return list(cores)
    spectra, out = bond_spectra(cores)
    ranks = allocate_ranks(spectra, [c.shape[1] for c in cores], delta)
    for k in range(len(out) - 1, 0, -1):
        r0, n, r1 = out[k].shape
        u, s, vt = np.linalg.svd(out[k].reshape(r0, n * r1), full_matrices=False)
        rank = min(ranks[k - 1], s.size)
        out[k] = vt[:rank].reshape(rank, n, r1)
        out[k - 1] = np.tensordot(out[k - 1], u[:, :rank] * s[:rank], axes=(2, 0))
    return out

"""Sweeps over the cores of tensor trains: QR orthogonalization, truncated-SVD rounding, batched.

The linear algebra of :func:`pgdcli.tensors.tt.tt_round` and its batched and shared forms, on
plain lists of cores ``(r_{k-1}, n_k, r_k)`` (or stacks of them, ``(B, r_{k-1}, n_k, r_k)``), so
it can be read and tested apart from the :class:`~pgdcli.tensors.tt.TT` type. numpy only.
"""

from __future__ import annotations

import numpy as np

from .tt_allocate import rank_within

__all__ = ["orthogonalize_left", "orthogonalize_right", "truncate_sweep", "pad_ranks", "reduce_wide_ends",
           "round_stacked"]


def orthogonalize_left(cores: list[np.ndarray]) -> list[np.ndarray]:
    """Left-orthogonalize cores 0..d-2 by QR; the norm moves into the last core."""
    for k in range(len(cores) - 1):
        r0, n, r1 = cores[k].shape
        q, r = np.linalg.qr(cores[k].reshape(r0 * n, r1))
        cores[k] = q.reshape(r0, n, q.shape[1])
        cores[k + 1] = np.tensordot(r, cores[k + 1], axes=(1, 0))
    return cores


def orthogonalize_right(cores: list[np.ndarray]) -> list[np.ndarray]:
    """Right-orthogonalize cores 1..d-1 by QR; the norm moves into the first core."""
    for k in range(len(cores) - 1, 0, -1):
        r0, n, r1 = cores[k].shape
        q, r = np.linalg.qr(cores[k].reshape(r0, n * r1).T)
        cores[k] = q.T.reshape(q.shape[1], n, r1)
        cores[k - 1] = np.tensordot(cores[k - 1], r.T, axes=(2, 0))
    return cores


def truncate_sweep(cores: list[np.ndarray], delta: float, max_rank: int | None) -> list[np.ndarray]:
    """Left-to-right truncated SVDs of right-orthogonal cores 1..d-1, each dropping at most ``delta``."""
    for k in range(len(cores) - 1):
        r0, n, r1 = cores[k].shape
        u, s, vt = np.linalg.svd(cores[k].reshape(r0 * n, r1), full_matrices=False)
        rank = rank_within(s, delta)
        if max_rank is not None:
            rank = min(rank, max_rank)
        cores[k] = u[:, :rank].reshape(r0, n, rank)
        cores[k + 1] = np.tensordot(s[:rank, None] * vt[:rank], cores[k + 1], axes=(1, 0))
    return cores


def pad_ranks(cores: list[np.ndarray], ranks: list[int]) -> list[np.ndarray]:
    """Zero-pad the bonds of one train to ``ranks`` (length d + 1); the tensor is unchanged."""
    out = []
    for k, c in enumerate(cores):
        r0, n, r1 = c.shape
        if (r0, r1) == (ranks[k], ranks[k + 1]):
            out.append(c)
            continue
        p = np.zeros((ranks[k], n, ranks[k + 1]))
        p[:r0, :, :r1] = c
        out.append(p)
    return out


def reduce_wide_ends(cores: list[np.ndarray]) -> None:
    """Cut bonds above what the outer modes allow, in place, on stacked cores ``(B, r0, n, r1)``.

    A sum of trains has bond ranks that add up (the march's stage sums: 13 trains),
    far above ``n`` at the outer bonds, where no tensor can have more. The full
    sweep of the rounding then pays QRs of ``(n r1, r0)`` unfoldings with the large
    ``r0``. Reducing first, from the last core while ``n r1 < r0`` and from the first
    while ``r0 n < r1`` (orthogonal transformations: the tensor is unchanged), leaves
    that sweep small matrices; on coupled.yaml (n = 20, sums of rank 50-80) it
    replaces QRs of 400 x 60 by 20 x 60 ones.
    """
    b, d = cores[0].shape[0], len(cores)
    for k in range(d - 1, 0, -1):
        _, r0, n, r1 = cores[k].shape
        if n * r1 >= r0:
            break
        q, r = np.linalg.qr(cores[k].reshape(b, r0, n * r1).transpose(0, 2, 1))  # r: (B, n r1, r0)
        cores[k] = q.transpose(0, 2, 1).reshape(b, n * r1, n, r1)
        _, ra, na, _ = cores[k - 1].shape
        cores[k - 1] = (cores[k - 1].reshape(b, ra * na, r0) @ r.transpose(0, 2, 1)).reshape(b, ra, na, n * r1)
    for k in range(d - 1):
        _, r0, n, r1 = cores[k].shape
        if r0 * n >= r1:
            break
        q, r = np.linalg.qr(cores[k].reshape(b, r0 * n, r1))  # r: (B, r0 n, r1)
        cores[k] = q.reshape(b, r0, n, r0 * n)
        _, _, nb, rb = cores[k + 1].shape
        cores[k + 1] = (r @ cores[k + 1].reshape(b, r1, nb * rb)).reshape(b, r0 * n, nb, rb)


def round_stacked(cores: list[np.ndarray], delta: float, max_rank: int | None) -> list[np.ndarray]:
    """TT-SVD rounding of ``B`` trains at once, each bond dropping at most ``delta`` of every train.

    Parameters
    ----------
    cores : list of ndarray, each of shape (B, r_{k-1}, n_k, r_k)
        The trains' cores stacked (zero-padded to common ranks, :func:`pad_ranks`); overwritten.
    delta : float
        Frobenius bound per bond (the train's bound over ``sqrt(d - 1)``).
    max_rank : int, optional
        Cap on every rank (the bound then no longer holds).

    Returns
    -------
    list of ndarray, each of shape (B, r'_{k-1}, n_k, r'_k)
        Every train keeps the largest rank any of them needs at a bond.
    """
    b, d = cores[0].shape[0], len(cores)
    reduce_wide_ends(cores)
    for k in range(d - 1, 0, -1):
        _, r0, n, r1 = cores[k].shape
        q, r = np.linalg.qr(cores[k].reshape(b, r0, n * r1).transpose(0, 2, 1))
        cores[k] = q.transpose(0, 2, 1).reshape(b, q.shape[2], n, r1)
        _, ra, na, _ = cores[k - 1].shape
        cores[k - 1] = (cores[k - 1].reshape(b, ra * na, r0) @ r.transpose(0, 2, 1)).reshape(b, ra, na, r.shape[1])
    for k in range(d - 1):
        _, r0, n, r1 = cores[k].shape
        u, s, vt = np.linalg.svd(cores[k].reshape(b, r0 * n, r1), full_matrices=False)
        tail = np.sqrt(np.cumsum((s * s)[:, ::-1], axis=1))[:, ::-1]
        rank = max(1, int(np.max(np.sum(tail > delta, axis=1))))
        if max_rank is not None:
            rank = min(rank, max_rank)
        cores[k] = u[:, :, :rank].reshape(b, r0, n, rank)
        _, _, nb, rb = cores[k + 1].shape
        sv = s[:, :rank, None] * vt[:, :rank]
        cores[k + 1] = (sv @ cores[k + 1].reshape(b, r1, nb * rb)).reshape(b, rank, nb, rb)
    return cores

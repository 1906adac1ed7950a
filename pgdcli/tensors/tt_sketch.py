"""Randomized rounding of sums of Hadamard products of tensor trains.

``sum_m w_m A_m * B_m`` rounded to a Frobenius bound without forming the products, whose
ranks are the products of the factors' ranks: a randomized range finder
(randomize-then-orthogonalize, Al Daas, Ballard et al., SIAM J. Sci. Comput. 2023) sketches
the sum with a Gaussian train, then the sketch is rounded by TT-SVD. Its cost per core is
about ``n r_A r_B (r_A + r_B) s`` for sketch rank ``s ~ r``: it grows as r^4 for factors of
rank r (the main cost of the march on the rigid body, benchmarks/build_speed.py).

This module imports numpy and :mod:`pgdcli.tensors.tt` only.
"""

from __future__ import annotations

import numpy as np

from .tt import TT, is_ones, tt_hadamard, tt_round, tt_sum

__all__ = ["tt_round_sum_of_products"]


def _sketch_sum_of_products(terms, rank: int, rng: np.random.Generator) -> TT:
    """Randomized range finder for ``sum_m w_m A_m * B_m`` (Hadamard), never forming a product.

    Randomize-then-orthogonalize (Al Daas, Ballard et al., SIAM J. Sci. Comput. 2023):
    right-to-left partial contractions of each product with a Gaussian train of
    ranks ``rank``, then a left-to-right sweep whose QR factors are the new cores.
    Costs O(d n r^3 rank) per product instead of the O(d n r^6) of rounding the
    explicit product of rank r^2.
    """
    first = terms[0][1]
    d = first.order
    shape = first.shape
    ranks = [1] + [rank] * (d - 1) + [1]
    omega = [rng.standard_normal((ranks[k], shape[k], ranks[k + 1])) for k in range(d)]
    # every contraction below is a reshape and a (batched) matrix product: einsum's
    # path search costs more than the arithmetic at these sizes
    sketches = []
    for _, a, b in terms:
        w = [None] * (d + 1)
        w[d] = np.ones((1, 1, 1))
        for k in range(d - 1, 0, -1):
            w[k] = _sketch_step(a.cores[k], b.cores[k], w[k + 1], omega[k])
        sketches.append(w)
    left = [np.full((1, 1, 1), float(weight)) for weight, _, _ in terms]
    cores = []
    for k in range(d - 1):
        products = [_left_product(left[m], a.cores[k], b.cores[k]) for m, (_, a, b) in enumerate(terms)]
        lp, n = products[0].shape[:2]
        s = 0.0
        for prod, sk in zip(products, sketches):
            x, y = prod.shape[2:]
            s = s + prod.reshape(lp * n, x * y) @ sk[k + 1].reshape(x * y, -1)
        q, _ = np.linalg.qr(s)
        core = q.reshape(lp, n, q.shape[1])
        cores.append(core)
        flat_core = q  # (lp n, l)
        left = [(flat_core.T @ prod.reshape(lp * n, -1)).reshape(q.shape[1], *prod.shape[2:]) for prod in products]
    last = 0.0
    for m, (_, a, b) in enumerate(terms):
        last = last + _left_product(left[m], a.cores[d - 1], b.cores[d - 1])[..., 0, 0]
    cores.append(last.reshape(last.shape[0], shape[-1], 1))
    return TT(cores)


def _sketch_step(a: np.ndarray, b: np.ndarray, w: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """``W_k[a, b, l] = sum_{i, x, y, z} A[a, i, x] B[b, i, y] Omega[l, i, z] W_{k+1}[x, y, z]``."""
    ra, n, rx = a.shape
    rb, _, ry = b.shape
    lk = omega.shape[0]
    # Y[x, y, l, i] = sum_z W[x, y, z] Omega[l, i, z]
    y = (w.reshape(rx * ry, -1) @ omega.reshape(lk * n, -1).T).reshape(rx, ry, lk, n)
    # Z[i, b, (x, l)] = sum_y B[b, i, y] Y[x, y, l, i]   (batched over i)
    yi = y.transpose(3, 1, 0, 2).reshape(n, ry, rx * lk)
    z = np.matmul(b.transpose(1, 0, 2), yi).reshape(n, rb, rx, lk)
    # W[a, (b, l)] = sum_{i, x} A[a, i, x] Z[i, b, x, l]
    zz = z.transpose(0, 2, 1, 3).reshape(n * rx, rb * lk)
    return (a.reshape(ra, n * rx) @ zz).reshape(ra, rb, lk)


def _left_product(left: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``P[j, i, x, y] = sum_{a, b} L[j, a, b] A[a, i, x] B[b, i, y]``."""
    lj, ra, rb = left.shape
    _, n, rx = a.shape
    ry = b.shape[2]
    # T[j, b, i, x] = sum_a L[j, a, b] A[a, i, x]
    t = (left.transpose(0, 2, 1).reshape(lj * rb, ra) @ a.reshape(ra, n * rx)).reshape(lj, rb, n, rx)
    # P[i, (j, x), y] = sum_b T[j, b, i, x] B[b, i, y]   (batched over i)
    ti = t.transpose(2, 0, 3, 1).reshape(n, lj * rx, rb)
    p = np.matmul(ti, b.transpose(1, 0, 2)).reshape(n, lj, rx, ry)
    return p.transpose(1, 0, 2, 3)


def tt_round_sum_of_products(terms, *, absolute: float, rank_hint: int = 8, oversample: int = 8,
                             rng: np.random.Generator | None = None, max_rank: int | None = None,
                             stats: dict | None = None) -> TT:
    """Rounded ``sum_m w_m A_m * B_m`` (Hadamard products; use :func:`tt_ones` for a lone factor).

    Small implicit ranks are summed and rounded exactly; large ones go
    through a randomized sketch of rank ``rank_hint + oversample``, doubled
    until the rounded result's ranks stay clear of the sketch size (so the
    rank, not the sketch, sets the accuracy), then rounded to ``absolute``.

    Parameters
    ----------
    terms : list of (float, TT, TT)
    absolute : float
        Frobenius error bound of the final rounding.
    stats : dict, optional
        Counters incremented in place: ``"exact"`` (summed and rounded exactly),
        ``"sketched"`` (randomized roundings) and ``"redone"`` (sketches whose
        rounded rank came too close to their size: a failed compression, redone
        with twice the sketch).
    """
    stats = {} if stats is None else stats
    terms = [(float(w), a, b) for w, a, b in terms if w != 0.0]
    if not terms:
        raise ValueError("no terms to sum")
    d = terms[0][1].order
    implicit = [max(a.cores[k].shape[2] * b.cores[k].shape[2] for k in range(d - 1)) if d > 1 else 1
                for _, a, b in terms]
    sketch = rank_hint + oversample
    if d == 1 or sum(implicit) <= 2 * sketch:
        exact = tt_sum([a if is_ones(b) else tt_hadamard(a, b) for _, a, b in terms], [w for w, _, _ in terms])
        stats["exact"] = stats.get("exact", 0) + 1
        return tt_round(exact, absolute=absolute, max_rank=max_rank)
    rng = np.random.default_rng(0) if rng is None else rng
    limit = sum(implicit)
    stats["sketched"] = stats.get("sketched", 0) + 1
    while True:
        x = tt_round(_sketch_sum_of_products(terms, min(sketch, limit), rng), absolute=absolute, max_rank=max_rank)
        if sketch >= limit or max(x.ranks) <= sketch - oversample // 2 or (max_rank and sketch >= max_rank):
            return x
        stats["redone"] = stats.get("redone", 0) + 1
        sketch *= 2

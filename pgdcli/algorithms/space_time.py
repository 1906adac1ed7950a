"""The codebook's space-time train: the march's states at the time nodes joined and rounded.

Joined ranks are the sums of the members' ranks, so the join is a tree of concatenations
along the leading (time) mode, each level rounded (exactly while small, else by the
randomized sum-of-products rounding).
"""

from __future__ import annotations

import numpy as np

from ..tensors.tt import TT, tt_concatenate, tt_rank_one, tt_round_many
from ..tensors.tt_sketch import tt_round_sum_of_products
from .polynomial_rhs import EXACT_RANK_LIMIT

__all__ = ["join_and_round", "lift"]


def lift(train: TT) -> TT:
    """The train with a leading mode of size 1 (a run of one time node)."""
    return TT([np.ones((1, 1, 1))] + list(train.cores))


def join_and_round(groups: list[list[TT]], delta: float, rng: np.random.Generator | None = None,
                   fan_in: int = 8, batched: bool = True,
                   stats: dict | None = None, lifted: bool = False) -> list[TT]:
    """Each group's trains joined along a new leading mode (``X[n, ...] = group[n][...]``), rounded
    to Frobenius error ``delta``: the codebook's space-time train from the states at the time nodes.

    Joined ranks are the sums of the members' ranks, so the join is built as a
    tree: up to ``fan_in`` members at a time are concatenated along the leading
    mode and rounded (exactly and batched across groups while the sums stay
    small, else by the randomized sum-of-products rounding, which never forms
    them), then the rounded pieces are joined the same way. The last level, which
    sets the final ranks, gets 0.7 of ``delta`` and the earlier ones share the
    rest; within a level the pieces are orthogonal blocks of the leading mode, so
    their errors add in quadrature. ``lifted``: the members have their leading (time) mode already, a run
    of nodes each (the grid march's compressed runs).
    """
    levels = max(1, int(np.ceil(np.log(max(len(g) for g in groups)) / np.log(fan_in))))
    # the last level sets the final ranks: it gets most of the budget, the others share the rest
    budgets = [0.7 * delta] if levels == 1 else [0.3 * delta / (levels - 1)] * (levels - 1) + [0.7 * delta]
    budgets[-1] = delta - sum(budgets[:-1])
    pieces = [list(g) if lifted else [lift(t) for t in g] for g in groups]
    for level in range(levels + 1):
        chunks = [[g[i:i + fan_in] for i in range(0, len(g), fan_in)] for g in pieces]
        flat = [chunk for g in chunks for chunk in g]
        # the error budget of a level is shared by its chunks (orthogonal blocks)
        chunk_delta = budgets[min(level, levels - 1)] / np.sqrt(max(len(g) for g in chunks))
        rounded = _round_concatenations(flat, chunk_delta, rng, batched, stats)
        it = iter(rounded)
        pieces = [[next(it) for _ in g] for g in chunks]
        if all(len(g) == 1 for g in pieces):
            return [g[0] for g in pieces]
    raise AssertionError("the join tree did not close")  # pragma: no cover


def _round_concatenations(chunks: list[list[TT]], delta: float, rng, batched: bool = True,
                          stats: dict | None = None) -> list[TT]:
    """Round ``tt_concatenate(chunk)`` for every chunk: exactly when small, else sketched.

    ``batched`` rounds equal-shape chunks together (fast; each keeps the largest rank of its
    batch), otherwise one by one (each gets its own smallest ranks: the codebook's final join).
    """
    sums = [sum(max(t.ranks, default=1) for t in chunk) for chunk in chunks]
    if max(sums) <= EXACT_RANK_LIMIT:
        joined = [tt_concatenate(chunk) for chunk in chunks]
        if stats is not None:
            stats["exact"] = stats.get("exact", 0) + len(joined)
        by_shape: dict = {}
        for i, j in enumerate(joined):
            by_shape.setdefault(j.shape, []).append(i)
        out: list = [None] * len(joined)
        for idx in by_shape.values():  # tt_round_many needs one shape per batch
            batches = [idx] if batched else [[i] for i in idx]
            for batch in batches:
                for i, r in zip(batch, tt_round_many([joined[i] for i in batch], absolute=delta)):
                    out[i] = r
        return out
    out = []
    for chunk in chunks:
        lead = [t.shape[0] for t in chunk]
        total = sum(lead)
        terms, offset = [], 0
        for t, n in zip(chunk, lead):
            selector = np.zeros(total)
            selector[offset:offset + n] = 1.0
            padded = np.zeros((1, total, t.cores[0].shape[2]))
            padded[0, offset:offset + n] = t.cores[0][0]
            terms.append((1.0, tt_rank_one([selector] + [np.ones(m) for m in t.shape[1:]]),
                          TT([padded] + list(t.cores[1:]))))
            offset += n
        # a join spans the members' union: start the sketch at twice the largest member rank
        hint = 2 * max(max(t.ranks, default=1) for t in chunk)
        out.append(tt_round_sum_of_products(terms, absolute=delta, rank_hint=hint, rng=rng, stats=stats))
    return out

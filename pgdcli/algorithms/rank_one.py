"""The rank-one correction of the PGD enrichment: an alternating-directions fixed point.

:func:`enrich` solves for one factor at a time with the others frozen. ``minres`` minimizes the
residual norm over that factor (always a descent, never stalls); ``galerkin`` imposes the
seed paper's Galerkin condition (eq. 12). The two differ only in their per-mode products and
systems (:class:`_MinresModes`, :class:`_GalerkinModes`); the sweep over the modes is shared.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

from ..tensors.cp import SeparatedOperator

__all__ = ["enrich", "solve_small"]


def enrich(
    op: SeparatedOperator,
    res_w: np.ndarray,
    res_f: list[np.ndarray],
    *,
    formulation: str = "minres",
    tolerance: float = 1e-8,
    max_iterations: int = 30,
    start: list[np.ndarray] | None = None,
) -> tuple[list[np.ndarray], int]:
    """Rank-one correction ``R_1 (x) ... (x) R_d`` of the residual by alternating directions.

    Parameters
    ----------
    op : SeparatedOperator
        ``K`` terms, ``d`` modes.
    res_w : ndarray, shape (C,)
    res_f : list of ndarray, each shape (m_j, C)
        The current residual ``r`` in separated form.
    formulation : {'minres', 'galerkin'}
        ``minres`` minimizes ``||A R - r||`` over each factor in turn;
        ``galerkin`` imposes ``<A R - r, R*> = 0`` (the paper's eq. 12).
    tolerance : float
        Stop when the relative change of the rank-one tensor is below this.
    max_iterations : int
    start : list of ndarray, optional
        Initial factors.

    Returns
    -------
    factors : list of ndarray, each shape (n_j,)
    iterations : int
    """
    d = op.order
    stacks = [op.mode_stack(j) for j in range(d)]
    # the factors are views into one vector: the fixed point's change is then a few array operations
    offsets = np.cumsum([0] + [s.shape[2] for s in stacks[:-1]])
    flat = np.concatenate([(np.ones(s.shape[2]) if start is None else np.asarray(start[j], dtype=float))
                           for j, s in enumerate(stacks)])
    R = np.split(flat, offsets[1:])
    for r in R:
        r /= np.linalg.norm(r)
    modes = _MinresModes(op, stacks, res_f) if formulation == "minres" else _GalerkinModes(stacks, res_f)
    # G[j], H[j]: mode j's products (modes.products); stacked with one more slot (ones, the
    # residual's weights) so that the products over the modes after j are one cumulative product
    first = [modes.products(j, R[j]) for j in range(d)]
    G, H = np.empty((d + 1,) + first[0][0].shape), np.empty((d + 1,) + first[0][1].shape)
    for j, (g, h) in enumerate(first):
        G[j], H[j] = g, h
    G[d], H[d] = 1.0, res_w

    iterations = 0
    for iterations in range(1, max_iterations + 1):
        previous = flat.copy()
        # products over the other modes: the modes before j (already updated in this pass)
        # times the modes after j (from the previous pass; the residual's weights included)
        after_G = np.cumprod(G[::-1], axis=0)[::-1]
        after_H = np.cumprod(H[::-1], axis=0)[::-1]
        before_G = before_H = 1.0
        for j in range(d):
            R[j][:] = modes.solve(j, before_G * after_G[j + 1], before_H * after_H[j + 1])
            G[j], H[j] = modes.products(j, R[j])
            before_G = before_G * G[j]
            before_H = before_H * H[j]
        if _relative_change(previous, flat, offsets) < tolerance:
            break
    return R, iterations


class _MinresModes:
    """Per-mode pieces of the minres fixed point: ``G_j = (A_kj R_j . A_lj R_j)`` (K, K) and
    ``H_j = (A_kj R_j . res_c)`` (K, C), and the normal equations of one factor."""

    def __init__(self, op: SeparatedOperator, stacks: list[np.ndarray], res_f: list[np.ndarray]) -> None:
        K = self.K = op.n_terms
        # flattened once so that each step is a few matrix products (the systems are tiny and
        # solved thousands of times per build: einsum's per-call cost would dominate)
        self.rows = [s.reshape(-1, s.shape[2]) for s in stacks]  # (K m_j, n_j): the A_kj stacked
        self.gram_ops = [op.mode_gram(j).reshape(K * K, -1) for j in range(op.order)]  # A_kj^T A_lj, (K K, n_j n_j)
        # A_kj^T applied to every residual column, rows (k, c): H_j = <A_kj R_j, res_c> is Y_j R_j
        self.Y = [(s.transpose(0, 2, 1) @ f).transpose(0, 2, 1).reshape(-1, s.shape[2]) for s, f in zip(stacks, res_f)]

    def products(self, j: int, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        V = (self.rows[j] @ r).reshape(self.K, -1)
        return V @ V.T, (self.Y[j] @ r).reshape(self.K, -1)

    def solve(self, j: int, c: np.ndarray, h: np.ndarray) -> np.ndarray:
        """The factor of mode j minimizing the residual, given the other modes' products c (K, K), h (K, C)."""
        n_j = self.rows[j].shape[1]
        M = (c.reshape(-1) @ self.gram_ops[j]).reshape(n_j, n_j)
        return solve_small(M, h.reshape(-1) @ self.Y[j], symmetric=True)


class _GalerkinModes:
    """Per-mode pieces of the Galerkin fixed point: ``G_j = (R_j . A_kj R_j)`` (K,) and
    ``H_j = (R_j . res_c)`` (C,), and the Galerkin system of one factor."""

    def __init__(self, stacks: list[np.ndarray], res_f: list[np.ndarray]) -> None:
        self.stacks, self.res_f = stacks, res_f

    def products(self, j: int, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return np.einsum("a,kab,b->k", r, self.stacks[j], r), r @ self.res_f[j]

    def solve(self, j: int, c: np.ndarray, h: np.ndarray) -> np.ndarray:
        M = np.einsum("k,kab->ab", c, self.stacks[j])
        return solve_small(M, self.res_f[j] @ h, symmetric=False)


_POSV, _GESV = scipy.linalg.get_lapack_funcs(("posv", "gesv"), dtype=np.float64)


def solve_small(M: np.ndarray, b: np.ndarray, *, symmetric: bool) -> np.ndarray:
    """Solve ``M x = b``, shape (n, n) and (n,): Cholesky if ``symmetric``, else LU; least squares on failure.

    LAPACK is called directly: these systems are tiny and solved thousands of
    times per build, where ``scipy.linalg.solve``'s checks and condition
    estimate cost ten times the factorization. Normal equations of nearly
    dependent modes are ill-conditioned by nature (the caller checks that the
    residual decreases); only a failed factorization (not positive definite,
    exactly singular) falls back to least squares.
    """
    if symmetric:
        _, x, info = _POSV(M, b)
    else:
        _, _, x, info = _GESV(M, b)
    if info == 0:
        return x
    return np.linalg.lstsq(M, b, rcond=None)[0]


def _relative_change(old: np.ndarray, new: np.ndarray, offsets: np.ndarray) -> float:
    """``||x_old - x_new|| / ||x_new||`` for rank-one tensors, from their factors.

    ``old`` and ``new`` hold the factors end to end, mode ``j`` from ``offsets[j]``.
    """
    n_old = math.prod(np.add.reduceat(old * old, offsets).tolist())
    n_new = math.prod(np.add.reduceat(new * new, offsets).tolist())
    cross = math.prod(np.add.reduceat(old * new, offsets).tolist())
    if n_new == 0.0:
        return 0.0 if n_old == 0.0 else np.inf
    return math.sqrt(max(n_old + n_new - 2.0 * cross, 0.0) / n_new)

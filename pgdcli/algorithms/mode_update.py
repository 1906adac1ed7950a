"""The joint update of all factors of one mode of the PGD enrichment (minres).

:func:`update_mode` re-solves one coordinate's factors with the others frozen: exactly, node
by node, when the mode's operator matrices are diagonal (parameters); else by a few
block-Jacobi preconditioned conjugate-gradient steps (:func:`_kronecker_pcg`).
"""

from __future__ import annotations

import warnings
from typing import Callable

import numpy as np
import scipy.linalg

from .enrichment_state import EnrichmentState

__all__ = ["update_mode", "CG_ITERATIONS", "CG_RTOL"]


# The update's conjugate gradients stop after CG_ITERATIONS steps, or once the preconditioned
# residual has fallen by CG_RTOL: the fixed point repeats the update after every enrichment, so
# inexact solves suffice: on the shipped linear problems (heat2d, spring, relaxation,
# heat2d_source) exact solves give the same modes and residuals (within one or two modes) at a
# higher build cost (benchmarks/build_speed.py).
CG_ITERATIONS = 10
CG_RTOL = 1e-4


def update_mode(state: EnrichmentState, j: int, *, cg_iterations: int = CG_ITERATIONS, cg_rtol: float = CG_RTOL) -> None:
    """Re-solve all factors of mode ``j`` jointly (minres), the others frozen.

    Minimizes ``||F - sum_i alpha_i A (x)_m U_im||`` over ``U_j`` (``n_j * n``
    unknowns) through its normal equations; the new columns are normalized
    into the weights. Called after an enrichment, it lets earlier modes adapt
    to later ones, which keeps the rank low. When every operator matrix of
    the mode is diagonal (parameter coordinates) the normal equations split
    into ``n_j`` independent ``n x n`` systems, one per node, solved exactly.
    Otherwise (the state mode, dense in time) the ``n n_j`` normal equations
    are a sum of ``K^2`` Kronecker products: a direct solve would cost
    ``(n n_j)^3``, so a few block-Jacobi preconditioned conjugate-gradient
    steps are taken from the current factors instead (at most ``cg_iterations``,
    fewer once the preconditioned residual has fallen by ``cg_rtol``). CG
    decreases the least-squares objective monotonically, so every step is an
    improvement.
    """
    op, K, n = state.op, state.op.n_terms, state.rank
    stack = op.mode_stack(j)
    a = state.alphas
    T = np.ones((K, n, K, n))
    rhs_c = np.ones((K, n, state.source.rank))
    for m in range(op.order):
        if m == j:
            continue
        gram, cross = state.image_products(m)
        T *= gram.reshape(K, n, K, n)
        rhs_c *= cross.reshape(K, n, -1)
    T *= a[None, :, None, None] * a[None, None, None, :]
    # (einsum contractions written as matrix products: these run thousands of times per build)
    W = ((rhs_c * state.source.weights).reshape(K * n, -1) @ state.source.factors[j].T).reshape(K, n, -1)  # (K, n, m_j)
    if op.mode_is_diagonal(j):
        diag = np.einsum("kaa->ka", stack)  # (K, n_j)
        pairs = (diag[:, None, :] * diag[None, :, :]).reshape(K * K, -1)  # [(k, l), a]
        N = (pairs.T @ T.transpose(0, 2, 1, 3).reshape(K * K, n * n)).reshape(-1, n, n)  # (n_j, n, n)
        rhs = np.einsum("ka,kia->ai", diag, W) * a[None, :]
        X = _solve_batched(N, rhs)  # (n_j, n)
    else:
        gram = op.mode_gram(j)
        rhs = (W.transpose(1, 0, 2).reshape(n, -1) @ stack.reshape(-1, stack.shape[2])) * a[:, None]  # (n, n_j)
        invert = state.preconditioners.setdefault(j, _KeptBlockInverses())
        X = _kronecker_pcg(T, gram, rhs, state.factors[j].T, iterations=cg_iterations,
                           rtol=cg_rtol, invert=invert).T  # (n_j, n)
    norms = np.linalg.norm(X, axis=0)
    keep = norms > 0
    X[:, keep] /= norms[keep]
    state.alphas = np.where(keep, a * norms, 0.0)
    state.set_mode(j, X)


def _kronecker_pcg(T: np.ndarray, G: np.ndarray, B: np.ndarray, X: np.ndarray, *, iterations: int,
                   rtol: float = 0.0, invert: Callable[[np.ndarray], np.ndarray] | None = None) -> np.ndarray:
    """Approximately solve ``sum_kl T_kl X G_kl^T = B`` for X, shape (n, m), by PCG.

    ``T`` has shape (K, n, K, n) (``T_kl = T[k, :, l, :]``), ``G`` shape (K, K, m, m);
    the operator is SPD (normal equations). Block-Jacobi preconditioner: one
    ``m x m`` block per row of X, inverted by ``invert`` (blocks (n, m, m) ->
    inverses; default :func:`_inverse_spd_blocks`). Stops after ``iterations``
    steps, or once the preconditioned residual norm has fallen by ``rtol``.
    """
    K, n, m = T.shape[0], T.shape[1], G.shape[2]
    # the operator as two matrix products (einsum would loop in C without BLAS)
    T_rows = T.transpose(1, 0, 2, 3).reshape(n, K * K * n)  # [i, (k, l, p)]
    G_t = np.ascontiguousarray(G.transpose(0, 1, 3, 2))  # [k, l, b, a]

    def apply(Y):
        return T_rows @ np.matmul(Y, G_t).reshape(K * K * n, m)

    diag_T = np.einsum("kili->kli", T).reshape(K * K, n)
    blocks = (diag_T.T @ G.reshape(K * K, m * m)).reshape(n, m, m)
    inv_blocks = (invert or _inverse_spd_blocks)(blocks)

    def precond(R):
        return np.matmul(inv_blocks, R[:, :, None])[:, :, 0]

    X = X.copy()
    R = B - apply(X)
    Zr = precond(R)
    Pd = Zr.copy()
    rz = np.vdot(R, Zr)
    stop = rtol**2 * rz
    for _ in range(iterations):
        if rz <= stop or rz <= 0.0:
            break
        Q = apply(Pd)
        pq = np.vdot(Pd, Q)
        if pq <= 0.0:
            break
        step = rz / pq
        X += step * Pd
        R -= step * Q
        Zr = precond(R)
        rz_new = np.vdot(R, Zr)
        Pd = Zr + (rz_new / rz) * Pd
        rz = rz_new
    return X


class _KeptBlockInverses:
    """Block-Jacobi inverses of one mode's update, kept from one update sweep to the next.

    Block ``i`` is ``alpha_i^2`` times a matrix that changes little between sweeps once
    term ``i`` has settled: a kept inverse is rescaled by the ratio of the blocks' traces,
    and only the blocks of new terms are inverted (all of them every ``REFRESH`` calls).
    Measured on heat2d, spring and relaxation: the same modes, the inverses' cost (about
    a tenth of a build) mostly gone. It is only a preconditioner: PCG stays exact.
    """

    REFRESH = 8

    def __init__(self):
        self.inverses: np.ndarray | None = None  # (n, m, m)
        self.traces: np.ndarray | None = None  # (n,): traces of the blocks they invert
        self.age = 0

    def __call__(self, blocks: np.ndarray) -> np.ndarray:
        traces = np.einsum("iaa->i", blocks)
        kept = self.inverses
        if (kept is None or kept.shape[0] > blocks.shape[0] or kept.shape[1:] != blocks.shape[1:]
                or self.age >= self.REFRESH):
            inverses, self.age = _inverse_spd_blocks(blocks), 0
        else:
            k = kept.shape[0]
            ratio = np.divide(self.traces, traces[:k], out=np.zeros(k), where=traces[:k] > 0.0)
            inverses = np.empty_like(blocks)
            inverses[:k] = kept * ratio[:, None, None]
            if k < blocks.shape[0]:
                inverses[k:] = _inverse_spd_blocks(blocks[k:])
            self.age += 1
        self.inverses, self.traces = inverses, traces
        return inverses


def _inverse_spd_blocks(blocks: np.ndarray) -> np.ndarray:
    """Inverses of symmetric positive semi-definite matrices, shape (n, m, m).

    Cholesky-based (half the cost of numpy's LU-based batched inverse); a singular
    block (not positive definite) gets a pseudo-inverse. An ill-conditioned one is
    inverted as it is: this is a preconditioner.
    """
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", scipy.linalg.LinAlgWarning)
        try:
            return scipy.linalg.inv(blocks, assume_a="pos", check_finite=False)
        except (np.linalg.LinAlgError, scipy.linalg.LinAlgError, ValueError):
            return np.linalg.pinv(blocks, hermitian=True)


def _solve_batched(N: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve ``N[a] x[a] = rhs[a]`` for SPD (possibly singular) ``N[a]``, shape (m, n, n) and (m, n).

    A Cholesky factorization decides whether every ``N[a]`` is positive definite (else
    least squares, one system at a time); the solve itself is numpy's batched LU, which
    is faster than two batched "general" solves with the triangular factors.
    """
    try:
        np.linalg.cholesky(N)
        return np.linalg.solve(N, rhs[:, :, None])[:, :, 0]
    except np.linalg.LinAlgError:
        return np.stack([np.linalg.lstsq(N[a], rhs[a], rcond=None)[0] for a in range(N.shape[0])])

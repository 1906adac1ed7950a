"""The PGD enrichment solver for linear parametric problems (the seed paper's Algorithm 1).

It works on the separated system of :mod:`pgdcli.discretization.linear`.

Algorithm (free functions below):

1. :func:`enrich` finds a rank-one term by an alternating-directions fixed
   point, solving for one mode with the others frozen. ``minres`` minimizes the
   residual norm (always a descent, never stalls); ``galerkin`` is the paper's
   Galerkin condition (eq. 12).
2. :func:`project_alphas` recomputes every weight (eq. 15 for Galerkin, a
   least-squares problem for minres, solved through an orthogonal sweep).
3. :func:`update_mode` optionally re-solves all modes of one coordinate jointly,
   which keeps the rank low. With updates (minres), every coordinate is updated
   after each enrichment and the residual checked once (:func:`_update_all`): the
   first update re-fits all weights, which does step 2's job. Should the residual
   not have fallen, the careful path is taken: step 2, then updates kept one by
   one only if they lower the residual, each checked with one more step of the
   projection's sweep (:func:`_update_sweep`).
4. The relative residual (eq. 16) is computed in separated form by orthogonal
   sweeps (:func:`pgdcli.tensors.cp.separated_norm`), accurate to rounding.

Over 400 lines: the enrichment, projection and update steps share the state and its partial
sweeps (``EnrichmentState``); split them and every step would import the others.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field
from functools import partial
from typing import Callable

import numpy as np
import scipy.linalg

from ..discretization.linear import Discretization
from ..tensors.cp import CPTensor, SeparatedOperator, khatri_rao_rows, separated_norm, sweep_order, sweep_step

__all__ = ["EnrichmentState", "enrich", "project_alphas", "update_mode", "residual_norm", "run_enrichment"]


# ----------------------------------------------------------------------------------------------
# the algorithm
# ----------------------------------------------------------------------------------------------
@dataclass
class EnrichmentState:
    """Current approximation ``U = sum_i alpha_i (x)_j U_j[:, i]`` and its images ``A_k U``."""

    op: SeparatedOperator
    source: CPTensor
    alphas: np.ndarray
    factors: list[np.ndarray]
    images: list[np.ndarray]  # images[j]: (K, m_j, n) = A_kj @ U_j
    # mode -> (images^T images, images^T source factors), until that mode changes (update_mode
    # needs them for every other mode, d - 1 times per update sweep)
    _products: dict = field(default_factory=dict, repr=False)
    # mode -> its update's block-Jacobi inverses, kept from one update sweep to the next
    preconditioners: dict = field(default_factory=dict, repr=False)

    @classmethod
    def empty(cls, op: SeparatedOperator, source: CPTensor) -> "EnrichmentState":
        sizes = [op.terms[0][j].shape for j in range(op.order)]
        return cls(
            op,
            source,
            np.zeros(0),
            [np.zeros((n, 0)) for _, n in sizes],
            [np.zeros((op.n_terms, m, 0)) for m, _ in sizes],
        )

    @property
    def rank(self) -> int:
        return self.alphas.size

    def append(self, columns: list[np.ndarray], alpha: float) -> None:
        self._products.clear()
        self.alphas = np.append(self.alphas, alpha)
        for j, col in enumerate(columns):
            self.factors[j] = np.column_stack([self.factors[j], col])
            stack = self.op.mode_stack(j)
            image = (stack.reshape(-1, stack.shape[2]) @ col).reshape(stack.shape[0], -1)
            self.images[j] = np.concatenate([self.images[j], image[:, :, None]], axis=2)

    def set_mode(self, j: int, factor: np.ndarray, image: np.ndarray | None = None) -> None:
        """Replace the factors of mode ``j`` (and their images, computed unless given)."""
        self._products.pop(j, None)
        self.factors[j] = factor
        if image is not None:
            self.images[j] = image
            return
        stack = self.op.mode_stack(j)
        self.images[j] = (stack.reshape(-1, stack.shape[2]) @ factor).reshape(stack.shape[0], stack.shape[1], -1)

    def residual_weights(self) -> np.ndarray:
        """Weights of ``F - A U``, shape (nF + K n,): the source's, then ``-alphas`` per operator term."""
        return np.concatenate([self.source.weights, -np.tile(self.alphas, self.op.n_terms)])

    def residual_columns(self, j: int) -> np.ndarray:
        """Mode ``j`` factors of ``F - A U``, shape (m_j, nF + K n): source columns, then images term-major."""
        image = self.images[j]
        return np.hstack([self.source.factors[j], image.transpose(1, 0, 2).reshape(image.shape[1], -1)])

    def residual(self) -> tuple[np.ndarray, list[np.ndarray]]:
        """``F - A U`` as weights (C,) and factors (m_j, C); source columns first."""
        return self.residual_weights(), [self.residual_columns(j) for j in range(self.op.order)]

    def residual_norm(self) -> float:
        """``||F - A U||`` by an orthogonal sweep, accurate to rounding."""
        return separated_norm(*self.residual())

    def snapshot(self) -> tuple:
        """A copy of the weights, factors and images, for :meth:`restore`."""
        return self.alphas.copy(), [f.copy() for f in self.factors], [m.copy() for m in self.images]

    def restore(self, snapshot: tuple) -> None:
        self._products.clear()
        alphas, factors, images = snapshot
        self.alphas, self.factors, self.images = alphas, factors, images

    def image_products(self, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Gram matrix of mode ``m``'s images, shape (K n, K n), and their products with the
        source's factors, shape (K n, nF); rows and columns term-major."""
        if m not in self._products:
            img = self.images[m].transpose(1, 0, 2).reshape(self.images[m].shape[1], -1)  # (m_m, K n)
            self._products[m] = (img.T @ img, img.T @ self.source.factors[m])
        return self._products[m]


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
    d, K, C = op.order, op.n_terms, res_w.size
    stacks = [op.mode_stack(j) for j in range(d)]
    # the factors are views into one vector: the fixed point's change is then a few array operations
    offsets = np.cumsum([0] + [s.shape[2] for s in stacks[:-1]])
    flat = np.concatenate([(np.ones(s.shape[2]) if start is None else np.asarray(start[j], dtype=float))
                           for j, s in enumerate(stacks)])
    R = np.split(flat, offsets[1:])
    for r in R:
        r /= np.linalg.norm(r)
    if formulation == "minres":
        # flattened once so that each step is a few matrix products (the systems are tiny and
        # solved thousands of times per build: einsum's per-call cost would dominate)
        rows = [s.reshape(-1, s.shape[2]) for s in stacks]  # (K m_j, n_j): the A_kj stacked
        gram_ops = [op.mode_gram(j).reshape(K * K, -1) for j in range(d)]  # A_kj^T A_lj, (K K, n_j n_j)
        # A_kj^T applied to every residual column, rows (k, c): H_j = <A_kj R_j, res_c> is Y_j R_j
        Y = [(s.transpose(0, 2, 1) @ f).transpose(0, 2, 1).reshape(-1, s.shape[2]) for s, f in zip(stacks, res_f)]
        V = [(rows[j] @ R[j]).reshape(K, -1) for j in range(d)]
        # G[j] = (A_kj R_j . A_lj R_j), H[j] = (A_kj R_j . res_c); stacked with one more slot
        # (ones, the residual's weights) so that the products over the modes after j are one
        # cumulative product per pass
        G, H = np.empty((d + 1, K, K)), np.empty((d + 1, K, C))
        for j in range(d):
            G[j], H[j] = V[j] @ V[j].T, (Y[j] @ R[j]).reshape(K, -1)
    else:
        # G[j] = (R_j . A_kj R_j), H[j] = (R_j . res_c), stacked likewise
        G, H = np.empty((d + 1, K)), np.empty((d + 1, C))
        for j in range(d):
            G[j], H[j] = np.einsum("a,kab,b->k", R[j], stacks[j], R[j]), R[j] @ res_f[j]
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
            c = before_G * after_G[j + 1]  # (K, K) or (K,)
            h = before_H * after_H[j + 1]  # (K, C) or (C,)
            if formulation == "minres":
                n_j = R[j].size
                M = (c.reshape(-1) @ gram_ops[j]).reshape(n_j, n_j)
                R[j][:] = _solve_small(M, h.reshape(-1) @ Y[j], symmetric=True)
                V[j] = (rows[j] @ R[j]).reshape(K, -1)
                G[j], H[j] = V[j] @ V[j].T, (Y[j] @ R[j]).reshape(K, -1)
            else:
                M = np.einsum("k,kab->ab", c, stacks[j])
                R[j][:] = _solve_small(M, res_f[j] @ h, symmetric=False)
                G[j], H[j] = np.einsum("a,kab,b->k", R[j], stacks[j], R[j]), R[j] @ res_f[j]
            before_G = before_G * G[j]
            before_H = before_H * H[j]
        if _relative_change(previous, flat, offsets) < tolerance:
            break
    return R, iterations


_POSV, _GESV = scipy.linalg.get_lapack_funcs(("posv", "gesv"), dtype=np.float64)


def _solve_small(M: np.ndarray, b: np.ndarray, *, symmetric: bool) -> np.ndarray:
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


def project_alphas(state: EnrichmentState, formulation: str = "minres") -> tuple[np.ndarray, float, float]:
    """Recompute all weights (the projection step) and the residual norm.

    Returns
    -------
    alphas : ndarray, shape (n,)
    residual : float
        ``||F - A U||`` with the new weights.
    source_norm : float
        ``||F||``.
    """
    alphas, residual, source_norm, _ = _project(state, formulation)
    return alphas, residual, source_norm


def _update_order(state: EnrichmentState) -> list[int]:
    """Modes in the order the update sweep visits them: smallest first.

    The projection's sweep runs the other way (largest first, the cheap order
    of :func:`~pgdcli.tensors.cp.sweep_order`), so its partial results are the
    suffixes the update sweep needs (:func:`_suffix_sweeps`).
    """
    return sweep_order([state.images[j].shape[1] for j in range(state.op.order)])[::-1]


def _suffix_sweeps(columns: list[np.ndarray], order: list[int]) -> list[np.ndarray | None]:
    """Orthogonal sweeps over the trailing modes of ``order``.

    Parameters
    ----------
    columns : list of ndarray, each shape (m_j, C)
        Factor matrices of the residual terms.
    order : list of int
        A permutation of the modes.

    Returns
    -------
    list of length d + 1
        Entry ``i`` is the sweep over the modes ``order[i:]`` (shape (r_i, C),
        visiting ``order[-1]`` first); entry 0 covers every mode, entry d is None.
        They do not depend on the weights.
    """
    out: list[np.ndarray | None] = [None] * (len(order) + 1)
    for i in range(len(order) - 1, -1, -1):
        out[i] = sweep_step(out[i + 1], columns[order[i]])
    return out


def _project(state: EnrichmentState, formulation: str) -> tuple[np.ndarray, float, float, list]:
    """:func:`project_alphas`, also returning the suffix sweeps of :func:`_update_order`."""
    K, n, nF = state.op.n_terms, state.rank, state.source.rank
    suffixes = _suffix_sweeps([state.residual_columns(j) for j in range(state.op.order)], _update_order(state))
    Z = suffixes[0]
    zF = Z[:, :nF] @ state.source.weights
    phi = Z[:, nF:].reshape(Z.shape[0], K, n).sum(axis=1)
    if formulation == "minres":
        alphas = np.linalg.lstsq(phi, zF, rcond=None)[0]
    else:
        alphas = _galerkin_alphas(state)
    return alphas, float(np.linalg.norm(zF - phi @ alphas)), float(np.linalg.norm(zF)), suffixes


def _galerkin_alphas(state: EnrichmentState) -> np.ndarray:
    """Paper's eq. (15): ``B alpha = H`` with ``B_il = <U_i, A U_l>``, ``H_i = <U_i, F>``."""
    d = state.op.order
    B = None
    Hv = None
    for j in range(d):
        u = state.factors[j]
        bj = np.einsum("ai,kal->kil", u, state.images[j])
        hj = u.T @ state.source.factors[j]
        B = bj if B is None else B * bj
        Hv = hj if Hv is None else Hv * hj
    return _solve_small(B.sum(axis=0), Hv @ state.source.weights, symmetric=False)


def residual_norm(op: SeparatedOperator, source: CPTensor, approx: CPTensor) -> float:
    """``||F - A U||`` in separated form (orthogonal sweep), never forming a full tensor."""
    return (source + op.apply(approx).scaled(-1.0)).norm()


# The update's conjugate gradients stop after CG_ITERATIONS steps, or once the preconditioned
# residual has fallen by CG_RTOL: the fixed point repeats the update after every enrichment, so
# inexact solves suffice. Measured on the shipped problems (heat2d, spring, relaxation,
# heat2d_source): 40 steps and rtol 0 give the same modes and residuals (within one or two modes)
# for up to 1.4x the build time.
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


STAGNATION_WINDOW = 8

def run_enrichment(disc: Discretization, opts, tol: float, nmax: int, callback):
    state = EnrichmentState.empty(disc.operator, disc.source)
    source_norm = disc.source.norm()
    history = [1.0 if source_norm > 0 else 0.0]
    iterations: list[int] = []
    if source_norm == 0.0:
        return state, history, iterations, 0
    status = 1
    for _ in range(nmax):
        res_w, res_f = state.residual()
        factors, its = None, 0
        starts = (make(res_f) for make in (partial(_dominant_term, res_w), partial(_random_start, seed=state.rank)))
        for start in starts:  # the random start only if the first gives a zero factor
            factors, its = enrich(
                disc.operator, res_w, res_f,
                formulation=opts.formulation,
                tolerance=opts.fixed_point_tolerance,
                max_iterations=opts.max_fixed_point_iterations,
                start=start,
            )
            norms = [np.linalg.norm(f) for f in factors]
            if min(norms) > 0.0 and np.all(np.isfinite(norms)):
                break
        else:
            status = 2
            break
        state.append([f / nf for f, nf in zip(factors, norms)], float(np.prod(norms)))
        if opts.update and opts.formulation == "minres":
            res = _update_all(state, history[-1] * source_norm)
        else:
            state.alphas, res, _ = project_alphas(state, opts.formulation)
        rel = res / source_norm
        history.append(rel)
        iterations.append(its)
        if callback is not None:
            callback({"mode": state.rank, "residual": rel, "iterations": its})
        if rel <= tol:
            status = 0
            break
        if len(history) > STAGNATION_WINDOW and history[-1] > 0.99 * history[-1 - STAGNATION_WINDOW]:
            status = 2
            break
    return state, history, iterations, status


def _dominant_term(res_w: np.ndarray, res_f: list[np.ndarray]) -> list[np.ndarray]:
    """Factors of the residual's largest rank-one term: a start that is never orthogonal to it."""
    size = np.abs(res_w) * np.prod([np.linalg.norm(f, axis=0) for f in res_f], axis=0)
    c = int(np.argmax(size))
    return [f[:, c] + 0.0 for f in res_f]


def _random_start(res_f: list[np.ndarray], seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)  # deterministic: the same spec gives the same codebook
    return [rng.standard_normal(f.shape[0]) for f in res_f]


def _update_all(state: EnrichmentState, previous: float) -> float:
    """Update every mode once after an enrichment, checking the residual once, at the end.

    The first update re-solves all factors of one mode, weights included, so it
    also does the projection's job: measured on the shipped problems, this
    gives the same modes and residuals as projecting first and checking every
    mode's update, for one orthogonal sweep per enrichment instead of two.
    Should the residual not have fallen below ``previous`` (the residual before
    the enrichment; rounding in the normal equations near the tolerance can do
    that), the updates are undone and the careful path is taken: projection,
    then mode by mode updates kept only if they lower the residual
    (:func:`_update_sweep`).

    Returns
    -------
    float
        ``||F - A U||`` after the update.
    """
    saved = state.snapshot()
    for j in _update_order(state):
        update_mode(state, j)
    res = state.residual_norm()
    if res < previous:
        return res
    state.restore(saved)
    state.alphas, res, _, suffixes = _project(state, "minres")
    return _update_sweep(state, res, suffixes)


def _update_sweep(state: EnrichmentState, res: float, suffixes: list) -> float:
    """One update of every coordinate mode; keeps a mode's update only if it lowers the residual.

    The modes are visited in :func:`_update_order`. Each candidate's residual
    norm needs at most one new sweep step: the modes before it (already final)
    are swept into ``prefix`` as the loop goes, the modes after it are
    unchanged since the projection, whose suffix sweeps ``suffixes`` (from
    :func:`_project`, same factors) cover them.
    """
    prefix = None
    order = _update_order(state)
    for i, j in enumerate(order):
        saved = (state.alphas.copy(), state.factors[j].copy(), state.images[j].copy())
        update_mode(state, j)
        extended, new_res = _extend_and_norm(prefix, state, j, suffixes[i + 1])
        if new_res <= res:
            res = new_res
        else:
            state.alphas = saved[0]
            state.set_mode(j, saved[1], saved[2])
            if extended is not None:
                extended, _ = _extend_and_norm(prefix, state, j, suffixes[i + 1])
        prefix = extended
    return res


def _extend_and_norm(prefix: np.ndarray | None, state: EnrichmentState, j: int,
                     suffix: np.ndarray | None) -> tuple[np.ndarray | None, float]:
    """Sweep mode ``j`` into ``prefix`` and return it with the residual norm ``||F - A U||``.

    ``prefix`` (r_p, C) and ``suffix`` (r_s, C) are orthogonal-sweep results
    (coefficients in orthonormal bases) over the modes before and after ``j``,
    None for no mode. The norm is then that of the (r_p', r_s) matrix
    ``prefix' diag(w) suffix^T``, and its rounding error that of the last
    step of a full sweep (a weighted sum of the terms). With no suffix (the
    last mode) the norm needs no QR at all, and no extended prefix is returned.
    """
    columns, weights = state.residual_columns(j), state.residual_weights()
    if suffix is None:
        k = columns if prefix is None else khatri_rao_rows(prefix, columns)
        return None, float(np.linalg.norm(k @ weights))
    extended = sweep_step(prefix, columns)
    return extended, float(np.linalg.norm((extended * weights) @ suffix.T))

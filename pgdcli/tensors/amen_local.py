"""The local systems of the alternating linear schemes: interfaces, products, solves of one core.

With the cores left of ``k`` left-orthogonal and those right of it right-orthogonal, the train
``x`` is ``X_{!=k} vec(x_k)`` for an orthonormal ``X_{!=k}``, and the system ``B x = g`` projected
on it is ``B_k y = g_k`` with

    B_k[(a, i, c), (b, j, e)] = sum_{p, q} L[a, p, b] B[p, i, j, q] R[c, q, e]
    g_k[a, i, c]              = sum_{s, t} l[a, s]    g[s, i, t]    r[c, t]

where ``L``, ``R`` (test rank, operator rank, trial rank) and ``l``, ``r`` (test rank, rank of
``g``) contract the other cores: the *interfaces*, updated one core at a time as the sweep
moves (:func:`left_interface`, :func:`right_interface`, :func:`left_vector_interface`,
:func:`right_vector_interface`). The operator's cores are ``(p, i, j, q)`` or, on a diagonal
mode, ``(p, i, q)`` (:class:`pgdcli.tensors.tt_matrix.TTMatrix`).

:func:`solve_local` solves a symmetric positive definite local system: densely (Cholesky) while
it is small, else by conjugate gradients with the inverse of its block diagonal (one ``n x n``
block per right rank over the left rank and the mode: the coupling with the time, which the
left interface carries, exact; Dolgov's "left Jacobi") as preconditioner.

numpy and scipy.linalg only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

__all__ = ["local_apply", "local_matrix", "local_rhs", "left_interface", "right_interface",
           "left_vector_interface", "right_vector_interface", "LocalSolve", "solve_local", "DENSE_LOCAL"]

#: Local systems up to this many unknowns are formed and solved densely.
DENSE_LOCAL = 1500
#: Flops allowed for inverting the preconditioner's blocks (beyond: its diagonal alone).
BLOCK_INVERSE_BUDGET = 2e9


def _operator_times_right(core: np.ndarray, t1: np.ndarray) -> np.ndarray:
    """``sum_{j, q} B[p, i, j, q] t1[b, j, c, q]`` -> ``(p, i, b, c)``."""
    if core.ndim == 4:
        return np.tensordot(core, t1, axes=((2, 3), (1, 3)))
    b, n, c, q = t1.shape
    stacked = t1.transpose(1, 3, 0, 2).reshape(n, q, b * c)  # (i, q, b c)
    out = np.matmul(core.transpose(1, 0, 2), stacked)  # (i, p, b c)
    return out.reshape(n, core.shape[0], b, c).transpose(1, 0, 2, 3)


def local_apply(left: np.ndarray, core: np.ndarray, right: np.ndarray, y: np.ndarray) -> np.ndarray:
    """``B_k y`` for ``y`` of shape ``(b, j, e)``; returns ``(a, i, c)``."""
    t1 = np.tensordot(y, right, axes=(2, 2))  # (b, j, c, q)
    t2 = _operator_times_right(core, t1)  # (p, i, b, c)
    return np.tensordot(left, t2, axes=((1, 2), (0, 2)))  # (a, i, c)


def local_matrix(left: np.ndarray, core: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``B_k`` as a dense ``(a i c, b j e)`` matrix (small local systems)."""
    if core.ndim == 3:
        n = core.shape[1]
        full = np.zeros((core.shape[0], n, n, core.shape[2]))
        full[:, np.arange(n), np.arange(n), :] = core
        core = full
    m = np.einsum("apb,pijq,cqe->aicbje", left, core, right, optimize=True)
    size = m.shape[0] * m.shape[1] * m.shape[2]
    return m.reshape(size, size)


def local_rhs(left: np.ndarray, g: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``g_k`` of shape ``(a, i, c)`` from the vector interfaces ``(a, s)``, ``(c, t)`` and the core ``(s, i, t)``."""
    return np.tensordot(np.tensordot(left, g, axes=(1, 0)), right, axes=(2, 1))


def left_interface(left: np.ndarray, core: np.ndarray, test: np.ndarray, trial: np.ndarray) -> np.ndarray:
    """The operator's interface one core further right: ``(a', q, b')`` from ``(a, p, b)``."""
    t = np.tensordot(left, trial, axes=(2, 0))  # (a, p, j, b')
    if core.ndim == 4:
        t = np.tensordot(t, core, axes=((1, 2), (0, 2)))  # (a, b', i, q)
    else:
        a, p, n, b1 = t.shape
        stacked = t.transpose(2, 0, 3, 1).reshape(n, a * b1, p)  # (i, a b', p)
        t = np.matmul(stacked, core.transpose(1, 0, 2))  # (i, a b', q)
        t = t.reshape(n, a, b1, -1).transpose(1, 2, 0, 3)  # (a, b', i, q)
    return np.tensordot(test, t, axes=((0, 1), (0, 2))).transpose(0, 2, 1)  # (a', q, b')


def right_interface(right: np.ndarray, core: np.ndarray, test: np.ndarray, trial: np.ndarray) -> np.ndarray:
    """The operator's interface one core further left: ``(a, p, b)`` from ``(c, q, e)``."""
    t1 = np.tensordot(trial, right, axes=(2, 2))  # (b, j, c, q)
    t2 = _operator_times_right(core, t1)  # (p, i, b, c)
    return np.tensordot(test, t2, axes=((1, 2), (1, 3)))  # (a, p, b)


def left_vector_interface(left: np.ndarray, g: np.ndarray, test: np.ndarray) -> np.ndarray:
    """``(a', t)`` from ``(a, s)``: ``sum test[a, i, a'] left[a, s] g[s, i, t]``."""
    t = np.tensordot(left, g, axes=(1, 0))  # (a, i, t)
    return np.tensordot(test, t, axes=((0, 1), (0, 1)))


def right_vector_interface(right: np.ndarray, g: np.ndarray, test: np.ndarray) -> np.ndarray:
    """``(a, s)`` from ``(c, t)``: ``sum test[a, i, c] g[s, i, t] right[c, t]``."""
    t = np.tensordot(g, right, axes=(2, 1))  # (s, i, c)
    return np.tensordot(test, t, axes=((1, 2), (1, 2)))


@dataclass
class LocalSolve:
    """How one local system was solved: ``dense``, or conjugate gradients with ``iterations`` (``last_gain``:
    what the last step took off twice the functional)."""

    dense: bool
    iterations: int
    relative_residual: float
    last_gain: float = 0.0


def _block_preconditioner(left: np.ndarray, core: np.ndarray, right: np.ndarray):
    """The inverse of ``B_k``'s diagonal blocks as a function, as fine as :data:`BLOCK_INVERSE_BUDGET` allows.

    The finest: one block over ``(a, i)`` per right rank ``c`` (the left interface carries the
    time, whose coupling with the mode is what makes the local systems stiff; the right rank is
    taken at its diagonal). Coarser, in turn: one such block for all ``c`` (the right interface's
    diagonal averaged over them), one ``n x n`` block per rank pair ``(a, c)``, one for all of
    them, the diagonal. A diagonal mode's blocks are ``(a, b)`` per ``(c, i)``, or per ``i``.
    """
    dr = np.einsum("cqc->cq", right)
    mean_r = dr.mean(axis=0)
    a, n, c = left.shape[0], core.shape[1], dr.shape[0]
    if core.ndim == 3:
        if c * n * a ** 3 <= BLOCK_INVERSE_BUDGET:
            blocks = np.einsum("apb,piq,cq->ciab", left, core, dr, optimize=True)
            inverse = np.linalg.inv(blocks)  # (c, i, a, b)
            return lambda v: np.matmul(inverse, v.transpose(2, 1, 0)[..., None])[..., 0].transpose(2, 1, 0)
        if n * a ** 3 <= BLOCK_INVERSE_BUDGET:
            inverse = np.linalg.inv(np.einsum("apb,piq,q->iab", left, core, mean_r, optimize=True))  # (i, a, b)
            return lambda v: np.einsum("iab,bic->aic", inverse, v, optimize=True)
        diag = np.einsum("apa,piq,cq->aic", left, core, dr, optimize=True)
        return lambda v: v / diag
    if c * (a * n) ** 3 <= BLOCK_INVERSE_BUDGET:
        blocks = np.einsum("apb,pijq,cq->caibj", left, core, dr, optimize=True).reshape(c, a * n, a * n)
        inverse = np.linalg.inv(blocks)  # (c, a i, b j)
        return lambda v: np.matmul(inverse, v.reshape(a * n, c).T[..., None])[..., 0].T.reshape(a, n, c)
    if (a * n) ** 3 <= BLOCK_INVERSE_BUDGET:
        block = np.einsum("apb,pijq,q->aibj", left, core, mean_r, optimize=True).reshape(a * n, a * n)
        inverse = np.linalg.inv(block)
        return lambda v: (inverse @ v.reshape(a * n, c)).reshape(a, n, c)
    dl = np.einsum("apa->ap", left)
    if a * c * n ** 3 <= BLOCK_INVERSE_BUDGET:
        blocks = np.einsum("ap,pijq,cq->acij", dl, core, dr, optimize=True)
        inverse = np.linalg.inv(blocks)  # (a, c, i, j)
        return lambda v: np.matmul(inverse, v.transpose(0, 2, 1)[..., None])[..., 0].transpose(0, 2, 1)
    if n ** 3 <= BLOCK_INVERSE_BUDGET:
        inverse = np.linalg.inv(np.einsum("p,pijq,q->ij", dl.mean(axis=0), core, mean_r, optimize=True))
        return lambda v: np.einsum("ij,ajc->aic", inverse, v, optimize=True)
    diag = np.einsum("ap,piiq,cq->aic", dl, core, dr, optimize=True)
    return lambda v: v / diag


def solve_local(left: np.ndarray, core: np.ndarray, right: np.ndarray, rhs: np.ndarray, energy: float,
                max_iterations: int = 200) -> tuple[np.ndarray, LocalSolve]:
    """Solve the symmetric positive definite ``B_k y = rhs`` until what is left to gain is within ``energy``.

    Conjugate gradients lower ``y^T B_k y / 2 - rhs^T y`` by ``alpha_k r_k^T z_k / 2`` at step ``k``;
    for the normal equations of ``A x = f`` twice that is what the step takes off ``||A x - f||^2``.
    They stop once a step takes off less than ``energy^2 / 10``: the steps' gains fall
    geometrically, so what is left is then about ``energy^2`` or less. (A relative residual of the
    normal equations would not do: it bounds ``||A x - f||`` only up to the condition number.)
    Small systems are solved densely (Cholesky), to rounding.

    Parameters
    ----------
    left, core, right : ndarray
        The interfaces ``(a, p, a)``, ``(c, q, c)`` and the operator's core.
    rhs : ndarray, shape (a, n, c)
    energy : float
        What may be left of the decrease of ``sqrt(2 phi)``, absolute.

    Returns
    -------
    (ndarray, LocalSolve)
    """
    size = rhs.size
    norm = float(np.linalg.norm(rhs))
    if norm == 0.0:
        return np.zeros_like(rhs), LocalSolve(size <= DENSE_LOCAL, 0, 0.0)
    if size <= DENSE_LOCAL:
        matrix = local_matrix(left, core, right)
        matrix = 0.5 * (matrix + matrix.T)
        try:
            y = scipy.linalg.solve(matrix, rhs.reshape(-1), assume_a="pos", check_finite=False)
        except np.linalg.LinAlgError:  # positive semidefinite in rounding: the least-squares solution
            y = scipy.linalg.lstsq(matrix, rhs.reshape(-1), check_finite=False)[0]
        y = y.reshape(rhs.shape)
        res = float(np.linalg.norm(local_apply(left, core, right, y) - rhs)) / norm
        return y, LocalSolve(True, 0, res, 0.0)
    precondition = _block_preconditioner(left, core, right)
    return _conjugate_gradients(lambda v: local_apply(left, core, right, v), precondition, rhs, norm,
                                0.1 * energy * energy, max_iterations)


def _conjugate_gradients(apply, precondition, rhs: np.ndarray, norm: float, smallest_gain: float,
                         max_iterations: int) -> tuple[np.ndarray, LocalSolve]:
    """Preconditioned conjugate gradients from zero, until a step gains less than ``smallest_gain``."""
    y = np.zeros_like(rhs)
    r = rhs.copy()
    z = precondition(r)
    p = z.copy()
    rz = float(np.vdot(r, z))
    gain = np.inf
    its = 0
    for its in range(1, max_iterations + 1):
        q = apply(p)
        pq = float(np.vdot(p, q))
        if not pq > 0.0:
            break
        alpha = rz / pq
        y += alpha * p
        r -= alpha * q
        gain = alpha * rz  # what this step took off twice the functional
        if gain <= smallest_gain:
            break
        z = precondition(r)
        rz_new = float(np.vdot(r, z))
        p = z + (rz_new / rz) * p
        rz = rz_new
    return y, LocalSolve(False, its, float(np.linalg.norm(r)) / norm, gain)

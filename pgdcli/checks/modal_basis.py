"""The eigenbasis of a method-of-lines operator, for the modal reference (:mod:`.reference_pde_modal`).

``B = V diag(lambda) V^-1``, trusted only when ``cond(V)`` is below :data:`MAX_CONDITION`. On a
tensor grid of two space coordinates an operator such as ``kappa (u_xx + u_yy)`` is a Kronecker sum
``B = A (x) I + I (x) C`` of two one-dimensional operators (each direction's boundary conditions
eliminated along its own lines); its eigenvalues are then ``a_i + c_j`` and its eigenvectors
``V_A (x) V_C``: two small decompositions instead of one of the whole grid (``O(n^3)`` instead of
``O(n^6)`` for ``n`` nodes a side), and a change of basis in ``O(n^3)`` instead of ``O(n^4)``.
The structure is read off the assembled matrix and checked to rounding; any other operator is
decomposed whole.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

__all__ = ["Modes", "KroneckerModes", "decompose", "decompose_samples", "MAX_CONDITION"]

#: The largest condition number of the eigenvector matrix accepted: the values then carry relative
#: errors of about ``MAX_CONDITION * eps`` (2e-12), below the integrators' 1e-10 to 1e-12.
MAX_CONDITION = 1e4

#: A matrix is taken as a Kronecker sum when it differs from the one read off it by at most this
#: (relative, Frobenius): the rounding of its assembly.
_KRONECKER = 1e-12
#: Samples' matrices are taken as multiples of one when they differ from it by at most this (relative,
#: Frobenius): the rounding of the products of a few coefficients.
_PROPORTIONAL = 1e-13


class Modes:
    """An eigenbasis ``B = V diag(lam) V^-1`` over the last axis of states ``(..., m)``."""

    def __init__(self, lam: np.ndarray, V: np.ndarray, lu) -> None:
        self.lam, self.V, self.lu = lam, V, lu

    def to_modes(self, y: np.ndarray) -> np.ndarray:
        """``V^-1 y`` along the last axis (complex)."""
        flat = np.asarray(y).reshape(-1, self.lam.size)
        return sla.lu_solve(self.lu, flat.T.astype(complex), check_finite=False).T.reshape(np.shape(y))

    def from_modes(self, z: np.ndarray) -> np.ndarray:
        """``V z`` along the last axis (complex)."""
        return z @ self.V.T


class KroneckerModes(Modes):
    """The eigenbasis of ``A (x) I + I (x) C`` on an ``(nx, ny)`` grid (C order): ``V = V_A (x) V_C``, ``lam``
    the sums of ``a`` (A's eigenvalues) and ``c`` (C's)."""

    def __init__(self, first: tuple, second: tuple) -> None:
        (a, self.Va, lua), (c, self.Vc, luc) = first, second
        self.a, self.c, self.shape = a, c, (a.size, c.size)
        self.lam = (a[:, None] + c[None, :]).reshape(-1)
        self.Va_inv = sla.lu_solve(lua, np.eye(a.size, dtype=complex))
        self.Vc_inv = sla.lu_solve(luc, np.eye(c.size, dtype=complex))

    def to_modes(self, y: np.ndarray) -> np.ndarray:
        grid = np.asarray(y).reshape(np.shape(y)[:-1] + self.shape)
        return (self.Va_inv @ grid @ self.Vc_inv.T).reshape(np.shape(y))

    def from_modes(self, z: np.ndarray) -> np.ndarray:
        grid = np.asarray(z).reshape(np.shape(z)[:-1] + self.shape)
        return (self.Va @ grid @ self.Vc.T).reshape(np.shape(z))


def decompose_samples(model, blocks: list) -> tuple[Modes, np.ndarray] | None:
    """One trusted eigenbasis of every sample's operator ``B_s`` (sparse, m x m) and their eigenvalues
    ``(S, m)``, or None.

    On a 2-D tensor grid, ``B_s = A_s (x) I + I (x) C_s`` with ``A_s = alpha_s A + sigma I`` and
    ``C_s = gamma_s C + tau I`` (a diffusivity per direction, ``u_xx + a u_yy``; a rate): eigenvalues
    ``alpha_s a_i + gamma_s c_j + sigma_s + tau_s``. Otherwise ``B_s = c_s B`` (one factor):
    ``c_s lambda``.
    """
    shape = _tensor_interior(model)
    split = None if shape is None else _split_samples(blocks, shape)
    if split is not None:
        (A, alpha), (C, gamma), shift = split
        modes = _kronecker_modes(A, C)
        if modes is not None:
            lam = (alpha[:, None, None] * modes.a[None, :, None] + gamma[:, None, None] * modes.c[None, None, :]
                   + shift[:, None, None])
            return modes, lam.reshape(len(blocks), -1)
    common = _common_matrix(blocks)
    modes = None if common is None else _whole_modes(common[0])  # (its split, if any, was tried above)
    return None if modes is None else (modes, common[1][:, None] * modes.lam[None, :])


def _split_samples(blocks: list, shape: tuple[int, int]):
    """``((A, alpha), (C, gamma), shift)``: every block a Kronecker sum of multiples of two traceless
    matrices plus a multiple of the identity, or None."""
    firsts, seconds, shift = [], [], np.empty(len(blocks))
    for s, block in enumerate(blocks):
        parts = _kronecker_parts(block, shape)
        if parts is None:
            return None
        A, C = parts
        shift[s] = np.trace(A) / shape[0] + np.trace(C) / shape[1]
        firsts.append(A - np.trace(A) / shape[0] * np.eye(shape[0]))
        seconds.append(C - np.trace(C) / shape[1] * np.eye(shape[1]))
    first, second = _common_matrix(firsts, allow_zero=True), _common_matrix(seconds, allow_zero=True)
    return None if first is None or second is None else (first, second, shift)


def _common_matrix(blocks: list, allow_zero: bool = False) -> tuple[np.ndarray, np.ndarray] | None:
    """``(B, c)`` with ``B_s = c_s B`` for every sample (``B`` the largest block, dense), or None. Sparse
    blocks are compared sparse: only the one returned is made dense. All zero: ``c = 0`` if allowed."""
    norms = np.array([_norm(B) for B in blocks])
    if not np.isfinite(norms).all() or (norms.max() == 0.0 and not allow_zero):
        return None
    ref = blocks[int(np.argmax(norms))]
    dense = ref.toarray() if sp.issparse(ref) else ref
    if norms.max() == 0.0:
        return dense, np.zeros(len(blocks))
    scales = np.array([float(ref.multiply(B).sum()) if sp.issparse(ref) else float(np.vdot(ref, B))
                       for B in blocks]) / norms.max() ** 2
    for B, c, nb in zip(blocks, scales, norms):
        if _norm(B - c * ref) > _PROPORTIONAL * max(nb, 1e-300):
            return None
    return dense, scales


def _norm(B) -> float:
    """The Frobenius norm of a dense or sparse matrix."""
    return float(np.linalg.norm(B.data if sp.issparse(B) else B))


def decompose(model, B: np.ndarray) -> Modes | None:
    """The trusted eigenbasis of ``B`` (m, m), the operator of ``model`` on its interior values, or None."""
    shape = _tensor_interior(model)
    parts = None if shape is None else _kronecker_parts(B, shape)
    modes = None if parts is None else _kronecker_modes(*parts)
    return modes if modes is not None else _whole_modes(B)


def _kronecker_modes(A: np.ndarray, C: np.ndarray) -> KroneckerModes | None:
    """The trusted eigenbasis of ``A (x) I + I (x) C``, or None."""
    first, second = _eig(A), _eig(C)
    if first is None or second is None or not first[3] * second[3] * MAX_CONDITION >= 1.0:
        return None
    return KroneckerModes(first[:3], second[:3])


def _whole_modes(B: np.ndarray) -> Modes | None:
    """The trusted eigenbasis of ``B`` decomposed whole, or None."""
    whole = _eig(B)
    return None if whole is None or not whole[3] * MAX_CONDITION >= 1.0 else Modes(*whole[:3])


def _tensor_interior(model) -> tuple[int, int] | None:
    """``(nx, ny)`` when one unknown's interior values are a tensor grid of two space coordinates, in C order."""
    if model.q != 1 or len(model.grid.shape) != 2:
        return None
    ny = model.grid.shape[1]
    interior = np.asarray(model.interior[0])
    xs, ys = np.unique(interior // ny), np.unique(interior % ny)
    expected = (xs[:, None] * ny + ys[None, :]).reshape(-1)
    return (xs.size, ys.size) if np.array_equal(interior, expected) else None


def _kronecker_parts(B, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(A, C)`` with ``B = A (x) I + I (x) C`` to rounding, else None (``C[0, 0] = 0``: the sum's split).
    ``B`` dense or sparse (compared sparse: a sample's dense block is the grid's size squared)."""
    nx, ny = shape
    if sp.issparse(B):
        B = B.tocsr()
        first, second = np.arange(nx) * ny, np.arange(ny)  # the nodes (i, 0) and (0, j)
        A = B[first][:, first].toarray()
        C = B[second][:, second].toarray()
        C[np.diag_indices(ny)] -= A[0, 0]
        rest = B - sp.kron(A, sp.identity(ny)) - sp.kron(sp.identity(nx), C)
        return (A, C) if _norm(rest) <= _KRONECKER * _norm(B) else None
    B4 = B.reshape(nx, ny, nx, ny)
    A = B4[:, 0, :, 0].copy()
    C = B4[0, :, 0, :].copy()
    C[np.diag_indices(ny)] -= A[0, 0]
    rest = B4.copy()
    for j in range(ny):
        rest[:, j, :, j] -= A
    for i in range(nx):
        rest[i, :, i, :] -= C
    return (A, C) if np.linalg.norm(rest) <= _KRONECKER * np.linalg.norm(B) else None


def _eig(B: np.ndarray):
    """``(eigenvalues, V, lu of V, reciprocal condition of V)``, or None.

    LAPACK's ``geev`` is backward stable (``B V - V Lambda`` is at rounding level relative to
    ``|B| |V|``); what can spoil the values is the change of basis, whose rounding errors the
    condition number of ``V`` multiplies. It is estimated from the LU factors (LAPACK ``gecon``,
    O(m^2)) rather than computed by an SVD (as costly as the decomposition itself).
    """
    try:
        lam, V = sla.eig(B, overwrite_a=False, check_finite=True)
        lu, piv = sla.lu_factor(V, check_finite=False)
    except (np.linalg.LinAlgError, ValueError):
        return None
    gecon = sla.get_lapack_funcs("gecon", (lu,))
    rcond, info = gecon(lu, np.linalg.norm(V, 1), norm="1")
    if info != 0 or not np.isfinite(rcond):
        return None
    return lam, V, (lu, piv), float(rcond)

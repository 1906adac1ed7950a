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

__all__ = ["Modes", "decompose", "MAX_CONDITION"]

#: The largest condition number of the eigenvector matrix accepted: the values then carry relative
#: errors of about ``MAX_CONDITION * eps`` (2e-12), below the integrators' 1e-10 to 1e-12.
MAX_CONDITION = 1e4

#: A matrix is taken as a Kronecker sum when it differs from the one read off it by at most this
#: (relative, Frobenius): the rounding of its assembly.
_KRONECKER = 1e-12


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
    """The eigenbasis of ``A (x) I + I (x) C`` on an ``(nx, ny)`` grid (C order): ``V = V_A (x) V_C``."""

    def __init__(self, first: tuple, second: tuple) -> None:
        (a, self.Va, lua), (c, self.Vc, luc) = first, second
        self.shape = (a.size, c.size)
        self.lam = (a[:, None] + c[None, :]).reshape(-1)
        self.Va_inv = sla.lu_solve(lua, np.eye(a.size, dtype=complex))
        self.Vc_inv = sla.lu_solve(luc, np.eye(c.size, dtype=complex))

    def to_modes(self, y: np.ndarray) -> np.ndarray:
        grid = np.asarray(y).reshape(np.shape(y)[:-1] + self.shape)
        return (self.Va_inv @ grid @ self.Vc_inv.T).reshape(np.shape(y))

    def from_modes(self, z: np.ndarray) -> np.ndarray:
        grid = np.asarray(z).reshape(np.shape(z)[:-1] + self.shape)
        return (self.Va @ grid @ self.Vc.T).reshape(np.shape(z))


def decompose(model, B: np.ndarray) -> Modes | None:
    """The trusted eigenbasis of ``B`` (m, m), the operator of ``model`` on its interior values, or None."""
    shape = _tensor_interior(model)
    parts = None if shape is None else _kronecker_parts(B, shape)
    if parts is not None:
        first, second = _eig(parts[0]), _eig(parts[1])
        if first is not None and second is not None and first[3] * second[3] * MAX_CONDITION >= 1.0:
            return KroneckerModes(first[:3], second[:3])
    whole = _eig(B)
    if whole is None or not whole[3] * MAX_CONDITION >= 1.0:
        return None
    return Modes(*whole[:3])


def _tensor_interior(model) -> tuple[int, int] | None:
    """``(nx, ny)`` when one unknown's interior values are a tensor grid of two space coordinates, in C order."""
    if model.q != 1 or len(model.grid.shape) != 2:
        return None
    ny = model.grid.shape[1]
    interior = np.asarray(model.interior[0])
    xs, ys = np.unique(interior // ny), np.unique(interior % ny)
    expected = (xs[:, None] * ny + ys[None, :]).reshape(-1)
    return (xs.size, ys.size) if np.array_equal(interior, expected) else None


def _kronecker_parts(B: np.ndarray, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(A, C)`` with ``B = A (x) I + I (x) C`` to rounding, else None (``C[0, 0] = 0``: the sum's split)."""
    nx, ny = shape
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

"""The phi-functions of the exponential integrators, for ``h c_j A`` at every node ``c_j``.

``phi_0(z) = e^z``, ``phi_{k+1}(z) = (phi_k(z) - 1/k!) / z``. For the matrices ``h c_j A`` (``A``
the eliminated Chebyshev ``d^2/dx^2``, the same for every node of the diffusion's parameter) they are
computed from one eigendecomposition ``A = V diag(lambda) V^-1``: ``phi_k(h c_j A) = V diag(phi_k(h c_j
lambda)) V^-1``, the scalars by the contour integral of Kassam & Trefethen (2005) (the mean of
``phi_k`` over a circle of radius 1 around ``z``), which avoids the cancellation of the explicit
formula for small ``|z|``. ``A`` is not normal, but its eigenvectors are well conditioned at the
node counts used (``cond(V)`` is recorded; :func:`phi_matrices` falls back to the ``expm`` of an
augmented matrix, Sidje 1998 / Higham's ``phi`` by block triangular exponentials, when it exceeds
:data:`MAX_CONDITION`).
"""

from __future__ import annotations

import numpy as np
import scipy.linalg as sla

__all__ = ["phi_scalars", "phi_matrices", "Eigen"]

#: Points on the contour of the scalar phi-functions (their error is ~ 1e-15 beyond 32).
CONTOUR_POINTS = 64
#: Eigenvector condition above which the matrix functions go through expm instead.
MAX_CONDITION = 1e6


def phi_scalars(z: np.ndarray, k_max: int) -> np.ndarray:
    """``phi_0 .. phi_{k_max}`` at the points ``z`` (complex or real), shape (k_max + 1,) + z.shape."""
    z = np.asarray(z, dtype=complex)
    out = np.empty((k_max + 1,) + z.shape, dtype=complex)
    large = np.abs(z) > 1.0  # far from 0 the explicit recursion is exact enough; the contour covers the rest
    # the stiff modes of h c A are nearly all large: they take one exponential each, not a contour's
    for points, mean in ((z[large][:, None], False), (z[~large][:, None] + _contour(), True)):
        p = np.exp(points)
        factorial = 1.0
        for k in range(k_max + 1):
            if k:
                p = (p - 1.0 / factorial) / points
                factorial *= k
            out[k][large if not mean else ~large] = p.mean(axis=-1) if mean else p[:, 0]
    return out


def _contour() -> np.ndarray:
    """The unit circle's CONTOUR_POINTS points (midpoint rule), around which small ``z`` are averaged."""
    return np.exp(2j * np.pi * (np.arange(CONTOUR_POINTS) + 0.5) / CONTOUR_POINTS)


class Eigen:
    """One eigendecomposition of ``A`` for every ``phi_k(h c A)``."""

    def __init__(self, A: np.ndarray) -> None:
        self.A = A
        lam, V = np.linalg.eig(A)
        if not np.iscomplexobj(A) and not np.any(lam.imag) and not np.any(V.imag):
            lam, V = lam.real, V.real  # the usual case (real spectrum): real arithmetic below
        self.lam, self.V = lam, V
        self.condition = float(np.linalg.cond(V))
        self.Vinv = np.linalg.inv(V) if self.condition <= MAX_CONDITION else None

    def spectra(self, scales: np.ndarray, k_max: int) -> np.ndarray | None:
        """``phi_k(s lambda)`` for every scale: shape (k_max + 1, len(scales), m), None when ``V`` is ill-conditioned.

        ``phi_k(s A) y = V (phi_k(s lambda) * (V^-1 y))``: :meth:`apply` uses these without forming matrices.
        """
        if self.Vinv is None:
            return None
        f = phi_scalars(np.asarray(scales, dtype=float)[:, None] * self.lam[None, :], k_max)
        return f.real if np.isrealobj(self.V) else f

    def apply(self, f: np.ndarray, Y: np.ndarray) -> np.ndarray:
        """``V (f_j * (V^-1 Y_j))`` for ``Y`` (m, n_k, r) and spectra ``f`` (n_k, m) per node j (n_k may be 1)."""
        m, nk, r = Y.shape
        inner = (self.Vinv @ Y.reshape(m, nk * r)).reshape(m, nk, r) * f.T[:, :, None]
        out = (self.V @ inner.reshape(m, nk * r)).reshape(m, nk, r)
        return out.real if np.isrealobj(Y) and np.iscomplexobj(out) else out

    def functions(self, scales: np.ndarray, k_max: int) -> np.ndarray:
        """``phi_k(s A)`` for every scale ``s``: shape (k_max + 1, len(scales), m, m)."""
        if self.Vinv is None:
            return np.stack([phi_matrices(s * self.A, k_max) for s in scales], axis=1)
        z = np.asarray(scales, dtype=float)[:, None] * self.lam[None, :]  # (S, m)
        f = phi_scalars(z, k_max)  # (K, S, m)
        if np.isrealobj(self.V):
            f = f.real
        out = (self.V * f[..., None, :]) @ self.Vinv  # batched products (BLAS), not a 3-operand einsum
        return out.real if np.isrealobj(self.A) else out


def phi_matrices(M: np.ndarray, k_max: int) -> np.ndarray:
    """``phi_0(M) .. phi_{k_max}(M)`` from one ``expm`` of the block matrix ``[[M, I, 0..], [0, 0, I..], ...]``."""
    m = M.shape[0]
    K = k_max + 1
    big = np.zeros((K * m, K * m), dtype=M.dtype)
    big[:m, :m] = M
    for k in range(1, K):
        big[(k - 1) * m:k * m, k * m:(k + 1) * m] = np.eye(m)
    E = sla.expm(big)
    return np.stack([E[:m, k * m:(k + 1) * m] for k in range(K)])

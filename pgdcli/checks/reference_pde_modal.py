"""The exact solution of a linear, time-invariant method-of-lines system, shared by every sample.

When a problem's collocation system (:class:`~pgdcli.checks.collocation_system.PdeSystem`) is
linear with coefficients and sources constant in time, each sample ``s`` of the parameters obeys

    y' = -(c_s B y + b_s),   y(t0) = y0_s

with one matrix ``B`` and a scalar ``c_s`` per sample whenever the parameters enter the operator as
one common factor (a diffusivity, a rate: ``u_t = kappa (u_xx + u_yy) + q f``). One
eigendecomposition ``B = V diag(lambda) V^-1`` then gives every sample exactly:

    y_s(t) = V [ exp(-c_s lambda dt) V^-1 y0_s - phi(c_s lambda, dt) V^-1 b_s ],
    phi(mu, dt) = (1 - exp(-mu dt)) / mu   (dt for mu = 0),   dt = t - t0,

at any times, with no time steps and no tolerance. One eigendecomposition costs about one
sample's stiff integration at a tight tolerance (BDF at 1e-12), so the reference of ``S`` samples
costs about ``1/S`` of the integrations'. The decomposition is used only when it is trustworthy:
its residual ``|B V - V Lambda|`` is at rounding level and ``cond(V)`` (which multiplies the rounding
errors of the change of basis) is below :data:`MAX_CONDITION`; otherwise, and for systems that are
not time-invariant or whose samples do not share one matrix, the caller integrates as before.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.linalg as sla

from ..blas import one_blas_thread
from .collocation import PdeModel
from .collocation_system import PdeSystem

__all__ = ["modal_states", "MAX_CONDITION", "MIN_SAMPLES", "METHOD_NAME"]

#: The largest condition number of the eigenvector matrix accepted: the values then carry relative
#: errors of about ``MAX_CONDITION * eps`` (2e-12), below the integrators' 1e-10 to 1e-12.
MAX_CONDITION = 1e4

#: The fewest samples for which one decomposition is worth it: it costs about one or two samples'
#: integrations (benchmarks/gate_cost.py).
MIN_SAMPLES = 4

#: How the reference settings name this solution.
METHOD_NAME = "eigendecomposition, exact in time"

#: Samples' matrices are taken as multiples of one when they differ from it by at most this (relative,
#: Frobenius): the rounding of the products of a few coefficients.
_PROPORTIONAL = 1e-13


def modal_states(model: PdeModel, params: Mapping[str, np.ndarray], S: int, t0: float,
                 times: np.ndarray) -> np.ndarray | None:
    """Full-grid values of ``S`` samples at ``times`` from the exact solution, or None when it does not apply.

    Parameters
    ----------
    model : PdeModel
    params : mapping of str to ndarray, each of shape (S,)
        The sampled (non-space) coordinates.
    S : int
    t0 : float
        The start of the time domain.
    times : ndarray, shape (T,)
        Sorted times, ``>= t0``.

    Returns
    -------
    ndarray, shape (S, q, T, n), or None
        The unknowns on the collocation grid (boundary values included), as the integration returns them.
    """
    if model.time is None or S < MIN_SAMPLES:
        return None
    with np.errstate(all="ignore"):
        system = PdeSystem(model, params, S, 0)
        u0 = model.initial_grid(params, S)
    if not system.constant or system.bad.any() or not np.isfinite(u0).all():
        return None
    m = model.m
    common = _common_matrix(_sample_blocks(system, S, m))
    if common is None:
        return None
    base, scales = common
    with one_blas_thread():  # as the integrations' LU factorizations (see pgdcli.blas)
        decomposition = _trusted_eig(base)
    if decomposition is None:
        return None
    lam, V, lu = decomposition
    y0 = model.interior_values(u0).reshape(S, m)
    b = np.asarray(system.b.get(None, np.zeros(S * m)), dtype=float).reshape(S, m)
    dt = np.asarray(times, dtype=float) - t0
    y = np.empty((S, dt.size, m))
    for i in range(S):
        c0 = sla.lu_solve(lu, y0[i].astype(complex))
        beta = sla.lu_solve(lu, b[i].astype(complex))
        mu = scales[i] * lam
        y[i] = ((np.exp(-np.outer(dt, mu)) * c0 - _phi(mu, dt) * beta) @ V.T).real
    if not np.isfinite(y).all():
        return None
    q, n = model.q, model.grid.n
    full = (model.Z @ y.reshape(-1, m).T).T.reshape(S, dt.size, q * n) + system.h[:, None, :]
    out = full.reshape(S, dt.size, q, n).transpose(0, 2, 1, 3)
    out[:, :, dt <= 0.0, :] = u0[:, :, None, :]  # the initial value as given, as the integration returns it
    return out


def _sample_blocks(system: PdeSystem, S: int, m: int) -> list[np.ndarray]:
    """Each sample's matrix ``B_s`` (m, m), dense, from the block-diagonal operator."""
    A = system.A.get(None)
    if A is None:
        return [np.zeros((m, m)) for _ in range(S)]
    A = A.tocsr()
    return [A[i * m:(i + 1) * m, i * m:(i + 1) * m].toarray() for i in range(S)]


def _common_matrix(blocks: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """``(B, c)`` with ``B_s = c_s B`` for every sample (``B`` the largest block), or None."""
    norms = np.array([np.linalg.norm(B) for B in blocks])
    if not np.isfinite(norms).all() or norms.max() == 0.0:
        return None
    ref = blocks[int(np.argmax(norms))]
    ref_norm2 = float(np.vdot(ref, ref))
    scales = np.array([float(np.vdot(ref, B)) / ref_norm2 for B in blocks])
    for B, c, nb in zip(blocks, scales, norms):
        if np.linalg.norm(B - c * ref) > _PROPORTIONAL * max(nb, 1e-300):
            return None
    return ref, scales


def _trusted_eig(B: np.ndarray):
    """``(eigenvalues, V, lu of V)`` when the eigendecomposition of ``B`` can be trusted, else None.

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
    if info != 0 or not rcond * MAX_CONDITION >= 1.0:
        return None
    return lam, V, (lu, piv)


def _phi(mu: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """``(1 - exp(-mu dt)) / mu`` (``dt`` where ``mu = 0``), shape (T, m)."""
    x = np.outer(dt, mu)
    safe = np.where(mu == 0, 1.0, mu)
    out = -np.expm1(-x) / safe
    return np.where(mu == 0, dt[:, None], out)

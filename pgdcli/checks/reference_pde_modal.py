"""The solution of a linear method-of-lines system with a time-invariant operator, shared by every sample.

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
costs about ``1/S`` of the integrations'. The decomposition is used only when it is trustworthy
(:mod:`.modal_basis`, which also splits the operator of a 2-D tensor grid into its two directions);
otherwise, and for systems that are not time-invariant or whose samples do not share one matrix,
the caller integrates as before.

When only the sources vary in time, the same decomposition leaves one scalar equation per mode,
solved by exponential quadrature in steps (:func:`forced_modal_states`).
"""

from __future__ import annotations

from typing import Mapping

import numpy as np
import scipy.sparse as sp
from numpy.polynomial import chebyshev as C

from ..blas import one_blas_thread
from ..problem.switches import switch_points
from .collocation import PdeModel
from .collocation_system import PdeSystem
from .modal_basis import MAX_CONDITION, decompose_samples

__all__ = ["modal_reference", "modal_states", "forced_modal_states", "steady_modal_states",
           "forcing_weights", "MAX_CONDITION", "MIN_SAMPLES", "METHOD_NAME",
           "FORCED_METHOD_NAME"]

#: The fewest samples for which one decomposition is worth it: it costs about one or two samples'
#: integrations (benchmarks/gate_cost.py).
MIN_SAMPLES = 4

#: How the reference settings name this solution.
METHOD_NAME = "eigendecomposition, exact in time"
#: ... and the one with sources that vary in time (:func:`forced_modal_states`).
FORCED_METHOD_NAME = "eigendecomposition, exponential quadrature in time (steps halved until two agree)"

#: Nodes of the sources' interpolation in time per step (Chebyshev-Lobatto: a polynomial of degree 8).
FORCING_NODES = 9
#: Steps over the time domain of the first try of :func:`forced_modal_states`, and the most it tries.
FIRST_STEPS, MAX_STEPS = 8, 512
#: ``|mu h|`` up to which the weights are integrated by Gauss-Legendre (beyond: by parts, exactly).
_GAUSS_LIMIT = 60.0



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
    decomposed = _decomposed(model, params, S, lambda system: model.time is not None and system.constant)
    return None if decomposed is None else _exact(model, t0, times, *decomposed)


def modal_reference(model: PdeModel, params: Mapping[str, np.ndarray], S: int, t0: float, times: np.ndarray,
                    rtol: float, atol: float) -> tuple[np.ndarray, str | None] | None:
    """The samples' values from their operators' shared eigenbasis, the system assembled and decomposed once:
    :func:`steady_modal_states`, :func:`modal_states` or :func:`forced_modal_states`, whichever applies, and
    the name of the method (None for a steady problem: a direct solve); None when none applies."""
    decomposed = _decomposed(model, params, S, lambda system: model.time is None or system.invariant_operator)
    if decomposed is None:
        return None
    if model.time is None:
        states, name = _steady(model, times, *decomposed), None
    elif decomposed[0].constant:
        states, name = _exact(model, t0, times, *decomposed), METHOD_NAME
    else:
        states, name = _forced(model, t0, times, rtol, atol, *decomposed), FORCED_METHOD_NAME
    return None if states is None else (states, name)


def _exact(model: PdeModel, t0: float, times: np.ndarray, system, u0, modes, lam) -> np.ndarray | None:
    """:func:`modal_states` of a decomposed system."""
    S, m = lam.shape
    c0 = modes.to_modes(model.interior_values(u0).reshape(S, m))
    beta = modes.to_modes(np.asarray(system.b.get(None, np.zeros(S * m)), dtype=float).reshape(S, m))
    dt = np.asarray(times, dtype=float) - t0
    y = np.empty((S, dt.size, m))
    for i in range(S):
        mu = lam[i]
        y[i] = modes.from_modes(np.exp(-np.outer(dt, mu)) * c0[i] - _phi(mu, dt) * beta[i]).real
    if not np.isfinite(y).all():
        return None
    q, n = model.q, model.grid.n
    full = (model.Z @ y.reshape(-1, m).T).T.reshape(S, dt.size, q * n) + system.h[:, None, :]
    out = full.reshape(S, dt.size, q, n).transpose(0, 2, 1, 3)
    out[:, :, dt <= 0.0, :] = u0[:, :, None, :]  # the initial value as given, as the integration returns it
    return out


def forced_modal_states(model: PdeModel, params: Mapping[str, np.ndarray], S: int, t0: float, times: np.ndarray,
                        rtol: float, atol: float) -> np.ndarray | None:
    """As :func:`modal_states` for a time-invariant operator whose sources vary in time, or None.

    With ``y' = -(c_s B y + b_s(t))`` and ``B = V diag(lambda) V^-1``, each mode ``z = V^-1 y`` obeys
    ``z' = -mu z - g(t)``, ``mu = c_s lambda``, ``g = V^-1 b_s``; over a step ``[a, a + h]``

        z(a + h) = exp(-mu h) z(a) - h sum_j W_j(-mu h) g(a + theta_j h),

    exact for sources polynomial of degree ``FORCING_NODES - 1`` in time over each step
    (:func:`forcing_weights`). Steps of at most ``span / N`` end at every time asked and every switch of
    time alone; ``N`` doubles from :data:`FIRST_STEPS` until two tries agree within ``atol + rtol |y|``
    (the last is returned: its error is far below that difference). None after :data:`MAX_STEPS`, when
    the differences stop falling fast (sources not smooth in time), or on a mode that grows.
    """
    decomposed = _decomposed(model, params, S, lambda system: model.time is not None and system.invariant_operator
                             and not system.constant)
    return None if decomposed is None else _forced(model, t0, times, rtol, atol, *decomposed)


def _forced(model: PdeModel, t0: float, times: np.ndarray, rtol: float, atol: float, system, u0, modes,
            mu) -> np.ndarray | None:
    """:func:`forced_modal_states` of a decomposed system (``mu``: its eigenvalues, (S, m))."""
    S, m = mu.shape
    span = float(times[-1]) - t0
    if span <= 0.0 or (-mu.real * span).max() > 50.0:  # a mode that grows: left to the integration
        return None
    z0 = modes.to_modes(model.interior_values(u0).reshape(S, m))  # (S, m)

    def modal_forcing(ts: np.ndarray) -> np.ndarray:  # the sources at the step's nodes, (S, p, m)
        return modes.to_modes(np.stack([system.forcing(t).reshape(S, m) for t in ts], axis=1))

    switches = switch_points(model.problem.equations, model.time, (t0, float(times[-1])))
    previous, change, steps = None, np.inf, FIRST_STEPS
    while True:
        with np.errstate(all="ignore"), one_blas_thread():
            y = modes.from_modes(_march_modes(z0, mu, modal_forcing, t0, times, steps, switches)).real  # (S, T, m)
        if not np.isfinite(y).all():
            return None
        if previous is not None:
            if (np.abs(y - previous) <= atol + rtol * np.abs(y)).all():
                break
            last, change = change, float(np.abs(y - previous).max())
            if steps >= 4 * FIRST_STEPS and change > last / 4:  # not smooth in time: left to the integration
                return None
        if steps >= MAX_STEPS:
            return None
        previous, steps = y, 2 * steps
    q, n = model.q, model.grid.n
    full = (model.Z @ y.reshape(-1, m).T).T.reshape(S, times.size, q * n) + system.h[:, None, :]
    out = full.reshape(S, times.size, q, n).transpose(0, 2, 1, 3)
    out[:, :, times <= t0, :] = u0[:, :, None, :]
    return out


def steady_modal_states(model: PdeModel, params: Mapping[str, np.ndarray], S: int,
                        times: np.ndarray) -> np.ndarray | None:
    """The steady system ``A_s y + b_s = 0`` of ``S`` samples solved in their operators' shared eigenbasis (one
    division per mode), shaped as :func:`modal_states` over ``times``; None without a shared basis or with an
    eigenvalue near zero (the sparse LU then says whether the system is singular)."""
    decomposed = _decomposed(model, params, S, lambda system: model.time is None)
    return None if decomposed is None else _steady(model, times, *decomposed)


def _steady(model: PdeModel, times: np.ndarray, system, u0, modes, lam) -> np.ndarray | None:
    """:func:`steady_modal_states` of a decomposed system."""
    S = lam.shape[0]
    size = np.abs(lam)
    if not (size.min(axis=1) > 1e-12 * size.max(axis=1)).all():
        return None
    m, q, n = model.m, model.q, model.grid.n
    b = np.asarray(sum(system.b.values()) if system.b else np.zeros(S * m), dtype=float).reshape(S, m)
    y = -modes.from_modes(modes.to_modes(b) / lam).real
    if not np.isfinite(y).all():
        return None
    full = (model.Z @ y.T).T + system.h  # (S, q n)
    return np.broadcast_to(full.reshape(S, q, 1, n), (S, q, times.size, n)).copy()


def _decomposed(model: PdeModel, params, S: int, applies):
    """``(system, u0, modes, eigenvalues (S, m))`` of samples whose system ``applies`` and whose operators
    share a trusted eigenbasis (:func:`pgdcli.checks.modal_basis.decompose_samples`), else None (``u0``:
    None for a steady problem)."""
    if S < MIN_SAMPLES:
        return None
    with np.errstate(all="ignore"):
        system = PdeSystem(model, params, S, 0)
        u0 = None if model.time is None else model.initial_grid(params, S)
    if not applies(system) or system.bad.any() or (u0 is not None and not np.isfinite(u0).all()):
        return None
    with one_blas_thread():  # as the integrations' LU factorizations (see pgdcli.blas)
        decomposed = decompose_samples(model, _sample_blocks(system, S, model.m))
    return None if decomposed is None else (system, u0, *decomposed)


def _march_modes(z0: np.ndarray, mu: np.ndarray, forcing, t0: float, times: np.ndarray, steps: int,
                 switches: list[float]) -> np.ndarray:
    """The modes ``(S, m)`` at ``times`` (S, T, m), in steps of at most ``(times[-1] - t0) / steps`` that end at
    every time asked and every switch of time alone (sources evaluated a few units in the last place inside
    each step: on one side of a switch)."""
    theta = _lobatto(FORCING_NODES)
    grid = np.union1d(np.linspace(t0, float(times[-1]), steps + 1), np.r_[times[times > t0], switches])
    out = np.empty((z0.shape[0], times.size, z0.shape[1]), dtype=complex)
    out[:, times <= t0] = z0[:, None, :]
    z, weights = z0, {}
    for a, b in zip(grid[:-1], grid[1:]):
        h = b - a
        key = f"{h:.13e}"
        if key not in weights:
            weights[key] = (np.exp(-mu * h), forcing_weights(-mu * h))  # (S, m), (S, m, p)
        decay, W = weights[key]
        at = np.clip(a + theta * h, a + 8 * np.spacing(b), b - 8 * np.spacing(b))
        g = forcing(at)  # (S, p, m)
        z = decay * z - h * np.einsum("smp,spm->sm", W, g)
        out[:, times == b] = z[:, None, :]
    return out


def _lobatto(p: int) -> np.ndarray:
    """Chebyshev-Lobatto points on [0, 1], increasing."""
    return 0.5 * (1.0 - np.cos(np.pi * np.arange(p) / (p - 1)))


def _lagrange_chebyshev(p: int) -> np.ndarray:
    """Chebyshev coefficients (in ``2 theta - 1``) of the Lagrange basis at :func:`_lobatto` points: (p, p)."""
    return np.linalg.inv(C.chebvander(2.0 * _lobatto(p) - 1.0, p - 1))  # column j: the coefficients of l_j


def forcing_weights(zeta: np.ndarray, p: int = FORCING_NODES) -> np.ndarray:
    """``W_j(zeta) = int_0^1 exp(zeta (1 - theta)) l_j(theta) d theta`` for the Lagrange basis ``l_j`` at
    ``p`` Chebyshev-Lobatto points: shape ``zeta.shape + (p,)``.

    Gauss-Legendre (64 points: exact to rounding for ``|zeta| <= 60``) where ``|zeta|`` is small; beyond,
    integration by parts, exact for a polynomial,
    ``W_j = sum_r (exp(zeta) l_j^(r)(0) - l_j^(r)(1)) / zeta^(r + 1)``, whose terms then fall.
    """
    coef = _lagrange_chebyshev(p)
    zeta = np.asarray(zeta, dtype=complex)
    flat = zeta.reshape(-1)
    out = np.empty((flat.size, p), dtype=complex)
    small = np.abs(flat) <= _GAUSS_LIMIT
    if small.any():
        x, w = np.polynomial.legendre.leggauss(64)
        theta = 0.5 * (x + 1.0)
        basis = C.chebval(2.0 * theta - 1.0, coef).T  # (Q, p): l_j(theta_q)
        out[small] = (0.5 * w * np.exp(np.outer(flat[small], 1.0 - theta))) @ basis
    if (~small).any():
        ends = np.empty((2, p, p))  # [end, r, j]: l_j^(r) at theta = 0 and 1
        for r in range(p):
            d = C.chebder(coef, r, scl=2.0) if r else coef
            ends[:, r] = C.chebval(np.array([-1.0, 1.0]), d).T
        big = flat[~small]
        inverse_powers = big[:, None] ** -np.arange(1, p + 1)  # (N, r)
        out[~small] = np.exp(big)[:, None] * (inverse_powers @ ends[0]) - inverse_powers @ ends[1]
    return out.reshape(zeta.shape + (p,))


def _sample_blocks(system: PdeSystem, S: int, m: int) -> list:
    """Each sample's matrix ``B_s`` (m, m), sparse (CSR), from the block-diagonal operator."""
    A = system.matrix(0.0).tocsr()  # a time-invariant operator: the same at every time
    return [A[i * m:(i + 1) * m, i * m:(i + 1) * m] for i in range(S)]


def _phi(mu: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """``(1 - exp(-mu dt)) / mu`` (``dt`` where ``mu = 0``), shape (T, m)."""
    x = np.outer(dt, mu)
    safe = np.where(mu == 0, 1.0, mu)
    out = -np.expm1(-x) / safe
    return np.where(mu == 0, dt[:, None], out)

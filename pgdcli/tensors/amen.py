"""AMEn: alternating minimal energy for symmetric positive definite systems in tensor-train form.

Dolgov & Savostyanov, "Alternating minimal energy methods for linear systems in higher
dimensions" (SIAM J. Sci. Comput. 36, 2014); the structure of one sweep follows the reference
implementations (ttpy's ``amen_solve``, the TT-Toolbox's ``amen_solve2``):

1. right to left: the cores of ``x`` (and of ``z``, a rank-``kickrank`` train that tracks the
   residual) are right-orthogonalized and the right interfaces built;
2. left to right, at every core ``k``: the local system ``B_k y = g_k`` (the system projected on
   the other cores, :mod:`pgdcli.tensors.amen_local`) is solved for the core; the core is
   truncated to the smallest rank whose dropped part has *energy* ``||y - y_r||_B`` within the
   bound (for the normal equations ``A^T A x = A^T f``, that is exactly how much the truncation
   can raise the residual ``||A x - f||``); then it is enriched with the residual's projection on
   ``z``'s right interface, which is what lets the ranks grow where the residual needs them (plain
   one-site ALS cannot), and the left interfaces move on.

After every sweep the true residual is measured (``residual``, a callback: the caller's own
norm; by default ``||B x - g|| / ||g||`` in tensor-train arithmetic, never estimated from
Gram products) and the iterate with the smallest one is kept. The solve stops when it meets
``tolerance`` or when it cannot: a rank would pass ``max_rank``, the residual stopped falling
(less than halved over :data:`STALL_SWEEPS` sweeps), ``max_sweeps`` sweeps, or ``callback``
asked it to (a predicted cost too high).

numpy and scipy.linalg only.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Callable

import numpy as np

from .amen_local import (LocalSolve, left_interface, left_vector_interface, local_apply, local_rhs,
                         right_interface, right_vector_interface, solve_local)
from .tt import TT, tt_sum
from .tt_matrix import TTMatrix

__all__ = ["AmenResult", "amen_solve", "STALL_SWEEPS"]

#: A residual that is not halved over this many sweeps has stopped falling.
STALL_SWEEPS = 3
#: What a local solve may leave of its gain, as a share of the energy a truncation may drop.
LOCAL_SHARE = 0.1
#: While the residual is above the tolerance, what a sweep's truncations may drop is this share of the
#: energy allowed at the tolerance times the residual over the tolerance.
LOOSE_SHARE = 0.1
#: Most conjugate-gradient steps of one local solve.
LOCAL_ITERATIONS = 200


@dataclass
class AmenResult:
    """The outcome of :func:`amen_solve`.

    Attributes
    ----------
    solution : TT
        The iterate with the smallest measured residual.
    status : str
        ``'converged'``, ``'rank cap'``, ``'stalled'``, ``'sweeps'`` or ``'stopped'`` (by the callback).
    message : str
    residuals : list of float
        The measured residual after each sweep.
    ranks : list of tuple of int
        The ranks after each sweep.
    times : list of float
        Seconds from the start to the end of each sweep.
    dense_solves, iterations : int
        Local systems solved densely; conjugate-gradient iterations of the others.
    short_solves : int
        Local solves stopped by the cap on conjugate-gradient steps with more to gain.
    """

    solution: TT
    status: str
    message: str
    residuals: list = field(default_factory=list)
    ranks: list = field(default_factory=list)
    times: list = field(default_factory=list)
    dense_solves: int = 0
    iterations: int = 0
    short_solves: int = 0

    @property
    def converged(self) -> bool:
        return self.status == "converged"

    @property
    def residual(self) -> float:
        return min(self.residuals) if self.residuals else float("inf")


def _random_train(shape, rank: int, rng: np.random.Generator) -> list[np.ndarray]:
    ranks = [1] + [rank] * (len(shape) - 1) + [1]
    return [rng.standard_normal((ranks[k], n, ranks[k + 1])) for k, n in enumerate(shape)]


def _orthogonalize_core_right(cores: list[np.ndarray], k: int) -> None:
    """Core ``k`` right-orthogonal (LQ), its factor pushed into core ``k - 1``."""
    r0, n, r1 = cores[k].shape
    q, r = np.linalg.qr(cores[k].reshape(r0, n * r1).T)
    cores[k] = q.T.reshape(q.shape[1], n, r1)
    cores[k - 1] = np.tensordot(cores[k - 1], r.T, axes=(2, 0))


def _orthogonalize_core_left(cores: list[np.ndarray], k: int) -> None:
    """Core ``k`` left-orthogonal (QR), its factor pushed into core ``k + 1``."""
    r0, n, r1 = cores[k].shape
    q, r = np.linalg.qr(cores[k].reshape(r0 * n, r1))
    cores[k] = q.reshape(r0, n, q.shape[1])
    cores[k + 1] = np.tensordot(r, cores[k + 1], axes=(1, 0))


def _energy(left, core, right, delta: np.ndarray) -> float:
    """``sqrt(<delta, B_k delta>)``."""
    return float(np.sqrt(max(np.vdot(delta, local_apply(left, core, right, delta)), 0.0)))


def _truncated_rank(u, s, vt, shape, left, core, right, bound: float) -> int:
    """Smallest rank whose dropped part of ``u diag(s) vt`` has energy within ``bound`` (bisection)."""
    def energy(rank: int) -> float:
        if rank >= s.size:
            return 0.0
        delta = (u[:, rank:] * s[rank:]) @ vt[rank:]
        return _energy(left, core, right, delta.reshape(shape))

    low, high = 1, s.size  # energy(high) == 0 <= bound
    if low >= high or energy(low) <= bound:
        return low
    while high - low > 1:
        mid = (low + high) // 2
        if energy(mid) <= bound:
            high = mid
        else:
            low = mid
    return high


class _Sweeps:
    """The state of the iteration: cores of ``x`` and ``z``, their interfaces, counters."""

    def __init__(self, matrix: TTMatrix, rhs: TT, x0: TT | None, kickrank: int, rng: np.random.Generator):
        self.a = list(matrix.cores)
        self.g = list(rhs.cores)
        self.d = d = matrix.order
        shape = matrix.column_shape
        self.x = list(x0.cores) if x0 is not None else _random_train(shape, 2, rng)
        self.kick = kickrank if d > 1 else 0
        self.z = _random_train(shape, self.kick, rng) if self.kick else None
        one, one2 = np.ones((1, 1, 1)), np.ones((1, 1))
        self.phi = [one] + [None] * (d - 1) + [one]  # x^T B x
        self.psi = [one2] + [None] * (d - 1) + [one2]  # x^T g
        self.phiz = [one] + [None] * (d - 1) + [one]  # z^T B x
        self.psiz = [one2] + [None] * (d - 1) + [one2]  # z^T g
        self.dense = self.iterations = self.short = 0
        self.capped = False

    def local_residual(self, k: int, left, right, lvec, rvec, core) -> np.ndarray:
        return local_apply(left, self.a[k], right, core) - local_rhs(lvec, self.g[k], rvec)

    def right_to_left(self, first: bool) -> None:
        for k in range(self.d - 1, 0, -1):
            if self.kick and not first:  # z follows the residual's projection on its own interfaces
                self.z[k] = self.local_residual(k, self.phiz[k], self.phiz[k + 1], self.psiz[k], self.psiz[k + 1],
                                                self.x[k])
            _orthogonalize_core_right(self.x, k)
            self.phi[k] = right_interface(self.phi[k + 1], self.a[k], self.x[k], self.x[k])
            self.psi[k] = right_vector_interface(self.psi[k + 1], self.g[k], self.x[k])
            if self.kick:
                _orthogonalize_core_right(self.z, k)
                self.phiz[k] = right_interface(self.phiz[k + 1], self.a[k], self.z[k], self.x[k])
                self.psiz[k] = right_vector_interface(self.psiz[k + 1], self.g[k], self.z[k])

    def left_to_right(self, local_energy: float, bound: float, max_rank: int) -> None:
        self.capped = False
        for k in range(self.d):
            self.solve_core(k, local_energy, LOCAL_ITERATIONS)
            if k == self.d - 1:
                return
            old = self.truncate(k, bound, max_rank)
            if self.kick:
                self.enrich(k, old)
            else:
                _orthogonalize_core_left(self.x, k)
            self.phi[k + 1] = left_interface(self.phi[k], self.a[k], self.x[k], self.x[k])
            self.psi[k + 1] = left_vector_interface(self.psi[k], self.g[k], self.x[k])

    def solve_core(self, k: int, energy: float, max_iterations: int) -> None:
        left, right = self.phi[k], self.phi[k + 1]
        rhs = local_rhs(self.psi[k], self.g[k], self.psi[k + 1])
        res = local_apply(left, self.a[k], right, self.x[k]) - rhs
        correction, how = solve_local(left, self.a[k], right, res, energy, max_iterations)
        self._count(how, energy, max_iterations)
        self.x[k] = self.x[k] - correction

    def _count(self, how: LocalSolve, energy: float, max_iterations: int) -> None:
        if how.dense:
            self.dense += 1
        self.iterations += how.iterations
        if how.iterations >= max_iterations and how.last_gain > 0.1 * energy * energy:
            self.short += 1

    def truncate(self, k: int, bound: float, max_rank: int) -> np.ndarray:
        """Core ``k`` cut to the rank the energy bound allows; returns it in the old right basis."""
        r0, n, r1 = self.x[k].shape
        u, s, vt = np.linalg.svd(self.x[k].reshape(r0 * n, r1), full_matrices=False)
        rank = _truncated_rank(u, s, vt, (r0, n, r1), self.phi[k], self.a[k], self.phi[k + 1], bound)
        if rank > max_rank:
            rank, self.capped = max_rank, True
        self.x[k] = u[:, :rank].reshape(r0, n, rank)
        self.x[k + 1] = np.tensordot(s[:rank, None] * vt[:rank], self.x[k + 1], axes=(1, 0))
        return ((u[:, :rank] * s[:rank]) @ vt[:rank]).reshape(r0, n, r1)

    def enrich(self, k: int, old: np.ndarray) -> None:
        """Core ``k`` widened by the residual's projection on ``z``'s right interface, then orthogonalized."""
        kick = self.local_residual(k, self.phi[k], self.phiz[k + 1], self.psi[k], self.psiz[k + 1], old)
        self.z[k] = self.local_residual(k, self.phiz[k], self.phiz[k + 1], self.psiz[k], self.psiz[k + 1], old)
        nxt = self.x[k + 1]
        self.x[k] = np.concatenate([self.x[k], kick], axis=2)
        self.x[k + 1] = np.concatenate([nxt, np.zeros((kick.shape[2],) + nxt.shape[1:])], axis=0)
        _orthogonalize_core_left(self.x, k)
        _orthogonalize_core_left(self.z, k)
        self.phiz[k + 1] = left_interface(self.phiz[k], self.a[k], self.z[k], self.x[k])
        self.psiz[k + 1] = left_vector_interface(self.psiz[k], self.g[k], self.z[k])


def amen_solve(matrix: TTMatrix, rhs: TT, tolerance: float, *, x0: TT | None = None,
               residual: Callable[[TT], float] | None = None, energy: float | None = None,
               max_rank: int = 400, max_sweeps: int = 40, kickrank: int = 6,
               callback: Callable[[dict], str | None] | None = None, seed: int = 0) -> AmenResult:
    """Solve ``B x = g`` (``B`` symmetric positive definite) in tensor-train form by AMEn.

    Parameters
    ----------
    matrix : TTMatrix
        ``B``, symmetric positive definite, square in every mode.
    rhs : TT
        ``g``.
    tolerance : float
        Stop when ``residual(x) <= tolerance``.
    x0 : TT, optional
        A first iterate (a previous solution); default a random train of rank 2.
    residual : callable, optional
        ``residual(x) -> float``, measured after every sweep; default ``||B x - g|| / ||g||``.
    energy : float, optional
        What the truncations may drop in energy, ``||y - y_r||_B``, over all the bonds
        (``energy / sqrt(d - 1)`` a bond); the local solves stop when what they could still
        gain is :data:`LOCAL_SHARE` of that. For the normal equations of ``A x = f``, the energy
        of a change is the change of ``||A x - f||``. Default ``tolerance * ||g|| / 2``.
    max_rank : int
        The largest rank a truncation may keep; a core that needs more ends the solve
        (``'rank cap'``) unless the residual met the tolerance in that sweep.
    max_sweeps, kickrank : int
    callback : callable, optional
        Called after each sweep with ``{"sweep", "residual", "ranks", "seconds"}``; a string
        returned stops the solve (``'stopped'``, the string as the message).
    seed : int
        Seeds the random first iterate and ``z``: the same system gives the same solution.

    Returns
    -------
    AmenResult
    """
    started = time.perf_counter()
    d = matrix.order
    if matrix.column_shape != tuple(rhs.shape) or matrix.row_shape != tuple(rhs.shape):
        raise ValueError(f"the operator's modes {matrix.row_shape} x {matrix.column_shape} do not match the "
                         f"right-hand side's {rhs.shape}")
    rhs_norm = rhs.norm()
    if rhs_norm == 0.0:
        return AmenResult(TT([np.zeros((1, n, 1)) for n in rhs.shape]), "converged", "the right-hand side is zero",
                          [0.0], [(1,) * (d - 1)], [0.0])
    if residual is None:
        def residual(x: TT) -> float:
            return tt_sum([matrix.matvec(x), rhs], [1.0, -1.0]).norm() / rhs_norm
    bonds = np.sqrt(max(d - 1, 1))
    energy = tolerance * rhs_norm / 2.0 if energy is None else float(energy)
    state = _Sweeps(matrix, rhs, x0, kickrank, np.random.default_rng(seed))
    result = AmenResult(TT(state.x), "sweeps", "")
    best = float("inf")
    for sweep in range(1, max_sweeps + 1):
        state.right_to_left(first=sweep == 1)
        # while the residual is far above the tolerance the truncations may drop more (lower ranks,
        # cheaper sweeps), as the reference codes truncate relative to the residual
        drop = max(energy, LOOSE_SHARE * energy / tolerance * result.residuals[-1]) if result.residuals else energy
        state.left_to_right(LOCAL_SHARE * drop / bonds, drop / bonds, max_rank)
        x = TT(state.x)
        res = float(residual(x))
        result.residuals.append(res)
        result.ranks.append(x.ranks)
        result.times.append(time.perf_counter() - started)
        result.dense_solves, result.iterations, result.short_solves = state.dense, state.iterations, state.short
        if res < best:
            best, result.solution = res, x
        stop = _stop_reason(result, tolerance, state.capped, max_rank)
        asked = callback({"sweep": sweep, "residual": res, "ranks": x.ranks, "seconds": result.times[-1]}) \
            if callback is not None else None
        if stop is None and asked:
            stop = ("stopped", asked)
        if stop is not None:
            result.status, result.message = stop
            return result
    result.message = f"residual {best:.3g} > {tolerance:.3g} after {max_sweeps} sweeps"
    return result


def _stop_reason(result: AmenResult, tolerance: float, capped: bool, max_rank: int) -> tuple[str, str] | None:
    res = result.residuals[-1]
    sweeps = len(result.residuals)
    if res <= tolerance:
        return "converged", f"residual {res:.3g} in {sweeps} sweeps, ranks {result.ranks[-1]}"
    if capped:
        return "rank cap", f"a rank reached max_rank = {max_rank} with residual {res:.3g} > {tolerance:.3g}"
    if sweeps > STALL_SWEEPS and res > 0.5 * result.residuals[-1 - STALL_SWEEPS]:
        return "stalled", (f"the residual stopped falling at {min(result.residuals):.3g} > {tolerance:.3g} "
                           f"({sweeps} sweeps, ranks {result.ranks[-1]})")
    return None

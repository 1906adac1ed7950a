"""Sums of Hadamard products of tensor trains by one-site cross interpolation, at O(n r^3) per core.

``F = sum_m w_m A_m * B_m`` (elementwise) is approximated in tensor-train form from its
values at nested fibres (the TT-cross of Oseledets & Tyrtyshnikov 2010, one core at a
time, with maximum-volume index sets, :func:`pgdcli.tensors.cross.maxvol`). The values of
``F`` at the fibre ``(I_k, i_k, J_{k+1})`` never need the product's r^2 ranks: each factor
``X`` contributes ``L_X[I_k] X_k[:, i_k, :] R_X[J_{k+1}]``, its partial products of cores at
the index sets (its interfaces), ``rho x r`` matrices. One core then costs about
``n r^2 rho + n r rho^2`` per factor, against ``n r^2 s (r + s)`` for the randomized
sketch of the rounding (:mod:`pgdcli.tensors.tt_sketch`): r^3 instead of r^4.

Rank adaptivity: each fibre block is truncated by SVD (ranks shrink to what the tolerance
needs) and the index sets get a few random extra rows before every half-sweep (ranks
grow). The result is trusted only when measured, never assumed: at random entries of the
grid (independent of the fibres) the root-mean-square difference from ``F``, evaluated
exactly from the factors, meets the tolerance, and every bond was truncated below the size
of its index set (the sets were large enough). Otherwise the cross sweeps again with
larger sets; after ``max_sweeps`` it reports failure and the caller falls back.

The index sets of one call warm-start the next (the march's stages change the state
little): usually one half-sweep suffices.

This module imports numpy and :mod:`pgdcli.tensors` only.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .cross import maxvol, tt_values_at
from .tt import TT, is_ones, tt_round
from .tt_svd import truncation_rank

__all__ = ["ProductCross", "CrossOfProducts", "round_products_by_cross"]

#: Random entries at which every half-sweep's train is compared with the exact sum of products.
SAMPLES = 384
#: Share of the RMS tolerance for the truncation of each fibre block.
BLOCK_SHARE = 0.25


@dataclass
class CrossOfProducts:
    """What one :meth:`ProductCross.__call__` produced."""

    train: TT | None  # None: not converged (caller falls back)
    sweeps: int
    sample_rms: float
    evaluations: int = 0
    message: str = ""
    ranks: tuple = field(default_factory=tuple)


def _left_interface(x: TT, rows: np.ndarray, k: int) -> np.ndarray:
    """``L[p, :] = prod_{m<k} X_m[:, rows[p, m], :]``, shape (P, r_k)."""
    v = np.ones((rows.shape[0], 1))
    for m in range(k):
        v = np.einsum("pa,apb->pb", v, x.cores[m][:, rows[:, m], :])
    return v


def _right_interface(x: TT, rows: np.ndarray, k: int) -> np.ndarray:
    """``R[:, p] = prod_{m>=k} X_m[:, rows[p, m - k], :]``, shape (r_k, P) (r_k: left rank of core k)."""
    d = x.order
    v = np.ones((1, rows.shape[0]))
    for m in range(d - 1, k - 1, -1):
        v = np.einsum("apb,bp->ap", x.cores[m][:, rows[:, m - k], :], v)
    return v


def _truncated_basis(block: np.ndarray, threshold: float) -> np.ndarray:
    """Orthonormal columns spanning ``block`` up to a discarded tail of norm <= threshold."""
    u, s, _ = np.linalg.svd(block, full_matrices=False)
    return u[:, :truncation_rank(s, threshold)]


class ProductCross:
    """A warm-started cross of ``sum_m w_m A_m * B_m`` on one grid (one slot of a right-hand side).

    Parameters
    ----------
    shape : tuple of int
    rng : numpy Generator
        For the random extra rows of the index sets and the random check entries.
    kick : int
        Random rows added to every index set before a half-sweep.
    max_sweeps : int
    """

    def __init__(self, shape, rng: np.random.Generator, kick: int = 4, max_sweeps: int = 6):
        self.shape = tuple(int(n) for n in shape)
        self.d = len(self.shape)
        self.rng, self.kick, self.max_sweeps = rng, kick, max_sweeps
        self.right: list | None = None  # J_k, k = 1..d-1: (rho_k, d - k) multi-indices

    def _random_rows(self, count: int, first: int, last: int) -> np.ndarray:
        return np.stack([self.rng.integers(0, n, size=count) for n in self.shape[first:last]], axis=1)

    def _kicked(self, sets: list, left: bool, max_rank: int, grow: float = 0.0) -> list:
        """Every set with ``kick`` (plus ``grow`` x its size) random rows more (distinct, at most ``max_rank``)."""
        out = list(sets)
        for k in range(1, self.d):
            count = self.kick + int(grow * sets[k].shape[0])
            extra = self._random_rows(count, 0, k) if left else self._random_rows(count, k, self.d)
            rows = np.unique(np.concatenate([sets[k], extra]), axis=0)
            out[k] = rows[:max_rank] if rows.shape[0] > max_rank else rows
        return out

    def __call__(self, terms, rms_tolerance: float, max_rank: int, rank_hint: int = 4) -> CrossOfProducts:
        """The cross of ``sum w A * B`` to root-mean-square ``rms_tolerance`` over the grid.

        Parameters
        ----------
        terms : list of (float, TT, TT)
            ``B`` may be :func:`pgdcli.tensors.tt.tt_ones`.
        rms_tolerance : float
        max_rank : int
        rank_hint : int
            Size of the first random index sets (no warm start yet).
        """
        d, shape = self.d, self.shape
        terms = [(float(w), a, None if is_ones(b) else b) for w, a, b in terms if w != 0.0]
        factors = {id(x): x for _, a, b in terms for x in (a, b) if x is not None}
        samples = np.stack([self.rng.integers(0, n, size=SAMPLES) for n in shape], axis=1)
        exact = self._values(terms, {key: tt_values_at(x, samples) for key, x in factors.items()})
        if self.right is None:
            self.right = [None] + [self._random_rows(max(rank_hint, 2), k, d) for k in range(1, d)]
        right = self._kicked(self.right, False, max_rank)
        left = None
        grow = 0.0
        threshold = BLOCK_SHARE * rms_tolerance
        rms = np.inf
        evaluations = 0
        for sweep in range(1, self.max_sweeps + 1):
            if sweep % 2 == 1:  # left to right on the (kicked) right sets: new left sets
                cores, left, saturated, n_values = self._sweep_right(terms, factors, right, threshold)
            else:  # right to left on the kicked left sets: new right sets, kept for the next call
                cores, new_right, saturated, n_values = self._sweep_left(
                    terms, factors, self._kicked(left, True, max_rank, grow), threshold)
                self.right = new_right
                right = self._kicked(new_right, False, max_rank, grow)
            evaluations += n_values
            train = TT(cores)
            rms = float(np.sqrt(np.mean((tt_values_at(train, samples) - exact) ** 2)))
            if not np.isfinite(rms):
                return CrossOfProducts(None, sweep, rms, evaluations, "not finite")
            if rms <= rms_tolerance and not saturated:
                return CrossOfProducts(train, sweep, rms, evaluations, "converged", train.ranks)
            # the sets bound the ranks, or two half-sweeps left the sampled error above the target: enlarge them
            grow = 0.5 if saturated or sweep >= 2 else 0.0
        return CrossOfProducts(None, self.max_sweeps, rms, evaluations,
                               f"sample RMS {rms:.3g} above {rms_tolerance:.3g} after {self.max_sweeps} half-sweeps")

    @staticmethod
    def _values(terms, values: dict) -> np.ndarray:
        """``sum w A * B`` from each factor's values (keyed by id)."""
        total = 0.0
        for w, a, b in terms:
            v = values[id(a)] if b is None else values[id(a)] * values[id(b)]
            total = total + w * v
        return total

    def _block_threshold(self, threshold: float, size: int) -> float:
        # an RMS tolerance per sampled entry, shared by the d - 1 truncated bonds
        return threshold * np.sqrt(size / max(self.d - 1, 1))

    def _sweep_right(self, terms, factors: dict, right: list, threshold: float):
        """Left to right: cores k = 0..d-2 interpolating, the last the values; new left sets."""
        d, shape = self.d, self.shape
        rights = {key: [None] + [_right_interface(x, right[k], k) for k in range(1, d)] for key, x in factors.items()}
        lefts = {key: np.ones((1, 1)) for key in factors}
        rows_left = np.zeros((1, 0), dtype=int)
        sets = [rows_left] + [None] * (d - 1)
        cores, saturated, evaluations = [], False, 0
        for k in range(d):
            n = shape[k]
            fibres = {}
            for key, x in factors.items():
                r0, _, r1 = x.cores[k].shape
                v = (lefts[key] @ x.cores[k].reshape(r0, n * r1)).reshape(-1, r1)
                fibres[key] = v @ rights[key][k + 1] if k < d - 1 else v
            block = self._values(terms, fibres)  # (rho_L n, rho_R)
            evaluations += block.size
            if not np.all(np.isfinite(block)):
                return [np.full((1, m, 1), np.nan) for m in shape], sets, True, evaluations
            rho = rows_left.shape[0]
            if k == d - 1:
                cores.append(block.reshape(rho, n, 1))
                break
            q = _truncated_basis(block, self._block_threshold(threshold, block.size))
            # the right set was too small to show where the ranks stop (unless it holds every index there)
            saturated |= q.shape[1] >= block.shape[1] and block.shape[1] < min(rho * n, np.prod(shape[k + 1:]))
            rows = maxvol(q)
            cores.append(np.linalg.solve(q[rows].T, q.T).T.reshape(rho, n, -1))
            a, i = np.divmod(rows, n)
            for key, x in factors.items():
                lefts[key] = np.einsum("pa,apb->pb", lefts[key][a], x.cores[k][:, i, :])
            rows_left = np.concatenate([rows_left[a], i.reshape(-1, 1)], axis=1)
            sets[k + 1] = rows_left
        return cores, sets, saturated, evaluations

    def _sweep_left(self, terms, factors: dict, left: list, threshold: float):
        """Right to left: cores k = d-1..1 interpolating, the first the values; new right sets."""
        d, shape = self.d, self.shape
        lefts = {key: [np.ones((1, 1))] + [_left_interface(x, left[k], k) for k in range(1, d)]
                 for key, x in factors.items()}
        rights = {key: np.ones((1, 1)) for key in factors}
        rows_right = np.zeros((1, 0), dtype=int)
        sets = [None] * d + [rows_right]
        cores, saturated, evaluations = [None] * d, False, 0
        for k in range(d - 1, -1, -1):
            n = shape[k]
            fibres = {}
            for key, x in factors.items():
                r0, _, r1 = x.cores[k].shape
                v = (x.cores[k].reshape(r0 * n, r1) @ rights[key]).reshape(r0, -1)  # (r0, n rho_R)
                fibres[key] = lefts[key][k] @ v
            block = self._values(terms, fibres)  # (rho_L, n rho_R)
            evaluations += block.size
            if not np.all(np.isfinite(block)):
                return [np.full((1, m, 1), np.nan) for m in shape], sets, True, evaluations
            rho = rows_right.shape[0]
            if k == 0:
                cores[0] = block.reshape(1, n, rho)
                break
            q = _truncated_basis(block.T, self._block_threshold(threshold, block.size))  # (n rho_R, rank)
            saturated |= q.shape[1] >= block.shape[0] and block.shape[0] < min(n * rho, np.prod(shape[:k]))
            cols = maxvol(q)
            cores[k] = np.linalg.solve(q[cols].T, q.T).reshape(-1, n, rho)
            i, b = np.divmod(cols, rho)
            for key, x in factors.items():
                rights[key] = np.einsum("apb,bp->ap", x.cores[k][:, i, :], rights[key][:, b])
            rows_right = np.concatenate([i.reshape(-1, 1), rows_right[b]], axis=1)
            sets[k] = rows_right
        return cores, sets, saturated, evaluations


def round_products_by_cross(cross: ProductCross, terms, *, absolute: float, max_rank: int,
                            rank_hint: int = 4) -> tuple[TT | None, CrossOfProducts]:
    """``sum w A * B`` within Frobenius ``absolute``: half to the cross (as an RMS), half to a final
    rounding. Returns (None, info) when the cross did not converge."""
    size = float(np.prod(cross.shape))
    info = cross(terms, 0.5 * absolute / np.sqrt(size), max_rank, rank_hint)
    if info.train is None:
        return None, info
    return tt_round(info.train, absolute=0.5 * absolute, max_rank=max_rank), info

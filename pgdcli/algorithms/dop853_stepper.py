"""The stages of the embedded Runge-Kutta pair DOP853 on a tensor-train state.

Every stage value ``y + h sum_j a_sj K_j`` is a sum of trains rounded once to an absolute
Frobenius bound, and every right-hand side ``K_s = f(t + c_s h, stage)`` is evaluated in
separated form (:func:`pgdcli.algorithms.polynomial_rhs.evaluate_rhs`). The coefficients are
those of :class:`scipy.integrate.DOP853` (Dormand-Prince 8(5,3)), its embedded estimate the
same formula; the dense output is scipy's nested polynomial applied to coefficient vectors,
so the state at a node inside a step is one more rounded combination of trains.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import DOP853

from ..tensors.tt import TT, tt_ones, tt_sum
from .polynomial_rhs import NonlinearSystem, evaluate_rhs, round_terms

__all__ = ["Dop853OnTrains", "TrialStep", "dense_weights", "frobenius_of_sums"]


@dataclass
class TrialStep:
    """One trial step: the new state, its right-hand side, all stages and the error estimate."""

    state: list | None  # list of TT, per unknown
    rhs: list | None  # f(t + h, state), the first stage of the next step
    stages: list  # K_0 .. K_12 (and K_13 = rhs), each a list of TT per unknown
    error: float  # Frobenius norm of the embedded estimate (inf after an overflow)
    norm: float  # largest Frobenius norm of the new state's unknowns


def frobenius_of_sums(terms: list[TT], weight_vectors: list) -> list[float]:
    """``|| sum_j w_j X_j ||_F`` for each weight vector ``w``, from one right-orthogonalization.

    The sums differ only in how their first cores weight the terms' blocks, so the later cores
    (block-diagonal) are orthogonalized once, as :meth:`TT.norm` would for each sum (accurate to
    rounding, no Gram cancellation: the embedded error estimates are differences of nearly equal
    stages). Terms whose weight is zero in every vector are left out.
    """
    keep = [j for j in range(len(terms)) if any(w[j] != 0.0 for w in weight_vectors)]
    if not keep:
        return [0.0] * len(weight_vectors)
    terms = [terms[j] for j in keep]
    weight_vectors = [np.asarray(w, dtype=float)[keep] for w in weight_vectors]
    if terms[0].order == 1:
        return [float(np.linalg.norm(sum(c * t.cores[0] for c, t in zip(w, terms)))) for w in weight_vectors]
    cores = list(tt_sum(terms).cores)
    # right-orthogonalize cores d-1..1: only the R factor carried to the left matters for the norm
    for k in range(len(cores) - 1, 0, -1):
        r0, n, r1 = cores[k].shape
        carried = np.linalg.qr(cores[k].reshape(r0, n * r1).T, mode="r").T  # (r0, r0')
        if k > 1:
            cores[k - 1] = np.tensordot(cores[k - 1], carried, axes=(2, 0))
    first = cores[0][0]  # (n, sum of the first bonds): the terms' first cores side by side, unweighted
    blocks = [t.cores[0].shape[2] for t in terms]
    return [float(np.linalg.norm((first * np.repeat(w, blocks)) @ carried)) for w in weight_vectors]


def dense_weights(x: float, h: float, D: np.ndarray) -> np.ndarray:
    """DOP853 dense output at ``t_old + x h`` as weights of ``[y_old, y_new, K_0..K_15]``.

    The same nested polynomial as scipy's ``Dop853DenseOutput``, applied to
    coefficient vectors instead of states, so the value is one linear
    combination of tensor trains.
    """
    nk = D.shape[1]
    size = 2 + nk
    y_old, y_new = np.eye(size)[0], np.eye(size)[1]
    K = np.eye(size)[2:]
    delta = y_new - y_old
    F = [delta, h * K[0] - delta, 2 * delta - h * (K[12] + K[0])] + [h * (D[i] @ K) for i in range(D.shape[0])]
    y = np.zeros(size)
    for i, f in enumerate(reversed(F)):
        y = y + f
        y = y * (x if i % 2 == 0 else 1.0 - x)
    return y + y_old


class Dop853OnTrains:
    """DOP853 stages, embedded error and dense output on a list of trains (one per unknown).

    Parameters
    ----------
    system : NonlinearSystem
    stage_delta : float
        Frobenius bound of every stage rounding (attribute: made tighter on stiff problems).
    max_rank : int
    rng : numpy.random.Generator
        For the randomized roundings (same spec, same codebook).
    stats : dict
        Rounding counters, incremented in place.
    """

    def __init__(self, system: NonlinearSystem, stage_delta: float, max_rank: int, rng, stats: dict):
        self.system, self.stage_delta, self.max_rank, self.rng, self.stats = system, stage_delta, max_rank, rng, stats
        self.ones = tt_ones(system.shape)

    def rhs(self, t: float, state: list[TT]) -> list[TT]:
        """``f(t, state)`` per unknown, rounded to the stage bound."""
        return evaluate_rhs(self.system, t, state, self.stage_delta, self.max_rank, self.rng, self.stats)

    def combine(self, y: list[TT], ks: list[list[TT]], weights, delta: float, base_weight: float = 1.0) -> list[TT]:
        """``base_weight * y + sum_j w_j k_j`` per unknown, rounded to ``delta``."""
        per_unknown = []
        for i in range(len(y)):
            terms = [(base_weight, y[i], self.ones)] + [(float(w), k[i], self.ones)
                                                        for k, w in zip(ks, weights) if w != 0.0]
            per_unknown.append([tm for tm in terms if tm[0] != 0.0])
        return round_terms(per_unknown, delta, [max(u.ranks, default=1) for u in y], self.max_rank, self.rng,
                           self.stats)

    def step(self, t: float, y: list[TT], f: list[TT], h: float, state_delta: float) -> TrialStep:
        """The trial step from ``(t, y)`` with ``f = f(t, y)``; the new state rounded to ``state_delta``."""
        A, B, C, E3, E5, n_stages = DOP853.A, DOP853.B, DOP853.C, DOP853.E3, DOP853.E5, DOP853.n_stages
        y_new = f_new = None
        err, norm_new, K = np.inf, np.inf, [f]
        try:
            with np.errstate(over="ignore", invalid="ignore"):
                for s in range(1, n_stages):
                    stage = self.combine(y, K, h * A[s, :s], self.stage_delta)
                    K.append(self.rhs(t + C[s] * h, stage))
                y_new = self.combine(y, K, h * B, state_delta)
                norm_new = max(u.norm() for u in y_new)
                if np.isfinite(norm_new):
                    f_new = self.rhs(t + h, y_new)
                    K.append(f_new)
                    err = 0.0
                    for i in range(len(y)):
                        e5, e3 = frobenius_of_sums([K[j][i] for j in range(n_stages + 1)], [E5, E3])
                        if e5 > 0.0 or e3 > 0.0:
                            err = max(err, h * e5 * e5 / np.sqrt(e5 * e5 + 0.01 * e3 * e3))
        except np.linalg.LinAlgError:  # a factorization met the non-finite values of an overflow
            err = np.inf
        return TrialStep(y_new, f_new, K, err, norm_new)

    def dense_output(self, t: float, h: float, y: list[TT], trial: TrialStep, outs: list[float], t_new: float,
                     state_delta: float) -> list[list[TT]]:
        """The states at the times ``outs`` inside ``(t, t_new]`` of an accepted step.

        Three extra stages when a node lies inside; each node's state is one combination of
        ``y``, the new state and the stages (measured faster on coupled.yaml, 324 vs 358 ms,
        than joining the 18 trains along a combination mode and rounding once, or than
        rounding all nodes in one padded batch).
        """
        K = trial.stages
        if any(tn < t_new for tn in outs):
            for s, (a, c) in enumerate(zip(DOP853.A_EXTRA, DOP853.C_EXTRA), start=DOP853.n_stages + 1):
                stage = self.combine(y, K, h * a[:s], self.stage_delta)
                K.append(self.rhs(t + c * h, stage))
        states = []
        for tn in outs:
            if tn >= t_new:
                states.append(trial.state)
            else:
                w = dense_weights((tn - t) / h, h, DOP853.D)
                states.append(self.combine(y, [trial.state] + K, w[1:], state_delta, base_weight=w[0]))
        return states

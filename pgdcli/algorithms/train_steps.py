"""The tensor-train state of the time march: a train per unknown, the arithmetic a stepper needs.

Every stage value ``y + h sum_j a_sj K_j`` is a sum of trains rounded once to an absolute
Frobenius bound, and every right-hand side ``K_s = f(t + c_s h, stage)`` is evaluated in
separated form (:func:`pgdcli.algorithms.polynomial_rhs.evaluate_rhs`). A step's new state is
rounded to its share of the state's budget, and the state at a node inside a step (the dense
output) is one more rounded combination of trains. The embedded error estimates are Frobenius
norms of combinations of the stages, computed without rounding (:func:`frobenius_of_sums`).
"""

from __future__ import annotations

import numpy as np

from ..tensors.tt import TT, tt_ones, tt_sum
from .blowup import WATCH_POINTS, largest_value
from .polynomial_rhs import NonlinearSystem, evaluate_rhs, round_terms
from .stepping import Trial

__all__ = ["TrainSpace", "MarchFailure", "frobenius_of_sums"]


class MarchFailure(Exception):
    """The march could not continue (blow-up, step size underflow, caps).

    Attributes
    ----------
    time : float
        Time reached.
    state : list of TT or None
        The last accepted state (to locate the failure in the domain).
    blowup_time : float or None
        The predicted blow-up time, when the march stopped on that prediction.
    """

    def __init__(self, message: str, time: float, state: list | None = None, blowup_time: float | None = None):
        super().__init__(message)
        self.time = time
        self.state = state
        self.blowup_time = blowup_time


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


class TrainSpace:
    """A tensor train per unknown, rounded as the march's error budget says
    (:class:`pgdcli.algorithms.stepping.StateSpace`).

    Parameters
    ----------
    system : NonlinearSystem
    stage_delta : float
        Frobenius bound of every stage rounding (attribute: made tighter on stiff problems).
    state_delta : float
        Frobenius bound of the states' rounding: a step's new state gets ``state_delta * h / span``,
        a state at a node inside a step all of it.
    span : float
        Length of the time domain.
    max_rank : int
    rng : numpy.random.Generator
        For the randomized roundings (same spec, same codebook).
    stats : dict
        Rounding counters, incremented in place.
    """

    failure = MarchFailure
    kind = "tensor trains"

    def __init__(self, system: NonlinearSystem, stage_delta: float, state_delta: float, span: float,
                 max_rank: int, rng, stats: dict):
        self.system, self.stage_delta, self.state_delta, self.span = system, stage_delta, state_delta, span
        self.max_rank, self.rng, self.stats = max_rank, rng, stats
        self.ones = tt_ones(system.shape)

    def rhs(self, t: float, y: list[TT]) -> list[TT]:
        """``f(t, y)`` per unknown, rounded to the stage bound."""
        return evaluate_rhs(self.system, t, y, self.stage_delta, self.max_rank, self.rng, self.stats)

    def combine(self, y: list[TT], ks: list[list[TT]], weights, delta: float, base_weight: float = 1.0) -> list[TT]:
        """``base_weight * y + sum_j w_j k_j`` per unknown, rounded to ``delta``."""
        per_unknown = []
        for i in range(len(y)):
            terms = [(base_weight, y[i], self.ones)] + [(float(w), k[i], self.ones)
                                                        for k, w in zip(ks, weights) if w != 0.0]
            per_unknown.append([tm for tm in terms if tm[0] != 0.0])
        return round_terms(per_unknown, delta, [max(u.ranks, default=1) for u in y], self.max_rank, self.rng,
                           self.stats)

    def stages(self, f: list[TT], slots: int) -> list:
        return [f] + [None] * (slots - 1)

    def stage(self, y: list[TT], K: list, a: np.ndarray, h: float) -> list[TT]:
        return self.combine(y, K, h * a, self.stage_delta)

    def state(self, y: list[TT], K: list, b: np.ndarray, h: float) -> list[TT]:
        return self.combine(y, K, h * b, self.rounding(h))

    def rounding(self, h: float) -> float:
        """The rounding bound of a step's new state: the states' budget is per unit step."""
        return self.state_delta * h / self.span

    def norm(self, y: list[TT]) -> float:
        """The largest Frobenius norm of the unknowns."""
        return max(u.norm() for u in y)

    def largest(self, y: list[TT]) -> float:
        """The largest nodal value (the blow-up watch's measure)."""
        return largest_value(self.system, y, WATCH_POINTS)[0]

    def error_norms(self, K: list, count: int, weights: list[np.ndarray]) -> list[np.ndarray]:
        per_unknown = [frobenius_of_sums([K[j][i] for j in range(count)], weights) for i in range(len(K[0]))]
        return [np.array([norms[v] for norms in per_unknown]) for v in range(len(weights))]

    def dense(self, y: list[TT], y_new: list[TT], K: list, W: np.ndarray | None, count: int, out=None) -> list:
        """Each row of ``W`` combines ``[y, y_new, K...]`` into one state rounded to the state bound (a
        rounding per node: measured faster than joining the trains along a combination mode)."""
        states = [] if W is None else [self.combine(y, [y_new] + K, w[1:], self.state_delta, base_weight=w[0])
                                       for w in W]
        return states + [y_new] * (count - len(states))

    def start(self, y: list[TT]) -> list[TT]:
        return y

    def accept(self, trial: Trial) -> tuple[list[TT], list[TT]]:
        """The accepted step's state and ``f`` there."""
        return trial.y_new, trial.f_new

    def after_stage_noise(self, h: float) -> float:
        """The stage roundings' noise set the error estimate: round them 10x tighter, retry ``h``."""
        self.stage_delta /= 10.0
        self.stats["stage_tightenings"] = self.stats.get("stage_tightenings", 0) + 1
        return h

    def check(self, trial: Trial, t: float, y: list[TT]) -> None:
        """Refuse an accepted step whose ranks reached the cap."""
        if max(max(u.ranks, default=0) for u in trial.y_new) >= self.max_rank:
            # a capped rounding breaks the error bound: say so rather than report a wrong estimate
            raise MarchFailure(f"a tensor-train rank reached solver.max_rank={self.max_rank} (raise it)", t, y)

    def ranks(self, y: list[TT]) -> list:
        return [u.ranks for u in y]

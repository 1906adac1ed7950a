"""The PGD enrichment solver for linear parametric problems (the seed paper's Algorithm 1).

It works on the separated system of :mod:`pgdcli.discretization.linear`.

Algorithm (free functions below):

1. :func:`enrich` finds a rank-one term by an alternating-directions fixed
   point, solving for one mode with the others frozen. ``minres`` minimizes the
   residual norm (always a descent, never stalls); ``galerkin`` is the paper's
   Galerkin condition (eq. 12).
2. :func:`project_alphas` recomputes every weight (eq. 15 for Galerkin, a
   least-squares problem for minres, solved through an orthogonal sweep).
3. :func:`update_mode` optionally re-solves all modes of one coordinate jointly,
   which keeps the rank low. With updates (minres), every coordinate is updated
   after each enrichment and the residual checked once (:func:`_update_all`): the
   first update re-fits all weights, which does step 2's job. Should the residual
   not have fallen, the careful path is taken: step 2, then updates kept one by
   one only if they lower the residual, each checked with one more step of the
   projection's sweep (:func:`_update_sweep`).
4. The relative residual (eq. 16) is computed in separated form by orthogonal
   sweeps (:func:`pgdcli.tensors.cp.separated_norm`), accurate to rounding.

The state is :mod:`pgdcli.algorithms.enrichment_state`, step 1 :mod:`pgdcli.algorithms.rank_one`,
step 3's update of one mode :mod:`pgdcli.algorithms.mode_update`; the projection, the update
sweeps (they share the projection's partial sweeps) and the loop are here.
"""

from __future__ import annotations

from functools import partial

import numpy as np

from ..discretization.linear import Discretization
from ..progress import EnrichmentStep, emit
from ..tensors.cp import CPTensor, SeparatedOperator
from ..tensors.cp_sweep import khatri_rao_rows, sweep_order, sweep_step
from .enrichment_state import EnrichmentState
from .mode_update import update_mode
from .outcome import Status
from .rank_one import enrich, solve_small

__all__ = ["EnrichmentState", "enrich", "project_alphas", "update_mode", "residual_norm", "run_enrichment",
           "predicted_modes"]


def project_alphas(state: EnrichmentState, formulation: str = "minres") -> tuple[np.ndarray, float, float]:
    """Recompute all weights (the projection step) and the residual norm.

    Returns
    -------
    alphas : ndarray, shape (n,)
    residual : float
        ``||F - A U||`` with the new weights.
    source_norm : float
        ``||F||``.
    """
    alphas, residual, source_norm, _ = _project(state, formulation)
    return alphas, residual, source_norm


def _update_order(state: EnrichmentState) -> list[int]:
    """Modes in the order the update sweep visits them: smallest first.

    The projection's sweep runs the other way (largest first, the cheap order
    of :func:`~pgdcli.tensors.cp.sweep_order`), so its partial results are the
    suffixes the update sweep needs (:func:`_suffix_sweeps`).
    """
    return sweep_order([state.images[j].shape[1] for j in range(state.op.order)])[::-1]


def _suffix_sweeps(columns: list[np.ndarray], order: list[int]) -> list[np.ndarray | None]:
    """Orthogonal sweeps over the trailing modes of ``order``.

    Parameters
    ----------
    columns : list of ndarray, each shape (m_j, C)
        Factor matrices of the residual terms.
    order : list of int
        A permutation of the modes.

    Returns
    -------
    list of length d + 1
        Entry ``i`` is the sweep over the modes ``order[i:]`` (shape (r_i, C),
        visiting ``order[-1]`` first); entry 0 covers every mode, entry d is None.
        They do not depend on the weights.
    """
    out: list[np.ndarray | None] = [None] * (len(order) + 1)
    for i in range(len(order) - 1, -1, -1):
        out[i] = sweep_step(out[i + 1], columns[order[i]])
    return out


def _project(state: EnrichmentState, formulation: str) -> tuple[np.ndarray, float, float, list]:
    """:func:`project_alphas`, also returning the suffix sweeps of :func:`_update_order`."""
    K, n, nF = state.op.n_terms, state.rank, state.source.rank
    suffixes = _suffix_sweeps([state.residual_columns(j) for j in range(state.op.order)], _update_order(state))
    Z = suffixes[0]
    zF = Z[:, :nF] @ state.source.weights
    phi = Z[:, nF:].reshape(Z.shape[0], K, n).sum(axis=1)
    if formulation == "minres":
        alphas = np.linalg.lstsq(phi, zF, rcond=None)[0]
    else:
        alphas = _galerkin_alphas(state)
    return alphas, float(np.linalg.norm(zF - phi @ alphas)), float(np.linalg.norm(zF)), suffixes


def _galerkin_alphas(state: EnrichmentState) -> np.ndarray:
    """Paper's eq. (15): ``B alpha = H`` with ``B_il = <U_i, A U_l>``, ``H_i = <U_i, F>``."""
    d = state.op.order
    B = None
    Hv = None
    for j in range(d):
        u = state.factors[j]
        bj = np.einsum("ai,kal->kil", u, state.images[j])
        hj = u.T @ state.source.factors[j]
        B = bj if B is None else B * bj
        Hv = hj if Hv is None else Hv * hj
    return solve_small(B.sum(axis=0), Hv @ state.source.weights, symmetric=False)


def residual_norm(op: SeparatedOperator, source: CPTensor, approx: CPTensor) -> float:
    """``||F - A U||`` in separated form (orthogonal sweep), never forming a full tensor."""
    return (source + op.apply(approx).scaled(-1.0)).norm()


STAGNATION_WINDOW = 8
#: The enrichment predicts, from the last PREDICTION_WINDOW modes (after PREDICTION_AFTER), how many modes its
#: residual needs to reach the tolerance at its present rate of decay; beyond max_modes PREDICTION_REPEATS
#: modes in a row, it stops at once (status 1, as at max_modes) instead of running up to the cap. A rate
#: read over ten modes of a decay that slows (the usual case) underestimates what is left, so a prediction
#: past the cap is seldom wrong; the repeats keep one plateau from stopping it. (Each mode costs more than
#: the last: the half of a hundred modes that an early stop saves is most of the enrichment's time, and the
#: tensor-train solver takes over.)
PREDICTION_AFTER = 25
PREDICTION_WINDOW = 10
PREDICTION_REPEATS = 3


def predicted_modes(history: list[float], tol: float) -> float:
    """Modes at which a residual falling as over its last :data:`PREDICTION_WINDOW` modes reaches ``tol``.

    ``history`` has the residual before the first mode and after each; inf when it is not falling.
    """
    recent = np.log(np.maximum(np.asarray(history[-PREDICTION_WINDOW - 1:]), 1e-300))
    rate = (recent[0] - recent[-1]) / (recent.size - 1)  # decades (natural) a mode
    if not rate > 0.0:
        return float("inf")
    return len(history) - 1 + max(0.0, (recent[-1] - np.log(tol)) / rate)


def out_of_reach(history: list[float], tol: float, nmax: int) -> bool:
    """The residual's decay (:func:`predicted_modes`) reaches ``tol`` only past ``nmax`` modes, read after each of
    the last :data:`PREDICTION_REPEATS` modes (from :data:`PREDICTION_AFTER` modes on)."""
    if len(history) <= PREDICTION_AFTER + PREDICTION_REPEATS - 1:
        return False
    return all(predicted_modes(history[:len(history) - i], tol) > nmax for i in range(PREDICTION_REPEATS))


def run_enrichment(disc: Discretization, opts, tol: float, nmax: int, callback):
    """Enrich until the relative residual is ``tol`` or below, ``nmax`` terms, or stagnation.

    Returns
    -------
    state : EnrichmentState
    history : list of float
        Relative residual before the first term and after each.
    iterations : list of int
        Fixed-point iterations of each term.
    status : Status
        CONVERGED, MAX_MODES or STAGNATED.
    """
    state = EnrichmentState.empty(disc.operator, disc.source)
    source_norm = disc.source.norm()
    history = [1.0 if source_norm > 0 else 0.0]
    iterations: list[int] = []
    if source_norm == 0.0:
        return state, history, iterations, Status.CONVERGED
    status = Status.MAX_MODES
    for _ in range(nmax):
        res_w, res_f = state.residual()
        factors, its = None, 0
        starts = (make(res_f) for make in (partial(_dominant_term, res_w), partial(_random_start, seed=state.rank)))
        for start in starts:  # the random start only if the first gives a zero factor
            factors, its = enrich(
                disc.operator, res_w, res_f,
                formulation=opts.formulation,
                tolerance=opts.fixed_point_tolerance,
                max_iterations=opts.max_fixed_point_iterations,
                start=start,
            )
            norms = [np.linalg.norm(f) for f in factors]
            if min(norms) > 0.0 and np.all(np.isfinite(norms)):
                break
        else:
            status = Status.STAGNATED
            break
        state.append([f / nf for f, nf in zip(factors, norms)], float(np.prod(norms)))
        if opts.update and opts.formulation == "minres":
            res = _update_all(state, history[-1] * source_norm)
        else:
            state.alphas, res, _ = project_alphas(state, opts.formulation)
        rel = res / source_norm
        history.append(rel)
        iterations.append(its)
        emit(callback, EnrichmentStep(state.rank, rel, its, tol, nmax))
        if rel <= tol:
            status = Status.CONVERGED
            break
        if len(history) > STAGNATION_WINDOW and history[-1] > 0.99 * history[-1 - STAGNATION_WINDOW]:
            status = Status.STAGNATED
            break
        if out_of_reach(history, tol, nmax):
            break  # status 1: it would run into max_modes first
    return state, history, iterations, status


def _dominant_term(res_w: np.ndarray, res_f: list[np.ndarray]) -> list[np.ndarray]:
    """Factors of the residual's largest rank-one term: a start that is never orthogonal to it."""
    size = np.abs(res_w) * np.prod([np.linalg.norm(f, axis=0) for f in res_f], axis=0)
    c = int(np.argmax(size))
    return [f[:, c] + 0.0 for f in res_f]


def _random_start(res_f: list[np.ndarray], seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)  # deterministic: the same spec gives the same codebook
    return [rng.standard_normal(f.shape[0]) for f in res_f]


def _update_all(state: EnrichmentState, previous: float) -> float:
    """Update every mode once after an enrichment, checking the residual once, at the end.

    The first update re-solves all factors of one mode, weights included, so it
    also does the projection's job: measured on the shipped problems, this
    gives the same modes and residuals as projecting first and checking every
    mode's update, for one orthogonal sweep per enrichment instead of two.
    Should the residual not have fallen below ``previous`` (the residual before
    the enrichment; rounding in the normal equations near the tolerance can do
    that), the updates are undone and the careful path is taken: projection,
    then mode by mode updates kept only if they lower the residual
    (:func:`_update_sweep`).

    Returns
    -------
    float
        ``||F - A U||`` after the update.
    """
    saved = state.snapshot()
    for j in _update_order(state):
        update_mode(state, j)
    res = state.residual_norm()
    if res < previous:
        return res
    state.restore(saved)
    state.alphas, res, _, suffixes = _project(state, "minres")
    return _update_sweep(state, res, suffixes)


def _update_sweep(state: EnrichmentState, res: float, suffixes: list) -> float:
    """One update of every coordinate mode; keeps a mode's update only if it lowers the residual.

    The modes are visited in :func:`_update_order`. Each candidate's residual
    norm needs at most one new sweep step: the modes before it (already final)
    are swept into ``prefix`` as the loop goes, the modes after it are
    unchanged since the projection, whose suffix sweeps ``suffixes`` (from
    :func:`_project`, same factors) cover them.
    """
    prefix = None
    order = _update_order(state)
    for i, j in enumerate(order):
        saved = (state.alphas.copy(), state.factors[j].copy(), state.images[j].copy())
        update_mode(state, j)
        extended, new_res = _extend_and_norm(prefix, state, j, suffixes[i + 1])
        if new_res <= res:
            res = new_res
        else:
            state.alphas = saved[0]
            state.set_mode(j, saved[1], saved[2])
            if extended is not None:
                extended, _ = _extend_and_norm(prefix, state, j, suffixes[i + 1])
        prefix = extended
    return res


def _extend_and_norm(prefix: np.ndarray | None, state: EnrichmentState, j: int,
                     suffix: np.ndarray | None) -> tuple[np.ndarray | None, float]:
    """Sweep mode ``j`` into ``prefix`` and return it with the residual norm ``||F - A U||``.

    ``prefix`` (r_p, C) and ``suffix`` (r_s, C) are orthogonal-sweep results
    (coefficients in orthonormal bases) over the modes before and after ``j``,
    None for no mode. The norm is then that of the (r_p', r_s) matrix
    ``prefix' diag(w) suffix^T``, and its rounding error that of the last
    step of a full sweep (a weighted sum of the terms). With no suffix (the
    last mode) the norm needs no QR at all, and no extended prefix is returned.
    """
    columns, weights = state.residual_columns(j), state.residual_weights()
    if suffix is None:
        k = columns if prefix is None else khatri_rao_rows(prefix, columns)
        return None, float(np.linalg.norm(k @ weights))
    extended = sweep_step(prefix, columns)
    return extended, float(np.linalg.norm((extended * weights) @ suffix.T))

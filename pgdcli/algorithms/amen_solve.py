"""The tensor-train solver of linear problems: AMEn on the discretized space-time-parameter system.

The system of :mod:`pgdcli.discretization.linear` is ``A v = F`` with the operator a sum of
Kronecker products and the source a separated tensor, its rows the integrated equations tested
on every coordinate's nodes and weighted by the square roots of the quadrature weights (the
enrichment's residual is then an L2 norm). This module

1. turns the operator into a TT-matrix and the source into a tensor train by TT-SVD
   (:func:`pgdcli.tensors.tt_matrix.tt_matrix_from_terms`, :func:`pgdcli.tensors.tt_svd.tt_from_cp`):
   a source of hundreds of Kronecker terms (a moving load) is a train of modest ranks;
2. takes the quadrature weights off the rows (``W^-1/2 A``, ``W^-1/2 F``): each row is then the
   integrated equation at one node, and the residual's 2-norm over the nodes is an absolute
   number that bounds the largest nodal error up to the operator's smallest singular value
   (measured: the largest nodal error 0.7-2 times that norm on heat1d and the moving source).
   The weights, tiny at the ends of a Chebyshev coordinate, would otherwise let a solver leave
   errors where they hide (heat1d: at the last time node next to a boundary, 2000 times the
   weighted residual) and make the operator ill-conditioned (heat1d 11000 -> 930, a forced
   oscillator 830 -> 60);
3. solves the normal equations ``A^T A v = A^T F`` of that system by AMEn
   (:func:`pgdcli.tensors.amen.amen_solve`): symmetric positive definite, so every local solve
   lowers the residual itself (the minimal-residual counterpart of the enrichment's ``minres``;
   a Galerkin projection of the nonsymmetric ``A`` can break down on an oscillator, whose
   operator's symmetric part is indefinite), measured after every sweep;
4. writes ``v`` plus the lift into one tensor train per unknown: the codebook's tensor-train
   fields (time first, then the other coordinates).

The target of a solve is that 2-norm (absolute, in the unknowns' units): the solver's own stopping
signal, which the driver tightens when the error measured at the nodes asks for it. A solve can
start from an earlier solution, at the same nodes or interpolated from fewer
(:func:`interpolated_start`).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from .. import __version__
from ..codebook.codebook import Codebook
from ..discretization.coefficients import separation_report_text
from ..discretization.coordinates import coordinate_infos
from ..discretization.linear import Discretization, discretize
from ..progress import AmenSweep, emit
from ..tensors.amen import amen_solve
from ..tensors.tt import TT, tt_round, tt_sum
from ..tensors.tt_matrix import TTMatrix, tt_matrix_from_terms
from ..tensors.tt_svd import tt_from_cp
from .result import SolveResult

__all__ = ["solve_amen", "AmenSolution", "interpolated_start", "train_modes", "nodal_system", "column_scales",
           "field_trains", "MAX_SOURCE_TERMS"]

#: Most Kronecker terms one non-separable coefficient may expand to before it is compressed again
#: into the source's train (the enrichment's cap is 400: each term costs it in every sweep).
MAX_SOURCE_TERMS = 20_000
#: The source's train is rounded to this share of the target.
SOURCE_SHARE = 1e-2
#: AMEn's truncations may drop this share of the target (in the residual's 2-norm).
TRUNCATION_SHARE = 0.2
#: The codebook's trains (solution plus lift) are rounded to this share of the tolerance
#: (absolute, Frobenius over the nodes: it bounds the largest nodal change too).
FIELD_SHARE = 1e-2
#: Cap on the sweeps of one solve.
MAX_SWEEPS = 40
#: Status codes of a stopped solve, as the enrichment's (``SolveResult.status``).
STATUS = {"converged": 0, "rank cap": 1, "stalled": 2, "sweeps": 2, "stopped": 2}


def column_scales(terms) -> list[np.ndarray]:
    """Per mode, the norms of the columns over all the terms: ``sqrt(sum_t ||A_tk[:, j]||^2)`` (zero: 1)."""
    scales = []
    for k in range(len(terms[0])):
        s = np.sqrt(sum(np.sum(np.asarray(t[k], dtype=float) ** 2, axis=0) for t in terms))
        scales.append(np.where(s > 0.0, s, 1.0))
    return scales


def train_modes(disc: Discretization) -> list[int]:
    """The order of the train's modes (indices of ``disc.names``): the state, the diagonal modes, the others.

    Collocated parameters have diagonal matrices: their local systems split node by node, so they
    can carry the large ranks between the space-time and the parameters cheaply, while a space
    coordinate (dense matrices) at the end of the train has one rank 1 (its local systems are a
    rank times its nodes, not two ranks times them).
    """
    op = disc.operator
    rest = range(1, op.order)
    return [0] + [j for j in rest if op.mode_is_diagonal(j)] + [j for j in rest if not op.mode_is_diagonal(j)]


def nodal_system(disc: Discretization, target: float, modes: list[int]) -> tuple[TTMatrix, TT, list[np.ndarray]]:
    """``W^-1/2 A D^-1`` as a TT-matrix, ``W^-1/2 F`` as a train, and ``D`` per mode, in the order ``modes``.

    ``W`` takes the quadrature weights off the rows; ``D`` scales the columns of every mode
    to unit norm (:func:`column_scales`), which cuts the condition number of the normal equations
    (heat1d 3300 -> 170, squared) and leaves the residual as it is (``v = D^-1 y``). The source
    is rounded to :data:`SOURCE_SHARE` of ``target``.
    """
    unweight = [1.0 / np.sqrt(disc.row_weights[j]) for j in modes]
    terms = [[term[j] * s[:, None] for j, s in zip(modes, unweight)] for term in disc.operator.terms]
    scales = column_scales(terms)
    operator = tt_matrix_from_terms([[m / s[None, :] for m, s in zip(term, scales)] for term in terms])
    factors = [disc.source.factors[j] * s[:, None] for j, s in zip(modes, unweight)]
    source = tt_from_cp(disc.source.weights, factors, SOURCE_SHARE * target)
    return operator, source, scales


def solve_amen(problem, target: float, *, max_rank: int, callback=None, tolerance: float | None = None,
               max_sweeps: int = MAX_SWEEPS, stop=None, start: TT | None = None) -> SolveResult:
    """One AMEn solve of a linear problem to a residual (the solver's internal target).

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
    target : float
        The 2-norm over the nodes of the integrated equations' residual asked (absolute, in the
        unknowns' units).
    max_rank : int
        Cap on every tensor-train rank (``solver.max_rank``).
    callback : callable, optional
        Receives a :class:`~pgdcli.progress.AmenSweep` after each sweep.
    tolerance : float, optional
        The codebook's tolerance: non-separable coefficients are separated to a share of it,
        and the codebook's trains rounded to another.
    stop : callable, optional
        ``stop(info) -> str | None`` after each sweep (the same dict): a reason ends the solve early.
    start : AmenSolution, optional
        An earlier solution (:func:`interpolated_start` brings it to these nodes).

    Returns
    -------
    SolveResult
        ``status`` 0 converged, 1 a rank reached ``max_rank``, 2 the residual stopped falling
        (or the sweeps ran out, or ``stop`` ended it). ``result.solution`` (an
        :class:`AmenSolution`) can start another solve.
    """
    tol = problem.solver.tolerance if tolerance is None else tolerance
    started = _time.perf_counter()
    disc = discretize(problem, tolerance=tol, max_terms=MAX_SOURCE_TERMS)
    modes = train_modes(disc)
    names = [disc.names[j] for j in modes]
    operator, source, scales = nodal_system(disc, target, modes)
    normal = operator.gram().rounded()
    rhs = tt_round(operator.transpose().matvec(source), 1e-14)
    def residual(v: TT) -> float:
        return tt_sum([operator.matvec(v), source], [1.0, -1.0]).norm()

    def each_sweep(info: dict):
        info = dict(info, target=target)
        emit(callback, AmenSweep(info["sweep"], info["residual"], target, list(info["ranks"])))
        return stop(info) if stop is not None else None

    if start is not None:  # rounded to the target: an interpolated start need not carry all its ranks
        start = tt_round(interpolated_start(start, disc, names), absolute=TRUNCATION_SHARE * target)
        start = TT([c * s[None, :, None] for c, s in zip(start.cores, scales)])
    outcome = amen_solve(normal, rhs, target, x0=start, residual=residual, energy=TRUNCATION_SHARE * target,
                         max_rank=max_rank, max_sweeps=max_sweeps, callback=each_sweep)
    wall = _time.perf_counter() - started
    status = STATUS[outcome.status]
    history = np.array(outcome.residuals)
    if status == 0:
        message = f"converged: residual {outcome.residual:.3g} (2-norm at the nodes) in {len(history)} sweeps"
    else:
        message = f"not converged: {outcome.message} (tensor-train solver)"
    report = {
        "method": "amen",
        "converged": status == 0,
        "status": status,
        "message": message,
        "residual": outcome.residual,
        "residual_target": target,
        "residual_history": history,
        "sweeps": len(history),
        "sweep_times": np.array(outcome.times),
        "amen_status": outcome.status,
        "operator_ranks": ",".join(str(r) for r in operator.ranks),
        "source_ranks": ",".join(str(r) for r in source.ranks),
        "local_dense_solves": outcome.dense_solves,
        "local_iterations": outcome.iterations,
        "local_short_solves": outcome.short_solves,
        "max_rank": max_rank,
        "wall_time": wall,
    }
    if disc.separations:
        report["separated_coefficients"] = separation_report_text(disc.separations)
    solution = TT([c / s[None, :, None] for c, s in zip(outcome.solution.cores, scales)])
    codebook = _codebook(problem, disc, names, solution, report, FIELD_SHARE * tol)
    sweeps = np.array([max(r, default=1) for r in outcome.ranks], dtype=int)  # the largest rank after each sweep
    result = SolveResult(codebook, status == 0, status, message, history, sweeps, wall)
    result.solution = AmenSolution(solution, names, disc.bases, disc.trial, disc.time, len(disc.unknowns))
    return result


@dataclass(frozen=True)
class AmenSolution:
    """A solution ``v`` of the lifted system and the discretization it lives on (to start another solve)."""

    train: TT
    names: list
    bases: dict
    trial: dict
    time: str | None
    unknowns: int


def interpolated_start(start: AmenSolution, disc: Discretization, names: list[str]) -> TT:
    """``start``'s train on the nodes of ``disc`` (modes ``names``): each core interpolated in its coordinate's basis.

    The nodes where ``v`` is zero (the first time node, Dirichlet ends) are put back before
    and taken out after; the same nodes give the same train.
    """
    if start.names != names:
        raise ValueError(f"a start over the modes {start.names} for a train over {names}")
    cores = []
    for k, (core, name) in enumerate(zip(start.train.cores, names)):
        if k == 0 and start.time is None:
            cores.append(core)
            continue
        coordinate = start.time if k == 0 else name
        old, new = start.bases[coordinate], disc.bases[coordinate]
        if k == 0:  # the state: unknowns x free time nodes, v = 0 at the first time node
            r0, _, r1 = core.shape
            values = core.reshape(r0, start.unknowns, -1, r1)
            values = np.concatenate([np.zeros((r0, start.unknowns, 1, r1)), values], axis=2)
        else:
            values = np.zeros((core.shape[0], 1, old.nodes.size, core.shape[2]))
            values[:, 0, start.trial.get(name, slice(None)), :] = core
        if old.nodes.size != new.nodes.size or not np.array_equal(old.nodes, new.nodes):
            values = np.einsum("ij,aujb->auib", old.interpolation_matrix(new.nodes), values)
        if k == 0:
            values = values[:, :, 1:, :]
        else:
            values = values[:, :, disc.trial.get(name, slice(None)), :]
        cores.append(values.reshape(values.shape[0], -1, values.shape[3]))
    return TT(cores)


def field_trains(disc: Discretization, modes: list[str], solution: TT, absolute: float
                 ) -> tuple[dict[str, TT], tuple[int, ...]]:
    """Per unknown, the train of ``u = lift + v`` over the coordinates (time first), and their spec indices.

    ``solution``'s modes are ``modes``: the state first (unknowns x free time nodes, or one
    weight per unknown when steady), then coordinates; the time's first node, where ``v = 0``,
    and the Dirichlet nodes of space coordinates, where the lift carries the value, are put back
    as zeros.
    """
    names = disc.coordinates
    params = modes[1:]
    q = len(disc.unknowns)
    cores = list(solution.cores)
    for k, name in enumerate(params, start=1):
        if name in disc.trial:
            c = cores[k]
            full = np.zeros((c.shape[0], disc.bases[name].nodes.size, c.shape[2]))
            full[:, disc.trial[name], :] = c
            cores[k] = full
    state = cores[0].reshape(q, -1, cores[0].shape[2])
    if disc.time is None:
        order = tuple(names.index(p) for p in params)
    else:
        order = (names.index(disc.time),) + tuple(names.index(p) for p in params)
    out = {}
    for s, u in enumerate(disc.unknowns):
        if disc.time is None:  # the unknown's weights go into the first coordinate's core
            first = np.tensordot(state[s, 0], cores[1], axes=(0, 0))[None]
            train = [first] + cores[2:]
        else:
            times = np.vstack([np.zeros((1, state.shape[2])), state[s]])
            train = [times[None]] + cores[1:]
        lift = disc.lift[u]
        lift_train = tt_from_cp(lift.weights, [lift.factors[j] for j in order], 0.0)
        out[u] = tt_round(tt_sum([TT(train), lift_train]), absolute=absolute)
    return out, order


def _codebook(problem, disc: Discretization, modes: list[str], solution: TT, report: dict, absolute: float
              ) -> Codebook:
    coords = coordinate_infos(problem, march=False)
    trains, order = field_trains(disc, modes, solution, absolute)
    fields = {u: TT(tuple(t.cores), order) for u, t in trains.items()}
    report = dict(report, pgdcli_version=__version__)
    return Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                    description=problem.description)

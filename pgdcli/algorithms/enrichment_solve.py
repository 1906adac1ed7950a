"""A linear problem by the PGD enrichment, into a codebook: one solve to a relative residual.

:func:`solve_enrichment` discretizes the problem (:mod:`pgdcli.discretization.linear`), enriches it
(:func:`pgdcli.algorithms.enrichment.run_enrichment`) and assembles the codebook of lift terms plus PGD
terms per unknown (:func:`codebook_from_solution`). The relative residual is the solver's own stopping
signal; the driver measures the codebook's error and asks for a smaller residual when the nodes need it.
"""

from __future__ import annotations

import time as _time

import numpy as np

from .. import __version__
from ..codebook.codebook import Codebook
from ..discretization.coefficients import separation_report_text
from ..discretization.coordinates import coordinate_infos
from ..discretization.linear import discretize
from ..tensors.cp import CPTensor
from .enrichment import predicted_modes, run_enrichment
from .outcome import Learned, SolverOutcome, Status

__all__ = ["solve_enrichment", "codebook_from_solution"]


def solve_enrichment(problem, target: float, max_modes: int, callback=None, separation_tolerance: float | None = None,
                     learned: Learned = Learned()) -> SolverOutcome:
    """Enrich until the relative residual is ``target`` or below (at most ``max_modes`` terms).

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        Linear in the unknowns.
    target : float
        Relative residual asked.
    max_modes : int
    callback : callable, optional
        Called with an :class:`~pgdcli.progress.EnrichmentStep` after each term.
    separation_tolerance : float, optional
        Non-separable coefficients are separated to a share of it (default: the spec's tolerance).
    learned : Learned
        Not used: nothing of an earlier solve changes the enrichment but its target.

    Returns
    -------
    SolverOutcome
    """
    opts = problem.solver
    started = _time.perf_counter()
    disc = discretize(problem, tolerance=separation_tolerance)
    state, history, iterations, status = run_enrichment(disc, opts, target, max_modes, callback)
    wall = _time.perf_counter() - started
    residual = history[-1]
    message = _message(status, history, target, max_modes, state.rank)
    report = {
        "converged": status is Status.CONVERGED,
        "status": int(status),
        "message": message,
        "modes": state.rank,
        "residual": residual,
        "residual_tolerance": target,
        "residual_history": np.array(history),
        "iterations": np.array(iterations, dtype=int),
        "wall_time": wall,
        "max_modes": max_modes,
        "formulation": opts.formulation,
        "update": bool(opts.update),
    }
    if disc.separations:  # how many terms each non-separable coefficient needed
        report["separated_coefficients"] = separation_report_text(disc.separations)
    codebook = codebook_from_solution(problem, disc, state.alphas, state.factors, report)
    return SolverOutcome(codebook, status, message, target, f"relative residual {residual:.3g} with {state.rank} modes",
                         residuals=np.array(history), iterations=np.array(iterations, dtype=int), wall_time=wall)


def _message(status: Status, history: list, target: float, max_modes: int, rank: int) -> str:
    residual = history[-1]
    if status is Status.CONVERGED:
        return f"converged: relative residual {residual:.3g} with {rank} modes"
    if status is Status.MAX_MODES and rank < max_modes:  # stopped early: the cap is out of reach at this rate
        needed = predicted_modes(history, target)
        advice = ("solver.method: amen (the tensor-train solver) may take it" if needed > 1e4 else
                  "raise solver.max_modes, or solver.method: amen (the tensor-train solver) may take it")
        return (f"not converged: relative residual {residual:.3g} after {rank} modes, falling as if to need "
                f"{'more than 10 000' if needed > 1e4 else f'about {np.ceil(needed):.0f}'} modes to reach {target:.3g} "
                f"(max_modes={max_modes}); {advice}")
    if status is Status.MAX_MODES:
        return (f"not converged: relative residual {residual:.3g} > {target:.3g} after max_modes={max_modes} modes "
                f"(raise solver.max_modes, or solver.method: amen)")
    return (f"not converged: relative residual stagnated at {residual:.3g} (asked {target:.3g}) "
            f"after {rank} modes; solver.method: amen (the tensor-train solver) may take it")


def codebook_from_solution(problem, disc, alphas: np.ndarray, factors: list[np.ndarray], report: dict):
    """Assemble the codebook of a solved problem: lift terms + PGD terms per unknown."""
    coords = coordinate_infos(problem, march=False)
    nodal = disc.nodal_factors(factors)
    fields = {}
    for u in disc.unknowns:
        lift = disc.lift[u]
        modes = nodal[u]
        # a term whose time function (steady: its weight, in the first modes) vanishes for this
        # unknown carries nothing for it
        j = 0 if disc.time is None else [c.name for c in coords].index(disc.time)
        keep = np.any(modes[j] != 0.0, axis=0) & (alphas != 0.0)
        fields[u] = CPTensor(
            np.concatenate([lift.weights, alphas[keep]]),
            tuple(np.hstack([lf, nf[:, keep]]) for lf, nf in zip(lift.factors, modes)),
        )
    report = dict(report)
    report["pgdcli_version"] = __version__
    return Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                    description=problem.description)

"""The solver methods and the rule that chooses one for a problem.

* ``pgd``: the PGD enrichment of linear problems (:mod:`pgdcli.algorithms.enrichment_solve`), to a
  relative residual;
* ``march``: the time march of nonlinear ODE problems (:mod:`pgdcli.algorithms.march`), to an RMS
  error over the parameter grid;
* ``pde march``: the exponential march of a nonlinear PDE in one space coordinate
  (:mod:`pgdcli.algorithms.pde_solve`), to an RMS error over the grid.

Each is a :class:`~pgdcli.driver.method.Method` in :data:`METHODS`; :func:`choose_method` reads the
spec's ``solver.method`` and the equations and returns a :class:`~pgdcli.driver.method.MethodChoice`.
"""

from __future__ import annotations

import numpy as np

from ..algorithms.amen_solve import solve_amen
from ..algorithms.enrichment_solve import solve_enrichment
from ..algorithms.march import solve_march
from ..algorithms.outcome import SolverOutcome, Status
from ..algorithms.pde_solve import solve_pde_march
from ..algorithms.pde_system import pde_refusal
from ..errors import SolverError
from ..problem.general import has_general
from .method import Kept, Method, MethodChoice, Try

__all__ = ["METHODS", "choose_method", "Enrichment", "Amen", "OdeMarch", "PdeMarch", "CHECK_FIRST", "CHECK_SAFETY",
           "MARCH_SAFETY", "RESIDUAL_FLOOR", "AMEN_FIRST", "AMEN_TIGHTEN", "AMEN_NODE_MARGIN"]

# The enrichment's residual is relative; the tolerance is an absolute error. The first solve asks
# for a relative residual equal to the tolerance (right for solutions of size ~1); when the error
# measured at the nodes is larger, the residual asked is scaled down by CHECK_SAFETY * tolerance /
# error and the enrichment runs again. An error that does not fall with the residual is
# discretization error: more nodes (pgdcli.adapt).
CHECK_SAFETY = 0.5
RESIDUAL_FLOOR = 1e-13
# The march controls an RMS over the parameter grid; the tolerance bounds the max abs error. The
# first march aims at CHECK_FIRST * tolerance, below the tolerance because the largest error is
# usually near the RMS target or somewhat above it: a target at the tolerance would often need a
# second march. A repeated march aims at MARCH_SAFETY / ratio of the last target: its error follows
# the target closely, and a smaller factor drives the ranks up for little gain.
CHECK_FIRST = 0.7
MARCH_SAFETY = 0.8
# A march this many times tighter than the last whose error did not halve: the error is not the
# march's (time nodes the spec fixes, a parameter between its nodes), and a tighter one only costs
# steps (down to max_steps at a target below rounding).
MARCH_STALL = 10.0


class Enrichment(Method):
    """The PGD enrichment, to a relative residual; a smaller residual when the nodes ask for it."""

    name = "pgd"
    hands_time_over = True  # time is one polynomial over the interval, refined one doubling at a time
    plural = "enrichments"
    target_name = "residual"
    label = "enrichment"
    names_itself = True
    #: The report entry of the solves at one set of nodes: (solves, 2), residual asked and node ratio.
    attempts_key = "enrichment_attempts"

    def solve(self, problem, target, settings, learned, callback) -> SolverOutcome:
        # non-separable coefficients are separated to a share of the tolerance, tightened with the
        # residual when the error at the nodes asks for another enrichment (as the march's target is)
        return solve_enrichment(problem, target, settings.max_modes, callback, min(settings.tolerance, target))

    def stalled(self, outcome: SolverOutcome) -> bool:
        # max_modes reached or predicted, or the residual stagnating: the tensor-train solver may take it
        return outcome.status in (Status.MAX_MODES, Status.STAGNATED)

    def next_target(self, problem, tries, settings) -> float | None:
        last = tries[-1]
        if not last.outcome.converged:
            return None
        ratio = last.check.node_ratio
        if not np.isfinite(ratio) or ratio <= 1.0 or last.target <= RESIDUAL_FLOOR:
            return None
        if len(tries) > 1 and ratio > 0.5 * tries[-2].check.node_ratio:
            return None  # a smaller residual did not help: discretization error
        # a residual is cheap to lower and the error follows it only roughly: at least a decade below
        # the residual reached
        return max(RESIDUAL_FLOOR, min(last.target, last.outcome.residual) * min(0.1, CHECK_SAFETY / ratio))

    def keep(self, tries) -> Kept | None:
        kept = super().keep(tries)
        if kept is None:
            return None
        last, stopped = tries[-1], None
        if not last.outcome.converged:
            stopped = last.outcome.message  # the smaller residual the nodes ask for was not reached
            if last.check is not None:  # max_modes, but the residual fell: the error decides
                kept.attempt, stopped = _at_max_modes(kept.attempt, last)
        if kept.attempt.check.node_ratio > 1.0:
            # the residual could not be lowered: more nodes would not help; or it did not bring the
            # error down: more time or space nodes
            kept.stopped = stopped.removeprefix("not converged: ") if stopped is not None else None
            kept.limited = stopped is None
        return kept

    def round_entries(self, kept, tries, settings) -> dict:
        measured = [t for t in tries if t.check is not None]
        entries = {}
        if kept.stopped is not None:
            entries["enrichment_stopped"] = kept.stopped
        elif kept.limited:
            entries["discretization_limited"] = 1
        entries["tolerance"] = float(settings.tolerance)
        # (solves, 2): residual asked, node ratio
        entries[self.attempts_key] = np.array([(t.target, t.check.node_ratio) for t in measured], dtype=float)
        entries["solver_message"] = self.summary(kept, tries)
        return entries


def _at_max_modes(kept: Try, stopped: Try) -> tuple[Try, str | None]:
    """Weigh an enrichment that stopped at max_modes below the residual asked against the one kept.

    Returns the better of the two and the reason to give when it still misses the
    tolerance: the enrichment's (its residual fell, and the error with it, but not
    far enough: more modes) or None (the residual fell tenfold and the error at the
    nodes not by half: discretization error, which more nodes reduce).
    """
    reason = stopped.outcome.message
    if stopped.check.node_ratio >= kept.check.node_ratio:
        return kept, reason
    if (stopped.outcome.residual <= 0.1 * kept.outcome.residual
            and stopped.check.node_ratio > 0.5 * kept.check.node_ratio):
        reason = None
    return stopped, reason


# AMEn's target is the 2-norm over the nodes of the integrated equations' residual (absolute, in the
# unknowns' units), which bounds the largest nodal error up to the operator's smallest singular value:
# the first solve asks AMEN_FIRST x the tolerance. A repeated solve, at the same nodes or more, starts
# from the last solution (interpolated); a tighter target is at most AMEN_TIGHTEN x tighter.
AMEN_FIRST = 0.5
AMEN_TIGHTEN = 10.0
# An error at the nodes this many times the residual reached is not the solver's: a tighter solve that
# stalls then blames the discretization (more nodes), not itself
AMEN_NODE_MARGIN = 10.0


class Amen(Method):
    """The tensor-train solver of a linear problem (AMEn), to an absolute residual at the nodes."""

    name = "amen"
    plural = "solves"
    target_name = "residual"
    label = "tensor-train solver"
    names_itself = True
    attempts_key = "amen_attempts"

    def first_target(self, settings, learned) -> float:
        return learned.target if learned.target is not None else AMEN_FIRST * settings.tolerance

    def solve(self, problem, target, settings, learned, callback) -> SolverOutcome:
        result = solve_amen(problem, target, max_rank=problem.solver.max_rank, callback=callback,
                            tolerance=settings.tolerance, start=learned.start)
        status = Status(result.status)
        ranks = max(max(f.ranks, default=1) for f in result.codebook.fields.values())
        summary = (f"tensor-train solver: residual {result.residuals[-1]:.3g} (2-norm at the nodes), "
                   f"{len(result.residuals)} sweeps, largest rank {ranks}")
        return SolverOutcome(result.codebook, status, result.message, target, summary, residuals=result.residuals,
                             iterations=result.iterations, wall_time=result.wall_time, start=result.solution)

    def measures(self, outcome, tries) -> bool:
        # a tighter solve that stopped short of its target is measured too: its best iterate may tell
        return outcome.converged or bool(tries)

    def next_target(self, problem, tries, settings) -> float | None:
        last = tries[-1]
        if not last.outcome.converged or last.check is None:
            return None
        ratio = last.check.node_ratio
        if not np.isfinite(ratio) or ratio <= 1.0 or last.target <= RESIDUAL_FLOOR * settings.tolerance:
            return None
        measured = [t for t in tries if t.check is not None]
        if len(measured) > 1 and ratio > 0.5 * measured[-2].check.node_ratio:
            return None  # a smaller residual did not help: discretization error
        # at most AMEN_TIGHTEN at once: a large error at the nodes may be the discretization's, and a
        # much smaller residual costs sweeps at higher ranks before the next measurement can tell
        return max(RESIDUAL_FLOOR * settings.tolerance,
                   min(last.target, last.outcome.residual) * max(1.0 / AMEN_TIGHTEN, CHECK_SAFETY / ratio))

    def keep(self, tries) -> Kept | None:
        measured = [t for t in tries if t.check is not None]
        converged = [t for t in measured if t.outcome.converged]
        if not converged:
            return None
        kept = Kept(min(measured, key=lambda t: t.check.node_ratio))
        if kept.attempt.check.node_ratio <= 1.0:
            return kept
        last, before = tries[-1], converged[-1]
        stopped = None
        if not last.outcome.converged:  # a tighter solve stopped short of its target
            stopped = last.outcome.message.removeprefix("not converged: ")
            reached = min(t.outcome.residual for t in measured)
            if before.check.node_error > AMEN_NODE_MARGIN * reached:
                stopped = None  # the error at the nodes is far above any residual reached: more nodes
            if (last.check is not None and last.outcome.residual <= 0.1 * before.outcome.residual
                    and last.check.node_ratio > 0.5 * before.check.node_ratio):
                stopped = None  # the residual fell and the error did not: more nodes
        kept.stopped, kept.limited = stopped, stopped is None
        return kept

    round_entries = Enrichment.round_entries  # its attempts as amen_attempts


class OdeMarch(Method):
    """The time march of a nonlinear ODE problem, to an RMS target; a tighter march when the nodes ask for it."""

    name = "march"
    marches = True
    plural = "marches"
    target_name = "RMS"
    pilots = True

    def first_target(self, settings, learned) -> float:
        return learned.target if learned.target is not None else CHECK_FIRST * settings.tolerance

    def solve(self, problem, target, settings, learned, callback) -> SolverOutcome:
        return solve_march(problem, target, callback=callback, learned=learned)

    def solver_ratio(self, check, problem) -> float:
        """The error at the grid nodes, at the time nodes and between them.

        Between time nodes a march's codebook interpolates within its accepted steps (the slabs),
        which a tighter march shortens: its error there is the march's own too.
        """
        time = problem.time
        return max(check.node_ratio, check.coordinate_ratio.get(time, 0.0) if time else 0.0)

    def next_target(self, problem, tries, settings) -> float | None:
        last = tries[-1]
        if not last.outcome.converged:
            return None
        ratio = self.solver_ratio(last.check, problem)
        if not np.isfinite(ratio) or ratio <= 1.0:
            return None
        measured = [t for t in tries if t.check is not None and t.outcome.converged]
        if len(measured) > 1 and measured[-1].target * MARCH_STALL <= measured[-2].target \
                and ratio > 0.5 * self.solver_ratio(measured[-2].check, problem):
            return None  # a much tighter march did not lower the error
        return last.target * (MARCH_SAFETY / ratio)

    def keep(self, tries) -> Kept | None:
        kept = super().keep(tries)
        last = tries[-1]
        if kept is not None and not last.outcome.converged:
            kept.notes.append(f"the march with the tighter target {last.target:.2g} failed ({last.outcome.message}); "
                              f"kept the one with target {kept.attempt.target:.2g}")
        return kept

    def failure_entries(self, target, settings) -> dict:
        # the report speaks of the user's tolerance; the march's own target beside it
        return {"tolerance": float(settings.tolerance), "march_tolerance": float(target)}

    def round_entries(self, kept, tries, settings) -> dict:
        measured = [t for t in tries if t.check is not None]
        return {
            "tolerance": float(settings.tolerance),
            "march_tolerance": float(measured[-1].target),
            # (marches, 2): RMS target, measured max error
            "march_attempts": np.array([(t.target, t.check.error) for t in measured], dtype=float),
            "solver_message": self.summary(kept, tries),
        }


class PdeMarch(OdeMarch):
    """The exponential march of a reaction-diffusion system (the ODE march's targets).

    A tighter march whose error did not halve is limited by the space nodes, not the steps: the
    Chebyshev tail of a coarse solution can understate that error (a 2-D Allen-Cahn on 17 x 17
    nodes kept the same error at two march targets 6x apart), so the resolution is told to refine
    the space coordinates instead of marching tighter again.
    """

    name = "pde march"
    #: No pilot: the space nodes are refined first (a march on too few of them stops), so a pilot along a
    #: parameter at the first space nodes would march for nothing.
    pilots = False

    def solve(self, problem, target, settings, learned, callback) -> SolverOutcome:
        return solve_pde_march(problem, target, callback=callback, learned=learned)

    def next_target(self, problem, tries, settings) -> float | None:
        return None if _space_limited(tries) else super().next_target(problem, tries, settings)

    def keep(self, tries) -> Kept | None:
        kept = super().keep(tries)
        if kept is not None and _space_limited(tries) and kept.attempt.check is not None:
            kept.limited = True  # pgdcli.adapt refines the space coordinates
        return kept

    def round_entries(self, kept, tries, settings) -> dict:
        entries = super().round_entries(kept, tries, settings)
        if kept.limited:
            entries["discretization_limited"] = 1
        return entries


def _space_limited(tries) -> bool:
    """Two measured marches, the tighter one's error more than half the other's."""
    measured = [t for t in tries if t.check is not None and t.outcome.converged]
    return len(measured) > 1 and measured[-1].check.error > 0.5 * measured[-2].check.error


#: The solver methods by name.
METHODS: dict[str, Method] = {m.name: m for m in (Enrichment(), Amen(), OdeMarch(), PdeMarch())}


def choose_method(problem) -> MethodChoice:
    """The method for ``problem`` (``solver.method``: ``auto``, ``pgd`` or ``march``), or a SolverError.

    ``auto`` marches nonlinear problems and enriches linear ones; a nonlinear PDE goes to the
    PDE march when it has one space coordinate.
    """
    nonlinear = any(eq.polynomial.degree >= 2 or has_general(eq.polynomial) for eq in problem.equations)
    asked = getattr(problem.solver, "method", "auto")
    if asked in ("pgd", "amen") and nonlinear:
        raise SolverError(f"{problem.source}: solver.method: '{asked}' solves equations linear in the unknowns only; "
                          f"use 'march' or 'auto' for this problem")
    march = asked == "march" or (asked == "auto" and nonlinear)
    if not march:
        if asked in ("pgd", "amen"):
            return MethodChoice((METHODS[asked],), f"solver.method: {asked}")
        if problem.time is not None and not any(c.role == "space" for c in problem.coordinates):
            # one polynomial in time over the whole interval cannot hold a fast transient (a stiff decay):
            # the march steps through it
            return MethodChoice((METHODS["pgd"], METHODS["amen"], METHODS["march"]),
                                "a linear problem: the enrichment first, the tensor-train solver if it stalls, "
                                "the time march if neither meets the tolerance")
        return MethodChoice((METHODS["pgd"], METHODS["amen"]),
                            "a linear problem: the enrichment first, the tensor-train solver if it stalls")
    if problem.time is None:
        raise SolverError(f"{problem.source}: equations: a steady problem (no time coordinate) needs equations linear "
                          f"in the unknowns and solver.method 'auto', 'pgd' or 'amen' (the march steps in time)")
    why = "solver.method: march" if asked == "march" else "equations nonlinear in the unknowns"
    if any(c.role == "space" for c in problem.coordinates):
        reason = pde_refusal(problem)  # a nonlinear PDE in one space coordinate goes to the PDE march
        if reason:
            raise SolverError(reason)
        return MethodChoice((METHODS["pde march"],), why + ", one space coordinate")
    return MethodChoice((METHODS["march"],), why)

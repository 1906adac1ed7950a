"""What a solver hands back, and what one solve of a problem learns for the next.

Every solver method (the PGD enrichment, the ODE march, the PDE march) returns a :class:`SolverOutcome`:
the codebook it built (its report holds the solver's own entries), a :class:`Status`, a message, and the
few facts the driver acts on, typed: the target it was asked, a coordinate whose lack of nodes stopped it
early, a march variant it gave up on. The driver carries a :class:`Learned` from one solve to the next.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np

__all__ = ["Status", "SolverOutcome", "Learned"]


class Status(IntEnum):
    """How a solve ended. The values are those of the codebook's report and of ``SolveResult.status``."""

    #: The solver met its target (and, in a :class:`~pgdcli.driver.SolveResult`, the measured error its tolerance).
    CONVERGED = 0
    #: The enrichment reached ``solver.max_modes`` above the residual asked.
    MAX_MODES = 1
    #: The enrichment's residual stopped falling.
    STAGNATED = 2
    #: The march could not reach the end of the time domain (blow-up, step size, rank or step caps).
    FAILED = 3
    #: The codebook's measured error exceeds its tolerance.
    INACCURATE = 4


@dataclass
class SolverOutcome:
    """One solve by one method at one set of nodes.

    Attributes
    ----------
    codebook : pgdcli.codebook.codebook.Codebook
        The solution (a placeholder of zeros when the march failed); its report holds the solver's entries.
    status : Status
    message : str
        ``"converged: ..."`` or ``"not converged: ..."``, the solver's own words.
    target : float
        The solver's own target: the relative residual (enrichment) or the RMS error (march) asked.
    summary : str
        What the solver did, for the result's message: ``"relative residual 3.1e-09 with 7 modes"``.
    residuals : ndarray, shape (n_modes + 1,)
        The enrichment's relative residuals; a march's error estimate (inf when it failed).
    iterations : ndarray, shape (n_modes,)
        Fixed-point iterations of each enrichment (empty for a march).
    wall_time : float
        Seconds.
    under_resolved : str or None
        A coordinate whose lack of nodes stopped the solver early: more nodes there, and solve again.
    cross_abandoned : str or None
        Why a cross of trajectories was given up for the grid march in this solve.
    stiff : str or None
        Why the march switched to its stiff stepper in this solve (``solver.integrator: auto``).
    """

    codebook: object
    status: Status
    message: str
    target: float
    summary: str = ""
    residuals: np.ndarray = field(default_factory=lambda: np.zeros(0))
    iterations: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))
    wall_time: float = 0.0
    under_resolved: str | None = None
    cross_abandoned: str | None = None
    stiff: str | None = None
    #: A solution another solve can start from (the tensor-train solver's), or None.
    start: object = None

    @property
    def converged(self) -> bool:
        return self.status is Status.CONVERGED

    @property
    def residual(self) -> float:
        return float(self.residuals[-1]) if self.residuals.size else float("nan")

    @property
    def n_modes(self) -> int:
        return int(self.iterations.size)


@dataclass(frozen=True)
class Learned:
    """What the solves of one problem so far teach the next (on the same or a finer grid).

    Attributes
    ----------
    target : float or None
        The solver's own target (residual or RMS) that last met the tolerance at the nodes: the error at the
        nodes hardly depends on how many there are, so the next solve starts from it.
    cross_abandoned : str or None
        A cross of trajectories ran past its budget: a finer grid asks it for more trajectories a node, not
        fewer, so the next solves take the grid march when it can hold the grid.
    start : object or None
        The last solution a solver can start from (the tensor-train solver's, interpolated to new nodes).
    stiff : str or None
        The march found the problem stiff: the next solves march with the stiff stepper from the start.
    """

    target: float | None = None
    cross_abandoned: str | None = None
    start: object = None
    stiff: str | None = None

    def after(self, outcome: SolverOutcome) -> "Learned":
        """What is known after ``outcome`` too."""
        learned = self
        if outcome.cross_abandoned and not self.cross_abandoned:
            learned = dataclasses.replace(learned, cross_abandoned=outcome.cross_abandoned)
        if outcome.stiff and not self.stiff:
            learned = dataclasses.replace(learned, stiff=outcome.stiff)
        if outcome.start is not None and outcome.converged:
            learned = dataclasses.replace(learned, start=outcome.start)
        return learned

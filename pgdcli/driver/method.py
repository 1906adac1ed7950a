"""The interface of a solver method, and the typed records of one round of solves.

A method (:class:`Method`) solves a problem at one set of nodes to its own target (a relative
residual, an RMS error) and says how to tighten that target when the error measured at the nodes
is too large. :mod:`pgdcli.driver.methods` holds the methods and the rule that chooses one;
:mod:`pgdcli.driver.refinement` runs them: solve -> check -> refine, until the error meets the tolerance.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ..algorithms.outcome import Learned, SolverOutcome, Status

__all__ = ["Settings", "Try", "Kept", "Method", "MethodChoice"]


@dataclass(frozen=True)
class Settings:
    """What the user asked of the codebook: ``|u - u_ref| <= tolerance + relative_tolerance |u_ref|``.

    ``max_modes`` caps the enrichment's terms.
    """

    tolerance: float
    relative_tolerance: float
    max_modes: int


@dataclass
class Try:
    """One solve at a set of nodes and its measured error.

    Attributes
    ----------
    target : float
        The solver's own target asked.
    outcome : SolverOutcome
    check : pgdcli.checks.check.CheckResult or None
        None when the solve was not measured (it failed).
    warnings : list of str
        Findings of the measurement (a reference that could not check every point).
    """

    target: float
    outcome: SolverOutcome
    check: object = None
    warnings: list = field(default_factory=list)


@dataclass
class Kept:
    """What the solves at one set of nodes gave: the try kept, and what the others said.

    Attributes
    ----------
    attempt : Try
        Measured; its outcome holds a solution (converged, or stopped at ``max_modes``).
    stopped : str or None
        The solver could not lower its own error at the nodes further: why (the refinement of
        the nodes then leaves the coordinates that only the solver could help).
    limited : bool
        The error at the nodes did not fall with the solver's target: discretization error,
        which only more nodes in time and space reduce.
    notes : list of str
        Warnings for the result (a tighter solve that failed).
    """

    attempt: Try
    stopped: str | None = None
    limited: bool = False
    notes: list = field(default_factory=list)


class Method:
    """A solver method: one entry of :data:`pgdcli.driver.methods.METHODS`.

    Subclasses set the class attributes and implement :meth:`solve`; the others have defaults
    (one solve per set of nodes, the tolerance and the solver's summary in the report) that a
    method overrides to tighten its own target when the error at the nodes asks for it.
    """

    #: The name in reports and messages.
    name = ""
    #: Its time nodes follow its steps: the automatic resolution does not refine them.
    marches = False
    #: What one solve is called in the result's message ("3 marches").
    plural = "solves"
    #: What the solver's target is, for progress lines ("residual", "RMS").
    target_name = "target"
    #: What messages call it ("enrichment", "tensor-train solver"); its name when empty.
    label = ""
    #: The report names it (``method``, ``method_reason``): a linear problem has two to choose from.
    names_itself = False
    #: Whether a linear ODE problem goes on to the time march, when the choice has it, once the automatic
    #: resolution would give this method more than :data:`pgdcli.driver.refinement.POLYNOMIAL_TIME_NODES`
    #: time nodes.
    hands_time_over = False
    #: Its first round's automatic parameter nodes come from a pilot (:mod:`pgdcli.adapt.pilot`): a solve costs
    #: little more with a few dozen nodes more along one coordinate.
    pilots = False

    @property
    def title(self) -> str:
        return self.label or self.name

    def first_target(self, settings: Settings, learned: Learned) -> float:
        """The target of the first solve at a set of nodes: what met the tolerance before, else the tolerance."""
        return learned.target if learned.target is not None else settings.tolerance

    def solve(self, problem, target: float, settings: Settings, learned: Learned, callback) -> SolverOutcome:
        """One solve to ``target``; progress events to ``callback``."""
        raise NotImplementedError

    def solver_ratio(self, check, problem) -> float:
        """The part of the measured error that a tighter target brings down (over the tolerance)."""
        return check.node_ratio

    def next_target(self, problem, tries: list[Try], settings: Settings) -> float | None:
        """A tighter target for another solve at the same nodes, or None: the tries are done (default: one try)."""
        return None

    def measures(self, outcome: SolverOutcome, tries: list[Try]) -> bool:
        """Whether the error of this outcome is measured (``tries``: those before it at these nodes).

        A converged solve always is; one that stopped at ``max_modes`` short of a tighter target is
        weighed against the one before it.
        """
        return outcome.converged or (outcome.status is Status.MAX_MODES and bool(tries))

    def keep(self, tries: list[Try]) -> Kept | None:
        """The try to keep of those at one set of nodes (None: the first solve failed): the last converged."""
        converged = [t for t in tries if t.outcome.converged]
        return Kept(converged[-1]) if converged else None

    def failure_entries(self, target: float, settings: Settings) -> dict:
        """Report entries of a first solve that failed."""
        return {"tolerance": float(settings.tolerance)}

    def round_entries(self, kept: Kept, tries: list[Try], settings: Settings) -> dict:
        """Report entries of the solves at one set of nodes: the tolerance and ``solver_message`` at least."""
        return {"tolerance": float(settings.tolerance), "solver_message": self.summary(kept, tries)}

    def summary(self, kept: Kept, tries: list[Try]) -> str:
        """The solver's part of the result's message: what the kept solve did, and how many solves it took."""
        measured = [t for t in tries if t.check is not None]
        more = f", {len(measured)} {self.plural}" if len(measured) > 1 else ""
        return kept.attempt.outcome.summary + more

    def stalled(self, outcome: SolverOutcome) -> bool:
        """The outcome says this method cannot solve the problem, where another may (:class:`MethodChoice`)."""
        return False


@dataclass(frozen=True)
class MethodChoice:
    """The methods for a problem, in order, and why.

    The first solves; when one's first solve at a set of nodes :meth:`~Method.stalled`, the next one
    takes over (``method: auto`` only lists more than one), and the report says so.
    """

    methods: tuple
    reason: str

    def fallback(self, method: Method, outcome: SolverOutcome) -> Method | None:
        """The method to try after ``method`` stalled with ``outcome``, or None."""
        return self.after(method) if method.stalled(outcome) else None

    def after(self, method: Method) -> Method | None:
        """The method after ``method`` in the choice, or None."""
        later = self.methods[self.methods.index(method) + 1:]
        return later[0] if later else None

"""The one refinement loop of a solve: (solve -> check -> refine)* until the measured error meets the tolerance.

Each pass solves the problem at its current nodes to the method's own target and measures the codebook
against the independent reference (:mod:`pgdcli.driver.gate`). Then one of three things happens:

* the method tightens its target at the same nodes (:meth:`~pgdcli.driver.method.Method.next_target`: a
  smaller residual, a tighter march), at most :data:`CHECK_ATTEMPTS` solves per set of nodes;
* the automatic resolution refines the nodes (:meth:`pgdcli.adapt.Resolution.judge`) and the next pass
  starts from the target that met the tolerance at the nodes before (:class:`~pgdcli.algorithms.outcome.Learned`);
* the loop ends with a verdict: within the tolerance, not checked, or a refusal saying why.

A first solve that fails at a set of nodes ends the loop with the solver's outcome, unless it stopped
for lack of nodes along a coordinate the resolution may refine, or another method of the
:class:`~pgdcli.driver.method.MethodChoice` takes over.
"""

from __future__ import annotations

import dataclasses
import time as _time

from ..adapt import Resolution, total_nodes
from ..adapt.pilot import LINE_NODES, PILOT_NODES, first_nodes
from ..algorithms.outcome import Learned
from ..algorithms.result import SolveResult
from ..discretization.coefficients import CanonicalTermsError
from ..progress import PhaseStarted, emit
from . import gate
from .method import Kept, Method, MethodChoice, Settings, Try

__all__ = ["solve_rounds", "CHECK_ATTEMPTS", "POLYNOMIAL_TIME_NODES"]

#: Most solves at one set of nodes: the first and the tighter ones.
CHECK_ATTEMPTS = 3
#: Time nodes past which the enrichment (one polynomial in time over the interval, one mode at a time) hands
#: a problem over to the time march, when the choice has one: a solution that needs more holds a transient
#: or many oscillations, which the march steps through at less cost. (The tensor-train solver takes fine
#: time grids well: a driven system's 129 nodes.)
POLYNOMIAL_TIME_NODES = 65


def solve_rounds(problem, choice: MethodChoice, settings: Settings, callback=None,
                 learned: Learned = Learned()) -> tuple[SolveResult, Learned]:
    """Solve, measure, tighten or refine until the error meets the tolerance, or say why it cannot.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        Validated (:func:`pgdcli.driver.check_solvable`).
    choice : MethodChoice
    settings : Settings
    callback : callable, optional
        Receives every :class:`~pgdcli.progress.ProgressEvent`.
    learned : Learned
        What earlier solves of this problem taught (nothing by default).

    Returns
    -------
    result : SolveResult
        ``accurate`` True (within the tolerance), False (status ``INACCURATE``) or None (the
        reference could not check it); ``converged`` False with the solver's status when it failed.
    learned : Learned
        What these solves teach the next.
    """
    loop = _Loop(problem, choice, settings, callback, learned)
    while True:
        attempt = loop.solve()  # solve and check
        if loop.tighten():  # refine: a tighter target at the same nodes
            continue
        kept = loop.method.keep(loop.tries)
        if kept is None:  # the first solve at these nodes failed
            if loop.fall_back(attempt) or loop.more_nodes(attempt) or loop.march_instead(
                    "stopped: " + attempt.outcome.message.removeprefix("not converged: ")):
                continue
            return loop.failed(attempt), loop.learned
        if kept.stopped is not None and loop.fall_back(loop.tries[-1], kept.stopped):  # it could go no further
            continue
        result = loop.kept_result(kept)
        verdict = loop.judge(result, kept)  # refine: more nodes (None), or the verdict
        if verdict is None:  # more nodes: the polynomial in time may have grown past its use
            if loop.past_polynomial_time():
                loop.march_instead(f"would need more than {POLYNOMIAL_TIME_NODES} nodes in time (a transient or "
                                   f"many oscillations in one polynomial over the interval)")
            continue
        if verdict.accurate is False and loop.march_instead(f"missed the tolerance: {verdict.reason}"):
            continue
        solved = loop.method.summary(kept, loop.tries)
        finished = gate.finish(result, solved, loop.resolution, verdict, loop.started, loop.check_seconds)
        return finished, loop.learned


class _Loop:
    """The state of :func:`solve_rounds`: the method, the nodes, the solves at these nodes, what was learned."""

    def __init__(self, problem, choice: MethodChoice, settings: Settings, callback, learned: Learned):
        self.started = _time.perf_counter()
        self.choice, self.settings, self.callback, self.learned = choice, settings, callback, learned
        self.method: Method = choice.methods[0]
        self.original = problem
        self.resolution = Resolution(problem, self.method.marches)
        self.tries: list[Try] = []
        self.target = self.method.first_target(settings, learned)
        self.solves = 0
        self.fallbacks: list[str] = []
        self.check_seconds = 0.0  # the error gate's share of the build
        self.marched = None  # (method, target, nodes, outcome) of a pilot march that is the first round's solve
        if self.method.pilots:
            self.pilot()

    @property
    def problem(self):
        return self.resolution.problem

    def pilot(self) -> None:
        """The first round's automatic parameter nodes from the pilot's marches (:mod:`pgdcli.adapt.pilot`);
        what they teach (a stiff problem) is learned. A pilot of one parameter marched the whole grid at
        :data:`~pgdcli.adapt.pilot.PILOT_NODES` nodes: when those suffice, that march is the first round's."""
        marched = {}

        def march(problem, name):
            emit(self.callback, PhaseStarted("solve", f"pilot {self.method.name} along {name}: {PILOT_NODES} "
                                                      f"nodes, {LINE_NODES} along the others", 1))
            outcome = self.method.solve(problem, self.target, self.settings, self.learned, None)
            self.learned = self.learned.after(outcome)
            marched[name] = (problem, outcome)
            return outcome.codebook if outcome.converged else None

        nodes = first_nodes(self.problem, self.settings.tolerance, march)
        if len(marched) == 1 and all(n <= PILOT_NODES for n in nodes.values()) and nodes:
            (name, (problem, outcome)), = marched.items()
            nodes[name] = PILOT_NODES
            self.marched = (self.method, self.target, _node_key(problem), outcome)
        if nodes:
            self.resolution.start_at(nodes)
            emit(self.callback, PhaseStarted("refine", "first nodes from the pilot: " + ", ".join(
                f"{name} {n}" for name, n in nodes.items()), 1))

    def solve(self) -> Try:
        """One solve at the current nodes and target, measured when the method weighs it."""
        self.solves += 1
        method, problem = self.method, self.problem
        emit(self.callback, PhaseStarted("solve", f"{method.name} to {method.target_name} {self.target:.2g}, "
                                                  f"nodes {_nodes_text(problem)}", self.solves))
        try:
            outcome = self.marched_outcome(problem) or method.solve(problem, self.target, self.settings,
                                                                    self.learned, self.callback)
        except CanonicalTermsError as exc:  # a coefficient the enrichment cannot take: the next method may
            if not self.switch(self.choice.after(method), f"the {method.title} cannot take it ({exc})"):
                raise
            return self.solve()
        self.learned = self.learned.after(outcome)
        attempt = Try(self.target, outcome)
        if method.measures(outcome, self.tries):
            checking = _time.perf_counter()
            attempt.check, attempt.warnings = gate.measure(problem, outcome.codebook, self.settings, self.callback,
                                                           self.solves)
            self.check_seconds += _time.perf_counter() - checking
        self.tries.append(attempt)
        return attempt

    def marched_outcome(self, problem):
        """The pilot's march when it is this solve's (same method, nodes and target), once; else None."""
        if self.marched is None or self.marched[:3] != (self.method, self.target, _node_key(problem)):
            return None
        outcome, self.marched = self.marched[3], None
        return outcome

    def tighten(self) -> bool:
        """Another solve at these nodes to the method's tighter target, if it has one and the tries allow."""
        if len(self.tries) >= CHECK_ATTEMPTS:
            return False
        target = self.method.next_target(self.problem, self.tries, self.settings)
        if target is None:
            return False
        ratio = self.method.solver_ratio(self.tries[-1].check, self.problem)
        emit(self.callback, PhaseStarted("refine", f"the error at the nodes is {ratio:.3g} x the tolerance: "
                                                   f"{self.method.target_name} {target:.2g}", self.solves))
        self.target = target
        return True

    def failed(self, attempt: Try) -> SolveResult:
        """The result of a first solve that failed, its report completed by the method."""
        return gate.failed_result(attempt.outcome,
                                  self.entries(self.method.failure_entries(attempt.target, self.settings)))

    def kept_result(self, kept: Kept) -> SolveResult:
        """The result of the try kept at these nodes; what it met the tolerance with is learned."""
        if self.method.solver_ratio(kept.attempt.check, self.problem) <= 1.0:
            measured = [t for t in self.tries if t.check is not None]
            self.learned = dataclasses.replace(self.learned, target=measured[-1].target)
        entries = self.entries(self.method.round_entries(kept, self.tries, self.settings))
        if self.fallbacks:  # never hide the choice: a warning beside the report's method_reason
            kept.notes.append(f"{entries['method_fallback']} (solver.method: auto)")
        return gate.kept_result(kept, entries, self.settings)

    def judge(self, result: SolveResult, kept: Kept):
        """The resolution's verdict on ``result``, or None after it refined the nodes (solve again)."""
        before = self.problem
        verdict = self.resolution.judge(result.check, result.codebook, kept.stopped, kept.limited, self.method.title)
        if verdict is None:
            self.largest_polynomial_first(before)
            self.refined(before)
        return verdict

    def largest_polynomial_first(self, before) -> None:
        """Time nodes predicted past :data:`POLYNOMIAL_TIME_NODES` by a method that hands time over: its largest
        polynomial in time is tried first (the march takes over only when that misses the tolerance)."""
        time = self.problem.time
        if not self.method.hands_time_over or time is None:
            return
        if total_nodes(before.coordinate(time)) < POLYNOMIAL_TIME_NODES < total_nodes(self.problem.coordinate(time)):
            self.resolution.at_most(time, POLYNOMIAL_TIME_NODES)

    def restart(self) -> None:
        """Solves at new nodes (or by another method) start from what met the tolerance before."""
        self.tries = []
        self.target = self.method.first_target(self.settings, self.learned)

    def fall_back(self, attempt: Try, why: str | None = None) -> bool:
        """Another method of the choice takes over from one that stalled (the report says so)."""
        other = self.choice.fallback(self.method, attempt.outcome)
        why = why if why is not None else attempt.outcome.message.removeprefix("not converged: ")
        return self.switch(other, f"the {self.method.title} stopped: {why}")

    def switch(self, other, note: str) -> bool:
        """``other`` (a method or None) takes over; ``note`` says why, in the report and a warning."""
        if other is None:
            return False
        self.fallbacks.append(note)
        emit(self.callback, PhaseStarted("refine", f"{note}; the {other.title} runs instead", self.solves))
        self.method = other
        self.resolution.marches = other.marches
        self.learned = dataclasses.replace(self.learned, target=None)  # another solver's target means nothing here
        self.restart()
        return True

    def past_polynomial_time(self) -> bool:
        """The automatic time nodes of a method that hands time over (the enrichment) are past
        :data:`POLYNOMIAL_TIME_NODES`."""
        time = self.problem.time
        if not self.method.hands_time_over or time is None:
            return False
        c = self.problem.coordinate(time)
        return c.auto and total_nodes(c) > POLYNOMIAL_TIME_NODES

    def march_instead(self, why: str) -> bool:
        """A method of the choice that marches in time takes over from one that failed or missed the tolerance
        (its time a polynomial over the whole interval), at the problem's first nodes; ``why`` completes
        "the <method> ..." in the report."""
        time = self.original.time
        if self.method.marches or time is None or not self.original.coordinate(time).auto:
            return False  # time nodes the spec sets are the representation asked for (per slab in a march)
        later = self.choice.methods[self.choice.methods.index(self.method) + 1:]
        other = next((m for m in later if m.marches), None)
        if other is None or not self.switch(other, f"the {self.method.title} {why}"):
            return False
        self.resolution = Resolution(self.original, other.marches)
        if other.pilots:
            self.pilot()
        return True

    def more_nodes(self, attempt: Try) -> bool:
        """The solve stopped early for lack of nodes along a coordinate the resolution refines."""
        before = self.problem
        if not self.resolution.more_nodes_for(attempt.outcome.under_resolved):
            return False
        self.refined(before)
        return True

    def refined(self, before) -> None:
        changed = [f"{c.name} {total_nodes(c)} -> {total_nodes(self.problem.coordinate(c.name))}"
                   for c in before.coordinates if total_nodes(c) != total_nodes(self.problem.coordinate(c.name))]
        emit(self.callback, PhaseStarted("refine", "more nodes: " + ", ".join(changed), self.solves))
        self.restart()

    def entries(self, entries: dict) -> dict:
        """A round's report entries, with the method and why it ran (``solver.method``, or the fallback)."""
        if self.fallbacks:
            reason = "; ".join(self.fallbacks) + f"; the {self.method.title} ran instead"
            entries = {**entries, "method_fallback": reason}
        else:
            reason = self.choice.reason
        if self.method.names_itself:
            entries = {**entries, "method": self.method.name, "method_reason": reason}
        return entries


def _nodes_text(problem) -> str:
    return ", ".join(f"{c.name}: {total_nodes(c)}" for c in problem.coordinates)


def _node_key(problem) -> tuple:
    """What tells one grid of nodes from another: per coordinate, its nodes and breakpoints."""
    return tuple((c.name, c.nodes, tuple(getattr(c, "breakpoints", ()))) for c in problem.coordinates)

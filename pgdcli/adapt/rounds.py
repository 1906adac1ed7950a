"""The rounds of one problem's automatic resolution: its nodes, its refinements and its verdict.

:class:`Resolution` holds the nodes of the current round; after each solve and check,
:meth:`Resolution.judge` refines them (:func:`pgdcli.adapt.resolution.next_nodes`) or ends
with a :class:`Verdict`, a refusal's reason from :func:`pgdcli.adapt.refusal.refusal`.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from ..checks.resolution import chebyshev_decay
from .refusal import refusal
from .resolution import MAX_ROUNDS, initial_nodes, next_nodes, refined_nodes, total_nodes

__all__ = ["Resolution", "Verdict"]


@dataclass(frozen=True)
class Verdict:
    """The end of the automatic resolution: the measured error meets the tolerance (``accurate`` True), misses it
    (False, ``reason`` says where and what would reduce it) or could not be measured (None)."""

    accurate: bool | None
    reason: str


class Resolution:
    """The automatic resolution of one problem: its current nodes and the rounds so far.

    One round is the solves at one set of nodes; after each, :meth:`judge` either refines
    the automatic coordinates (the problem at the new nodes is :attr:`problem`) or ends
    with a :class:`Verdict`. It writes its own report entries (:meth:`report_entries`).
    """

    def __init__(self, problem, marches: bool):
        self.problem = initial_nodes(problem, marches)
        self.marches = marches  # the method's time nodes follow its steps: they are not refined here
        self.auto = [c.name for c in self.problem.coordinates if c.auto]
        self.rounds: list[list[float]] = []  # per round: the nodes of each coordinate, then the measured ratio
        self.history: dict = {}  # per coordinate: its refinements (Refinement)
        self.pilot: dict[str, int] = {}  # the first round's nodes chosen by a pilot (start_at)

    def _record(self, ratio: float) -> None:
        self.rounds.append([total_nodes(c) for c in self.problem.coordinates] + [ratio])

    def start_at(self, nodes: dict[str, int]) -> None:
        """The first round at ``nodes`` (coordinate -> nodes) on those automatic coordinates, within
        ``solver.max_nodes``; before any round."""
        cap = self.problem.solver.max_nodes
        coords = tuple(dataclasses.replace(c, nodes=min(int(nodes[c.name]), cap)) if c.name in nodes and c.auto
                       else c for c in self.problem.coordinates)
        self.problem = dataclasses.replace(self.problem, coordinates=coords)
        self.pilot = {c.name: c.nodes for c in coords if c.name in nodes and c.auto}

    def more_nodes_for(self, lacking: str | None) -> bool:
        """A solve stopped early for lack of nodes along ``lacking``: refine it, if the rounds and the cap allow."""
        if not lacking or len(self.rounds) >= MAX_ROUNDS - 1:
            return False
        refined = refined_nodes(self.problem, [lacking])
        if total_nodes(refined.coordinate(lacking)) <= total_nodes(self.problem.coordinate(lacking)):
            return False
        self._record(float("inf"))  # stopped early
        self.problem = refined
        return True

    def at_most(self, name: str, nodes: int) -> None:
        """At most ``nodes`` nodes on coordinate ``name`` from now on (no fewer than it had)."""
        coords = tuple(dataclasses.replace(c, nodes=min(c.nodes, nodes)) if c.name == name else c
                       for c in self.problem.coordinates)
        self.problem = dataclasses.replace(self.problem, coordinates=coords)

    def judge(self, check, codebook, stopped: str | None = None, limited: bool = False,
              solver: str = "enrichment") -> Verdict | None:
        """The verdict on a round's codebook, or None when automatic coordinates were refined (solve again).

        ``stopped``: the solver could not lower its own error at the nodes further (why); ``limited``:
        that error did not fall with the solver's target (the time and space discretization);
        ``solver``: what the refusal calls the method ("enrichment", "tensor-train solver").
        """
        this_round = len(self.rounds)
        self._record(check.ratio)
        if not check.checked:
            return Verdict(None, "not checked")
        if check.passed:
            return Verdict(True, "the measured error meets the tolerance")
        # a solver stopped short of the target the nodes ask for: its error at the nodes is not the
        # discretization's, and only the coordinates that lack nodes between them are refined
        stopping = bool(stopped) and check.node_ratio > 1.0
        decay = chebyshev_decay(codebook)
        refined, refine, stuck = next_nodes(self.problem, check, decay, self.history,
                                            march=self.marches, limited=limited, stopping=stopping)
        pending = False
        if refine:
            if stuck != refine and this_round < MAX_ROUNDS - 1:
                self.problem = refined
                return None
            pending = stuck != refine  # a refinement was chosen that the rounds left no solve for
        reason = refusal(self.problem, check, self.marches, stopped, limited, solver, self.history, decay)
        return Verdict(False, f"still refining after {MAX_ROUNDS} solves: {reason}" if pending else reason)

    def report_entries(self, reason: str) -> dict:
        """The codebook report's ``resolution_*`` entries: rounds, automatic coordinates, elements, reason."""
        coords = self.problem.coordinates
        return {
            "resolution_rounds": np.array(self.rounds, dtype=float),  # (rounds, coordinates + 1): nodes, ratio
            "resolution_auto": ",".join(c.name for c in coords if c.auto),
            "resolution_elements": ",".join(f"{c.name}:{len(c.breakpoints) - 1}" for c in coords
                                            if len(c.breakpoints) > 2),
            "resolution_reason": reason,
            **({"resolution_pilot": ",".join(f"{k}:{v}" for k, v in self.pilot.items())} if self.pilot else {}),
        }


"""The automatic resolution: which coordinates get more nodes after a measured error, and why a refusal.

A tolerance is a promise about the codebook, not about the solver: every solve is
followed by a measurement of its error against an independent reference
(:mod:`pgdcli.checks.check`). The driver's refinement loop (:mod:`pgdcli.driver.refinement`)
first lowers the solver's own error at the nodes (a tighter march, a smaller residual);
:class:`Resolution` then turns the measurement of the codebook it kept into a decision:

* the error within the tolerance (``ratio <= 1``): done;
* too large at points off the nodes of a coordinate whose nodes the solver chooses
  (``nodes: auto`` or no ``nodes:``): that coordinate gets more nodes (n -> 2n - 1,
  which keeps Chebyshev-Lobatto nodes nested) or, for a parameter whose error does
  not fall geometrically with its nodes, more elements where the error is
  (hp-refinement), and the problem is solved again, up to ``solver.max_nodes`` nodes
  in all per coordinate;
* otherwise a refusal (:func:`refusal`): one clause saying how large the error is, where,
  and which coordinate lacks resolution; the driver marks the result inaccurate
  (status :data:`INACCURATE`), and the CLI writes nothing then (exit 1) unless asked to keep it.

The report records the nodes tried per coordinate, the measured ratio of each
round, and why the last round ended (:meth:`Resolution.report_entries`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

from .algorithms.outcome import Status
from .checks.resolution import chebyshev_decay

__all__ = ["INACCURATE", "MAX_ROUNDS", "REFINE_AT", "Resolution", "Verdict", "refusal", "refined_nodes",
           "initial_nodes", "total_nodes", "split_elements"]

#: SolveResult.status of a codebook whose measured error exceeds its tolerance.
INACCURATE = Status.INACCURATE
#: Most solves of one problem by the automatic resolution.
MAX_ROUNDS = 8
#: Nodes per element beyond which a parameter coordinate is split into elements instead.
MAX_ELEMENT_NODES = 65
#: A doubling of a coordinate's nodes that cuts its off-node error less than this does not converge
#: geometrically (a sharp feature): the coordinate is split into elements where the error is instead.
P_GAIN = 8.0
#: A coordinate is refined when its off-node error ratio exceeds this share of the tolerance: the
#: other parts of the error (the solver's, the other coordinates') need room too.
REFINE_AT = 0.5
#: First node counts of automatic coordinates by role (the spec's default, 9, for parameters): an
#: enrichment's time coordinate is one polynomial over the whole interval; space coordinates carry
#: boundary layers. The march's time nodes are per step (9 >= 8 reproduces its dense output).
FIRST_NODES = {"time": 33, "space": 17}


def initial_nodes(problem, march: bool):
    """The problem with its automatic coordinates at their first node counts."""
    coords = []
    for c in problem.coordinates:
        if c.auto and c.role in FIRST_NODES and not (march and c.role == "time"):
            first = FIRST_NODES[c.role] if c.discretization == "chebyshev" else 2 * FIRST_NODES[c.role] - 1
            c = dataclasses.replace(c, nodes=min(first, problem.solver.max_nodes))
        coords.append(c)
    return dataclasses.replace(problem, coordinates=tuple(coords))


def total_nodes(c) -> int:
    """Nodes of a spec coordinate in all (``nodes`` is per element when it has elements)."""
    elements = max(1, len(c.breakpoints) - 1)
    return elements * (c.nodes - 1) + 1


def refined_nodes(problem, names, at_least: int = 0):
    """The problem with ``n -> max(2n - 1, at_least)`` nodes (per element) on the named coordinates,
    within ``max_nodes`` in all."""
    cap = problem.solver.max_nodes
    coords = []
    for c in problem.coordinates:
        if c.name in names:
            elements = max(1, len(c.breakpoints) - 1)
            most = (cap - 1) // elements + 1  # nodes per element that keep the total within the cap
            c = dataclasses.replace(c, nodes=max(c.nodes, min(max(2 * c.nodes - 1, at_least), most)))
        coords.append(c)
    return dataclasses.replace(problem, coordinates=tuple(coords))


def _predicted_nodes(c, ratio: float, past: list) -> int:
    """Nodes at which the error ratio falls to a quarter, from its geometric decay over the last doubling.

    Chebyshev interpolation of an analytic function converges like rho**-n: two
    measurements give rho, and the count that reaches the target in one more solve
    instead of several doublings (0 without a previous doubling to measure it by).
    """
    if not past or past[-1][0] != "p" or not ratio > 0.25:
        return 0
    _, before, n_before = past[-1]
    if not before > ratio or c.nodes <= n_before:
        return 0
    return _nodes_to_a_quarter(c.nodes, ratio, np.log(before / ratio) / (c.nodes - n_before))


def _nodes_to_a_quarter(nodes: int, ratio: float, per_node: float) -> int:
    """Nodes at which an error ratio falling by ``exp(per_node)`` per node reaches a quarter."""
    return int(np.ceil(nodes + np.log(ratio / 0.25) / per_node))


#: Slowest decay of the Chebyshev coefficients (per node, natural log) that a first prediction trusts:
#: slower spectra (a sharp feature, or the pre-asymptotic start of one) are doubled and measured.
MIN_DECAY = np.log(1.2)


def _doublings(before: int, after: int) -> float:
    """How many doublings of the node intervals lead from ``before`` to ``after`` nodes (at least 1)."""
    return max(1.0, float(np.log2(max(after - 1, 1) / max(before - 1, 1))))


def _spectral_nodes(c, ratio: float, decay: float | None) -> int:
    """Nodes at which the error ratio falls to a quarter, from the decay of the coefficients of one solve.

    The first refinement of a coordinate has no earlier doubling to measure the
    convergence by (:func:`_predicted_nodes`); the Chebyshev spectrum of the
    codebook along the coordinate gives the rate instead
    (:func:`pgdcli.checks.resolution.chebyshev_decay`). It is trusted only up to
    :data:`MAX_ELEMENT_NODES` (beyond, the feature may be sharp: doubling and
    measuring the gain decides between nodes and elements, as before: 0), and
    gives at most two doublings at once, so that a pre-asymptotic spectrum cannot
    ask for an oversized grid.
    """
    if decay is None or not decay >= MIN_DECAY or not ratio > 0.25:
        return 0
    predicted = _nodes_to_a_quarter(c.nodes, ratio, decay)
    return 0 if predicted > MAX_ELEMENT_NODES else min(predicted, 4 * c.nodes - 3)


def split_elements(problem, name: str, where: np.ndarray):
    """The problem with every element of ``name`` that holds a point of ``where`` cut in two."""
    c = problem.coordinate(name)
    bp = np.asarray(c.breakpoints or c.domain, dtype=float)
    hit = np.unique(np.clip(np.searchsorted(bp, where, side="right") - 1, 0, bp.size - 2))
    mids = 0.5 * (bp[hit] + bp[hit + 1])
    new = tuple(float(v) for v in np.sort(np.concatenate([bp, mids])))
    coords = tuple(dataclasses.replace(c, breakpoints=new) if c.name == name else c for c in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)


def _refine(problem, check, names, history, decay=None):
    """More nodes (p) or more elements where the error is (h) for each named coordinate.

    A Chebyshev parameter goes on adding nodes while a doubling cuts its off-node
    error :data:`P_GAIN`-fold or more (geometric convergence: the next count is
    predicted from that rate, at least double) and the count stays within
    :data:`MAX_ELEMENT_NODES` per element; otherwise the feature is sharp, and the
    elements holding off-node points with too large an error are cut in two
    (chebfun's splitting, by the measured error instead of the tail).
    ``decay`` (coordinate -> log rho of its Chebyshev spectrum) predicts the first
    p-refinement of a coordinate. Returns the refined problem and the coordinates
    that could not be refined.
    """
    cap = problem.solver.max_nodes
    decay = decay or {}
    stuck = []
    for name in names:
        c = problem.coordinate(name)
        ratio = check.coordinate_ratio.get(name, 0.0)
        past = history.setdefault(name, [])
        # P_GAIN per doubling of the nodes (a predicted jump can span several)
        slow = bool(past) and past[-1][0] == "p" and past[-1][1] < P_GAIN ** _doublings(past[-1][2], c.nodes) * ratio
        predicted = _predicted_nodes(c, ratio, past) or (0 if past else _spectral_nodes(c, ratio, decay.get(name)))
        h_able = c.role == "parameter" and c.discretization == "chebyshev" and name in check.line_points
        if h_able and (slow or max(c.nodes, predicted) > MAX_ELEMENT_NODES):
            x, r = check.line_points[name]
            # the elements where the error is; at least the worst one (a coordinate flagged by its tail)
            candidate = split_elements(problem, name, x[r >= min(REFINE_AT, r.max(initial=0.0))])
            if total_nodes(candidate.coordinate(name)) <= cap:
                problem = candidate
                past.append(("h", ratio, c.nodes))
                continue
        if total_nodes(c) < cap and not (h_able and slow and c.nodes >= MAX_ELEMENT_NODES):
            problem = refined_nodes(problem, [name], predicted)
            past.append(("p", ratio, c.nodes))
            continue
        stuck.append(name)
    return problem, stuck


def _lacks_nodes(check, name: str) -> bool:
    """The coordinate's interpolation error is a large part of the tolerance.

    Measured off its nodes, that error counts when it is not just the solver's
    error at the nodes seen again (it must be twice the node ratio); the Chebyshev
    tail is the estimate where no such sample exists (space coordinates) or where
    the solver's error at the nodes is the coordinate's discretization error
    (an enrichment's time coordinate).
    """
    off = check.coordinate_ratio.get(name, 0.0)
    return (off > REFINE_AT and off > 2.0 * check.node_ratio) or check.tail_ratio.get(name, 0.0) > REFINE_AT


def _to_refine(problem, check, march: bool, discretization_limited=False) -> tuple[list[str], list[str]]:
    """Coordinates that lack nodes: (automatic ones below the cap, the others)."""
    refine, stuck = [], []
    # an enrichment whose error at the nodes did not fall with its residual: the time and space
    # discretization, which only more nodes there reduce
    limited = bool(discretization_limited) and check.node_ratio > 1.0
    for c in problem.coordinates:
        if march and c.role == "time":
            continue  # the march's time nodes follow its steps
        if not (_lacks_nodes(check, c.name) or (limited and c.role in ("time", "space"))):
            continue
        if c.auto and total_nodes(c) < problem.solver.max_nodes:
            refine.append(c.name)
        else:
            stuck.append(c.name)
    return refine, stuck


def _largest_off_node(problem, check, march: bool) -> list[str]:
    """The automatic coordinates with the largest off-node errors, when none is too large alone.

    The parts of the error add up: the solver's at the nodes and each coordinate's
    interpolation, each within the tolerance alone and not together. The coordinates
    with at least half the largest off-node ratio are refined.
    """
    ratios = {c.name: check.coordinate_ratio.get(c.name, 0.0) for c in problem.coordinates
              if c.auto and total_nodes(c) < problem.solver.max_nodes and not (march and c.role == "time")}
    if not ratios:
        return []
    top = max(ratios.values())
    return [n for n, r in ratios.items() if r > 0 and r >= 0.5 * top]


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
        self.history: dict = {}  # per coordinate: its refinements, ("p" or "h", ratio, nodes before)

    def _record(self, ratio: float) -> None:
        self.rounds.append([total_nodes(c) for c in self.problem.coordinates] + [ratio])

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
        refine, stuck = _to_refine(self.problem, check, self.marches, limited)
        if not refine and not stuck and not stopping:
            refine = _largest_off_node(self.problem, check, self.marches)
        pending = False
        if refine:
            refined, stuck = _refine(self.problem, check, refine, self.history, chebyshev_decay(codebook))
            if stuck != refine and this_round < MAX_ROUNDS - 1:
                self.problem = refined
                return None
            pending = stuck != refine  # a refinement was chosen that the rounds left no solve for
        reason = refusal(self.problem, check, self.marches, stopped, limited, solver)
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
        }


def refusal(problem, check, marches: bool, stopped: str | None = None, limited: bool = False,
            solver: str = "enrichment") -> str:
    """Why the error is too large and what would reduce it, in one clause.

    ``stopped`` and ``limited`` as :meth:`Resolution.judge`'s.
    """
    stopped = stopped if check.node_ratio > 1.0 else None
    refine, stuck = _to_refine(problem, check, marches, limited)
    names = refine + stuck
    if stopped and not any(_lacks_nodes(check, n) for n in names):
        return (f"the error at the nodes is {check.node_ratio:.2g} x the tolerance and the {solver} could not "
                f"lower its residual further: {stopped}")
    if names:
        def share(n):
            return max(check.coordinate_ratio.get(n, 0.0), check.tail_ratio.get(n, 0.0))

        worst = max(names, key=share)
        c = problem.coordinate(worst)
        ratio = share(worst)
        measured = check.coordinate_ratio.get(worst, 0.0) >= check.tail_ratio.get(worst, 0.0)
        # the larger of the two says it: the error measured off the coordinate's nodes, or the estimate
        # from its Chebyshev tail (the tail can exceed what was measured many times over)
        seen = "error between its nodes" if measured else "its Chebyshev tail estimates an error between its nodes of"
        if c.auto and total_nodes(c) >= problem.solver.max_nodes:
            need = f"it reached solver.max_nodes = {problem.solver.max_nodes}"
        elif c.auto:
            need = f"it has {total_nodes(c)} nodes"
        else:
            need = f"it has nodes: {c.nodes}; add nodes or write 'nodes: auto'"
        if ratio > REFINE_AT:
            return (f"coordinate {worst!r} lacks resolution ({seen} {ratio:.2g} x the tolerance; "
                    f"{need})")
        return (f"the error at the nodes did not fall with the residual: coordinate {worst!r} may lack resolution "
                f"({need})")
    if check.method.startswith("method of lines"):
        # the method-of-lines reference's own error, not the codebook's, can be what is measured
        return ("the error did not fall with the residual nor with nodes; note that the method-of-lines "
                "reference of problems with space coordinates is itself accurate to about 1e-9, so a tighter "
                "tolerance cannot be checked (--keep-inaccurate keeps the codebook)")
    if check.node_ratio > 1.0:
        what = "march" if marches else solver
        return f"the {what} did not reach the tolerance at the nodes ({check.node_ratio:.2g} x the tolerance)"
    return "the error between the nodes exceeds the tolerance, in no one coordinate alone"

"""The automatic resolution: which coordinates get more nodes after a measured error, and why a refusal.

A tolerance is a promise about the codebook, not about the solver: every solve is
followed by a measurement of its error against an independent reference
(:mod:`pgdcli.checks.check`). The driver's refinement loop (:mod:`pgdcli.driver.refinement`)
first lowers the solver's own error at the nodes (a tighter march, a smaller residual);
:class:`Resolution` then turns the measurement of the codebook it kept into a decision:

* the error within the tolerance (``ratio <= 1``): done;
* too large along a coordinate whose nodes the solver chooses (``nodes: auto`` or no
  ``nodes:``), by the error measured off its nodes or, where the check measures the
  error as a whole (space coordinates), by its Chebyshev tail: that coordinate, and
  only it, gets the nodes at which the geometric decay of its error (measured over
  its last refinement, or read from its Chebyshev spectrum) brings the error to its
  share of the tolerance (n -> 2n - 1 without a rate to go by) or, for a parameter
  whose error does not fall geometrically with its nodes, more elements where the
  error is (hp-refinement), and the problem is solved again, up to
  ``solver.max_nodes`` nodes in all per coordinate;
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
from .checks.resolution import chebyshev_decay, error_estimates, nodes_for_decay

__all__ = ["INACCURATE", "MAX_ROUNDS", "REFINE_AT", "Resolution", "Verdict", "refusal", "refined_nodes",
           "initial_nodes", "total_nodes", "split_elements", "next_nodes"]

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
#: The share of the tolerance a refined coordinate's predicted error is brought to: the other parts of the
#: error, and a prediction a little short (another whole solve), need the rest.
TARGET = 0.1
#: The share of the tolerance the coordinates refined at once are brought to together (each to at most
#: :data:`TARGET`): their errors can add up at one point.
ROOM = 0.25
#: Of the time and space coordinates of a discretization-limited solve, those whose Chebyshev tail is below
#: this share of the tolerance are left as they are: more nodes there would not lower the error.
LIMITED_TAIL = 0.05
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


def refined_nodes(problem, names, to: int = 0):
    """The problem with ``to`` nodes (per element) on the named coordinates, ``n -> 2n - 1`` when 0 (a
    doubling of the intervals, which keeps Chebyshev-Lobatto nodes nested), within ``max_nodes`` in all."""
    cap = problem.solver.max_nodes
    coords = []
    for c in problem.coordinates:
        if c.name in names:
            elements = max(1, len(c.breakpoints) - 1)
            most = (cap - 1) // elements + 1  # nodes per element that keep the total within the cap
            c = dataclasses.replace(c, nodes=max(c.nodes, min(to or 2 * c.nodes - 1, most)))
        coords.append(c)
    return dataclasses.replace(problem, coordinates=tuple(coords))


def _predicted_nodes(c, ratio: float, past: list, target: float = TARGET) -> int:
    """Nodes at which the error ratio falls to ``target``, from its geometric decay over the last refinement.

    Chebyshev interpolation of an analytic function converges like rho**-n: two
    measurements give rho, and the count that reaches the target in one more solve
    instead of several doublings (0 without a previous refinement to measure it by).
    """
    if not past or past[-1][0] != "p" or not ratio > target:
        return 0
    _, before, n_before = past[-1]
    if not before > ratio or c.nodes <= n_before:
        return 0
    # at most two doublings at once: a rate measured over a pre-asymptotic step can be far too slow
    return min(nodes_for_decay(c.nodes, ratio / target, np.log(before / ratio) / (c.nodes - n_before)), 4 * c.nodes - 3)


#: Slowest decay of the Chebyshev coefficients (per node, natural log) that a first prediction trusts:
#: slower spectra (a sharp feature, or the pre-asymptotic start of one) are doubled and measured.
MIN_DECAY = np.log(1.2)


def _doublings(before: int, after: int) -> float:
    """How many doublings of the node intervals lead from ``before`` to ``after`` nodes (a fraction for a
    smaller step, at least a half)."""
    return max(0.5, float(np.log2(max(after - 1, 1) / max(before - 1, 1))))


def _spectral_nodes(c, ratio: float, decay: float | None, target: float = TARGET) -> int:
    """Nodes at which the error ratio falls to ``target``, from the decay of the coefficients of one solve.

    The first refinement of a coordinate has no earlier one to measure the
    convergence by (:func:`_predicted_nodes`); the Chebyshev spectrum of the
    codebook along the coordinate gives the rate instead
    (:func:`pgdcli.checks.resolution.chebyshev_decay`). For a parameter that may
    be split into elements it is trusted only up to :data:`MAX_ELEMENT_NODES`
    (beyond, the feature may be sharp: doubling and measuring the gain decides
    between nodes and elements, as before: 0); it gives at most two doublings at
    once, so that a pre-asymptotic spectrum cannot ask for an oversized grid.
    """
    if decay is None or not decay >= MIN_DECAY or not ratio > target:
        return 0
    predicted = nodes_for_decay(c.nodes, ratio / target, decay)
    if predicted > MAX_ELEMENT_NODES and _h_able(c):
        return 0
    return min(predicted, 4 * c.nodes - 3)


def _h_able(c) -> bool:
    """A coordinate that may be split into elements (a Chebyshev parameter)."""
    return c.role == "parameter" and c.discretization == "chebyshev"


def split_elements(problem, name: str, where: np.ndarray):
    """The problem with every element of ``name`` that holds a point of ``where`` cut in two."""
    c = problem.coordinate(name)
    bp = np.asarray(c.breakpoints or c.domain, dtype=float)
    hit = np.unique(np.clip(np.searchsorted(bp, where, side="right") - 1, 0, bp.size - 2))
    mids = 0.5 * (bp[hit] + bp[hit + 1])
    new = tuple(float(v) for v in np.sort(np.concatenate([bp, mids])))
    coords = tuple(dataclasses.replace(c, breakpoints=new) if c.name == name else c for c in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)


def _refine(problem, check, names, history, decay=None, estimates=None):
    """More nodes (p) or more elements where the error is (h) for each named coordinate.

    A coordinate gets the nodes at which its estimated error (``estimates``: ratio to
    the tolerance, :func:`pgdcli.checks.resolution.error_estimates`; the off-node ratio by default) falls to its
    share of the tolerance (:data:`TARGET`, or :data:`ROOM` shared by the coordinates
    refined at once), predicted from the geometric decay of that error over its last
    refinement or, at the first, from ``decay`` (coordinate -> log rho of its Chebyshev
    spectrum); without either, its node intervals double. A Chebyshev parameter goes
    on adding nodes while a doubling cuts its off-node error :data:`P_GAIN`-fold or
    more (geometric convergence) and the count stays within :data:`MAX_ELEMENT_NODES`
    per element; otherwise the feature is sharp, and the elements holding off-node
    points with too large an error are cut in two (chebfun's splitting, by the
    measured error instead of the tail). Returns the refined problem and the
    coordinates that could not be refined.
    """
    cap = problem.solver.max_nodes
    decay = decay or {}
    estimates = estimates if estimates is not None else {n: check.coordinate_ratio.get(n, 0.0) for n in names}
    target = min(TARGET, ROOM / max(1, len(names)))
    stuck = []
    for name in names:
        c = problem.coordinate(name)
        ratio = estimates.get(name, 0.0)
        past = history.setdefault(name, [])
        # P_GAIN per doubling of the nodes (a predicted step can span more or fewer)
        slow = bool(past) and past[-1][0] == "p" and past[-1][1] < P_GAIN ** _doublings(past[-1][2], c.nodes) * ratio
        predicted = (_predicted_nodes(c, ratio, past, target)
                     or (0 if past else _spectral_nodes(c, ratio, decay.get(name), target)))
        h_able = _h_able(c) and name in check.line_points
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


def _has_tail(c) -> bool:
    """The coordinate's nodes give it a tail indicator (:func:`pgdcli.checks.resolution.resolution_tails`)."""
    if c.breakpoints and len(c.breakpoints) > 2:
        return False
    return c.nodes >= (4 if c.discretization == "chebyshev" else 3)


def _to_refine(problem, check, march: bool, discretization_limited=False) -> tuple[list[str], list[str]]:
    """Coordinates that lack nodes: (automatic ones below the cap, the others).

    An error at the nodes that did not fall with the solver's residual
    (``discretization_limited``) is the time and space discretization's, which only
    more nodes there reduce: of those coordinates, the ones whose tail is at least
    :data:`LIMITED_TAIL` of the tolerance (or that have no tail) are refined. When no
    coordinate at all shows a lack of nodes, the ones with the largest tails are
    (:func:`_largest_tails`: a parameter's error off its nodes is in the error the
    check of a PDE measures as a whole), or else all of time and space.
    """
    limited = bool(discretization_limited) and check.node_ratio > 1.0
    candidates = [c for c in problem.coordinates if not (march and c.role == "time")]  # the march's follow its steps
    discretization = [c for c in candidates if limited and c.role in ("time", "space")]
    chosen = {c.name for c in candidates if _lacks_nodes(check, c.name)}
    chosen |= {c.name for c in discretization if not _has_tail(c) or check.tail_ratio.get(c.name, 0.0) > LIMITED_TAIL}
    if not chosen and limited:
        # the tails say where the error between the nodes is, if anywhere (a parameter's, off its nodes)
        chosen = set(_largest_tails(check, candidates)) or {c.name for c in discretization}
    refine, stuck = [], []
    for c in candidates:
        if c.name not in chosen:
            continue
        if c.auto and total_nodes(c) < problem.solver.max_nodes:
            refine.append(c.name)
        else:
            stuck.append(c.name)
    return refine, stuck


def _largest_tails(check, coordinates) -> list[str]:
    """Of ``coordinates``, those whose Chebyshev tail is at least half the largest, when that is at least
    :data:`LIMITED_TAIL` of the tolerance: where the error between the nodes is likeliest, when neither the
    tails nor the measured errors show a lack of nodes alone."""
    tails = {c.name: check.tail_ratio.get(c.name, 0.0) for c in coordinates}
    top = max(tails.values(), default=0.0)
    return [n for n, r in tails.items() if r >= 0.5 * top] if top > LIMITED_TAIL else []


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


def next_nodes(problem, check, decay: dict, history: dict, *, march: bool = False, limited: bool = False,
               stopping: bool = False):
    """The nodes of the next round after a measured error ``check`` that misses the tolerance.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        At the nodes that were measured.
    check : pgdcli.checks.check.CheckResult
    decay : dict of str to float
        Per coordinate, its :func:`~pgdcli.checks.resolution.chebyshev_decay`.
    history : dict
        Per coordinate, its refinements so far (updated here): ``("p" or "h", ratio, nodes before)``.
    march, limited, stopping : bool
        The time nodes follow the method's steps (not refined here); the solver's error at the nodes did
        not fall with its target (the time and space discretization); the solver stopped short of its
        target (only coordinates that lack nodes are refined).

    Returns
    -------
    refined : Problem
        The problem at its new nodes.
    chosen : list of str
        The automatic coordinates chosen for refinement (those that lack nodes, or else the ones with the
        largest off-node errors or Chebyshev tails).
    stuck : list of str
        Those of ``chosen`` that could not be refined (at ``solver.max_nodes``).
    """
    chosen, stuck = _to_refine(problem, check, march, limited)
    if not chosen and not stuck and not stopping:
        automatic = [c for c in problem.coordinates if c.auto and total_nodes(c) < problem.solver.max_nodes
                     and not (march and c.role == "time")]
        chosen = _largest_off_node(problem, check, march) or _largest_tails(check, automatic)
    if not chosen:
        return problem, [], []
    refined, stuck = _refine(problem, check, chosen, history, decay, error_estimates(check, chosen))
    return refined, chosen, stuck


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
        refined, refine, stuck = next_nodes(self.problem, check, chebyshev_decay(codebook), self.history,
                                            march=self.marches, limited=limited, stopping=stopping)
        pending = False
        if refine:
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

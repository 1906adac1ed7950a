"""Which coordinates get more nodes after a measured error, and how many (the decision of one round).

:func:`next_nodes` turns the measurement of a round's codebook into the nodes of the next:
p-refinement by the measured or spectral decay of a coordinate's error, hp-refinement
(elements cut where the error is) for a parameter whose error does not fall geometrically.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ..algorithms.outcome import Status
from ..checks.resolution import error_estimates, nodes_for_decay
from .grading import error_end, graded_elements

__all__ = ["INACCURATE", "MAX_ROUNDS", "REFINE_AT", "TARGET", "ROOM", "P_GAIN", "MIN_DECAY", "refined_nodes",
           "initial_nodes", "total_nodes", "has_room", "split_elements", "next_nodes", "lacks_nodes", "to_refine",
           "doublings", "Refinement"]

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


class Refinement(NamedTuple):
    """One refinement of a coordinate, as it stood before: how (``"p"`` nodes, ``"h"`` elements cut in two,
    ``"g"`` an end element graded), its error ratio, its nodes per element and in all, and the end of the box
    its worst off-node error lay near (-1 low, 1 high, 0 neither: :func:`pgdcli.adapt.grading.error_end`)."""

    kind: str
    ratio: float
    nodes: int
    total: int
    end: int = 0


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


def has_room(c, cap: int) -> bool:
    """More nodes fit within ``cap`` on coordinate ``c``: a node more per element, or (a parameter that may
    be split) one element more."""
    elements = max(1, len(c.breakpoints) - 1)
    return (cap - 1) // elements + 1 > c.nodes or (_h_able(c) and total_nodes(c) + c.nodes - 1 <= cap)


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
    before, n_before = past[-1][1], past[-1][2]
    if not before > ratio or c.nodes <= n_before:
        return 0
    # at most two doublings at once: a rate measured over a pre-asymptotic step can be far too slow
    return min(nodes_for_decay(c.nodes, ratio / target, np.log(before / ratio) / (c.nodes - n_before)), 4 * c.nodes - 3)


#: Slowest decay of the Chebyshev coefficients (per node, natural log) that a first prediction trusts:
#: slower spectra (a sharp feature, or the pre-asymptotic start of one) are doubled and measured.
MIN_DECAY = np.log(1.2)


def doublings(before: int, after: int) -> float:
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
        slow = bool(past) and past[-1][0] == "p" and past[-1][1] < P_GAIN ** doublings(past[-1][2], c.nodes) * ratio
        predicted = (_predicted_nodes(c, ratio, past, target)
                     or (0 if past else _spectral_nodes(c, ratio, decay.get(name), target)))
        h_able = _h_able(c) and name in check.line_points
        end = error_end(c, *check.line_points[name]) if h_able else 0
        if h_able and (slow or max(c.nodes, predicted) > MAX_ELEMENT_NODES):
            candidate, kind = _cut(problem, name, check.line_points[name], end if past and past[-1].end == end else 0)
            if total_nodes(candidate.coordinate(name)) <= cap:
                problem = candidate
                past.append(Refinement(kind, ratio, c.nodes, total_nodes(c), end))
                continue
        refined = refined_nodes(problem, [name], predicted)  # nothing more within the cap: stuck
        grows = total_nodes(refined.coordinate(name)) > total_nodes(c)
        if grows and not (h_able and slow and c.nodes >= MAX_ELEMENT_NODES):
            problem = refined
            past.append(Refinement("p", ratio, c.nodes, total_nodes(c), end))
            continue
        stuck.append(name)
    return problem, stuck


def _cut(problem, name: str, line: tuple, end: int):
    """The elements of ``name`` cut where the error is (``"h"``), or its element at ``end`` graded toward it
    (``"g"``: the error peaked near that end of the box this round and the last), if that fits the cap."""
    x, r = line
    if end:
        graded = graded_elements(problem, name, end, x, r)
        if total_nodes(graded.coordinate(name)) <= problem.solver.max_nodes:
            return graded, "g"
    # the elements where the error is; at least the worst one (a coordinate flagged by its tail)
    return split_elements(problem, name, x[r >= min(REFINE_AT, r.max(initial=0.0))]), "h"


def lacks_nodes(check, name: str) -> bool:
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


def to_refine(problem, check, march: bool, discretization_limited=False) -> tuple[list[str], list[str]]:
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
    chosen = {c.name for c in candidates if lacks_nodes(check, c.name)}
    chosen |= {c.name for c in discretization if not _has_tail(c) or check.tail_ratio.get(c.name, 0.0) > LIMITED_TAIL}
    if not chosen and limited:
        # the tails say where the error between the nodes is, if anywhere (a parameter's, off its nodes)
        chosen = set(_largest_tails(check, candidates)) or {c.name for c in discretization}
    refine, stuck = [], []
    for c in candidates:
        if c.name not in chosen:
            continue
        if c.auto and has_room(c, problem.solver.max_nodes):
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
              if c.auto and has_room(c, problem.solver.max_nodes) and not (march and c.role == "time")}
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
        Per coordinate, its refinements so far (updated here): a list of :class:`Refinement`.
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
    chosen, stuck = to_refine(problem, check, march, limited)
    if not chosen and not stuck and not stopping:
        automatic = [c for c in problem.coordinates if c.auto and has_room(c, problem.solver.max_nodes)
                     and not (march and c.role == "time")]
        chosen = _largest_off_node(problem, check, march) or _largest_tails(check, automatic)
    if not chosen:
        return problem, [], []
    refined, stuck = _refine(problem, check, chosen, history, decay, error_estimates(check, chosen))
    return refined, chosen, stuck

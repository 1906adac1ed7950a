"""Why a codebook misses its tolerance, and what would meet it: the refusal's one clause.

A refusal gives advice only where following it is predicted to work. A coordinate
that reached ``solver.max_nodes`` is told the cap that would meet the tolerance when
its measured error was still falling, predicted from the measured rate
(:func:`cap_advice`): geometric (``exp(-rate n)``) while nodes were added and the
error fell at least :data:`~pgdcli.adapt.resolution.P_GAIN`-fold per doubling,
algebraic (``n**-order``) once elements were split or the fall was slower. An error
that did not fall with its nodes gets no such advice: a larger cap would not help.
"""

from __future__ import annotations

import numpy as np

from ..checks.resolution import error_estimates
from ..problem.spec_coordinates import MAX_NODES
from .resolution import MIN_DECAY, P_GAIN, REFINE_AT, doublings, has_room, lacks_nodes, to_refine, total_nodes

__all__ = ["refusal", "cap_advice", "predicted_cap", "FALLING"]

#: The least fall of a coordinate's error per doubling of its nodes that a larger ``solver.max_nodes`` is
#: predicted to turn into an error within the tolerance (an algebraic order of about 1/2).
FALLING = 1.5


def predicted_cap(nodes: int, ratio: float, past: list, decay: float | None) -> tuple[int, str] | None:
    """The nodes in all at which a coordinate's error ratio is predicted to fall to
    :data:`~pgdcli.adapt.resolution.REFINE_AT` (room for the other parts of the error).

    Parameters
    ----------
    nodes : int
        The coordinate's nodes in all (every element).
    ratio : float
        Its measured error ratio at ``nodes`` (to the tolerance).
    past : list of pgdcli.adapt.resolution.Refinement
        Its refinements: ``(kind, ratio, nodes per element, nodes in all, ...)`` before each.
    decay : float or None
        The decay per node of its Chebyshev coefficients (used when nothing was measured).

    Returns
    -------
    (int, str) or None
        The nodes, and the measured fall in words ("its error fell ..."); 0 nodes when the
        error was not falling, -1 when one refinement measured a fall too slow to extrapolate
        (a sharp feature not yet resolved falls slowly at first) or the last one graded its
        elements; None when no rate is known.
    """
    factor = max(ratio / REFINE_AT, 1.0)
    if past:
        kind, before, _, total_before = past[-1][:4]
        if kind == "g":  # a new mesh, with fewer nodes per element: its error is no rate of the last
            return -1, "its elements were graded at its last refinement"
        gain = before / ratio if ratio > 0 else np.inf
        per_doubling = gain ** (1.0 / doublings(total_before, nodes))
        if not per_doubling >= FALLING or nodes <= total_before:
            return 0, (f"its error went from {before:.2g} to {ratio:.2g} x the tolerance from {total_before} to "
                       f"{nodes} nodes")
        words = f"its error fell {per_doubling:.2g}x per doubling of its nodes"
        if kind == "p" and per_doubling >= P_GAIN:  # geometric: exp(-rate n)
            rate = np.log(gain) / (nodes - total_before)
            return int(np.ceil(nodes + np.log(factor) / rate)), words
        if len(past) < 2:  # one slow step may be the start of a sharp feature's resolution, not its rate
            return -1, words + " over one refinement"
        order = np.log(gain) / np.log((nodes - 1) / (total_before - 1))  # algebraic: n**-order
        return int(np.ceil((nodes - 1) * factor ** (1.0 / order))) + 1, words
    if decay is not None and decay >= MIN_DECAY:
        words = f"its Chebyshev coefficients fall {np.exp(decay):.2g}x per node"
        return int(np.ceil(nodes + np.log(factor) / decay)), words
    return None


def cap_advice(problem, name: str, ratio: float, past: list, decay: float | None) -> str:
    """What a coordinate at ``solver.max_nodes`` would need: a larger cap (and the rate it is predicted
    from), or why none is predicted to help.

    The suggested cap is the next ``2**k + 1`` (the node counts a doubling reaches) at or
    above the predicted nodes, and above the cap reached, within the spec's largest
    (:data:`pgdcli.problem.spec_coordinates.MAX_NODES`).
    """
    cap = problem.solver.max_nodes
    reached = f"it reached solver.max_nodes = {cap}"
    predicted = predicted_cap(total_nodes(problem.coordinate(name)), ratio, past, decay)
    if predicted is None:
        return f"{reached} before its error could be seen to fall"
    need, words = predicted
    if need < 0:
        return f"{reached}, and {words}: too few refinements to predict a solver.max_nodes that meets it"
    if need == 0:
        return f"{reached}, and {words}: a larger solver.max_nodes is not predicted to meet it"
    if need > MAX_NODES:
        return f"{reached}, and {words}: at that rate no solver.max_nodes up to {MAX_NODES} is predicted to meet it"
    suggested = min(2 ** int(np.ceil(np.log2(max(need, cap + 1) - 1))) + 1, MAX_NODES)
    return f"{reached}, and {words}: solver.max_nodes: {suggested} is predicted to meet it"


def refusal(problem, check, marches: bool, stopped: str | None = None, limited: bool = False,
            solver: str = "enrichment", history: dict | None = None, decay: dict | None = None) -> str:
    """Why the error is too large and what would reduce it, in one clause.

    ``stopped`` and ``limited`` as :meth:`pgdcli.adapt.rounds.Resolution.judge`'s; ``history`` the
    refinements per coordinate and ``decay`` its Chebyshev decay per node, from which a larger
    ``solver.max_nodes`` is predicted (:func:`cap_advice`).
    """
    stopped = stopped if check.node_ratio > 1.0 else None
    refine, stuck = to_refine(problem, check, marches, limited)
    names = refine + stuck
    if stopped and not any(lacks_nodes(check, n) for n in names):
        return (f"the error at the nodes is {check.node_ratio:.2g} x the tolerance and the {solver} could not "
                f"lower its residual further: {stopped}")
    if names:
        return _lacking(problem, check, names, history or {}, decay or {})
    if check.method.startswith("method of lines"):
        # the method-of-lines reference's own error, not the codebook's, can be what is measured
        return ("the error did not fall with the residual nor with nodes; note that the method-of-lines "
                "reference of problems with space coordinates is itself accurate to about 1e-9, so a tighter "
                "tolerance cannot be checked (--keep-inaccurate keeps the codebook)")
    if check.node_ratio > 1.0:
        what = "march" if marches else solver
        return f"the {what} did not reach the tolerance at the nodes ({check.node_ratio:.2g} x the tolerance)"
    return "the error between the nodes exceeds the tolerance, in no one coordinate alone"


def _lacking(problem, check, names: list, history: dict, decay: dict) -> str:
    """The clause naming the coordinate of ``names`` with the largest error between its nodes."""
    def share(n):
        return max(check.coordinate_ratio.get(n, 0.0), check.tail_ratio.get(n, 0.0))

    worst = max(names, key=share)
    c = problem.coordinate(worst)
    ratio = share(worst)
    measured = check.coordinate_ratio.get(worst, 0.0) >= check.tail_ratio.get(worst, 0.0)
    # the larger of the two says it: the error measured off the coordinate's nodes, or the estimate
    # from its Chebyshev tail (the tail can exceed what was measured many times over)
    seen = "error between its nodes" if measured else "its Chebyshev tail estimates an error between its nodes of"
    estimate = error_estimates(check, [worst]).get(worst, ratio)  # what the refinements went by
    if c.auto and not has_room(c, problem.solver.max_nodes):
        need = cap_advice(problem, worst, estimate, history.get(worst, []), decay.get(worst))
    elif c.auto:
        need = f"it has {total_nodes(c)} nodes"
    else:
        need = _nodes_advice(c, estimate, decay.get(worst))
    if ratio > REFINE_AT:
        return f"coordinate {worst!r} lacks resolution ({seen} {ratio:.2g} x the tolerance; {need})"
    return (f"the error at the nodes did not fall with the residual: coordinate {worst!r} may lack resolution "
            f"({need})")


def _nodes_advice(c, ratio: float, decay: float | None) -> str:
    """What a coordinate with explicit ``nodes:`` needs: the count its Chebyshev spectrum predicts, where it
    has one (one piece, a geometric decay), or the solver's choice."""
    predicted = None if len(c.breakpoints) > 2 else predicted_cap(c.nodes, ratio, [], decay)
    if predicted is None or not c.nodes < predicted[0] <= MAX_NODES:
        return f"it has nodes: {c.nodes}; add nodes or write 'nodes: auto'"
    return f"it has nodes: {c.nodes}; nodes: {predicted[0]} is predicted to meet it, or write 'nodes: auto'"

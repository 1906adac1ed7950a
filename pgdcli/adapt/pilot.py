"""The first round's nodes of a march from a pilot: lines of trajectories along each automatic parameter.

Starting every automatic parameter at 9 nodes costs a march and an error gate per doubling before the
nodes suffice (a pendulum's amplitude: 9 -> 33 -> 49). A march's cost hardly depends on a few dozen
trajectories more, and its codebook's Chebyshev spectrum along a coordinate says how many nodes the
coordinate needs. So before the first round, one march per automatic parameter ``p_j`` on the grid of
:data:`PILOT_NODES` nodes along ``p_j`` and 3 along the other automatic parameters (their ends and
centre: lines through the centre and the corners of the box) measures the spectrum along ``p_j``
(:func:`pgdcli.checks.resolution.chebyshev_spectra`, RMS over the other nodes), and the first round
takes the fewest nodes whose Chebyshev tail, ``2 sum_{k >= n} |c_k|``, is within the coordinate's share
of the tolerance (:data:`~pgdcli.adapt.resolution.TARGET`, or :data:`~pgdcli.adapt.resolution.ROOM`
shared) divided by :data:`SPECTRUM_SAFETY` (the RMS over the lines is not their maximum). A
coordinate the pilot does not resolve starts at :data:`PILOT_NODES` when its spectrum falls geometrically
fast enough to need no elements (the extrapolated tail meets the limit within
:data:`~pgdcli.adapt.resolution.MAX_ELEMENT_NODES` nodes), else at its first nodes: a sharp feature (Runge's
function, a trajectory leaving an unstable point) is cut into elements by the rounds, which measure how
its error falls from there. The pilot only chooses where the rounds start: every round's codebook is still
measured by the error gate, which refines on.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import numpy as np

from ..checks.resolution import chebyshev_spectra, spectrum_decay
from .resolution import MAX_ELEMENT_NODES, MIN_DECAY, ROOM, TARGET

__all__ = ["PILOT_NODES", "PILOT_TRAJECTORIES", "SPECTRUM_SAFETY", "LINE_NODES", "pilot_coordinates",
           "pilot_problem", "nodes_from_spectrum", "extrapolated_nodes", "first_nodes"]

#: Nodes along the coordinate a pilot march measures.
PILOT_NODES = 33
#: Most trajectories of all the pilot's marches together; beyond (many parameters), no pilot.
PILOT_TRAJECTORIES = 2000
#: The tail of the RMS spectrum is brought this far below the coordinate's share of the tolerance.
SPECTRUM_SAFETY = 4.0
#: Nodes of the other automatic parameters in a pilot march: their ends and centre.
LINE_NODES = 3


def pilot_coordinates(problem) -> list[str]:
    """The automatic parameters a pilot measures (Chebyshev, one piece, below :data:`PILOT_NODES` and within
    ``solver.max_nodes``), or none when their pilot marches would exceed :data:`PILOT_TRAJECTORIES`."""
    names = [c.name for c in problem.coordinates if c.auto and c.role == "parameter"
             and c.discretization == "chebyshev" and len(c.breakpoints) <= 2
             and c.nodes < PILOT_NODES <= problem.solver.max_nodes]
    fixed = int(np.prod([c.nodes for c in problem.parameter_coordinates if c.name not in names]))
    per_line = PILOT_NODES * LINE_NODES ** max(0, len(names) - 1) * fixed
    return names if names and len(names) * per_line <= PILOT_TRAJECTORIES else []


def pilot_problem(problem, name: str, names: list[str]):
    """The problem on the pilot's grid for ``name``: :data:`PILOT_NODES` along it, :data:`LINE_NODES` along
    the other ``names``."""
    coords = tuple(dataclasses.replace(c, nodes=PILOT_NODES if c.name == name else LINE_NODES)
                   if c.name in names else c for c in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)


def nodes_from_spectrum(spectrum: np.ndarray, limit: float) -> int | None:
    """The fewest nodes whose Chebyshev tail ``2 sum_{k >= n} |c_k|`` of ``spectrum`` (degree 0 first) is at
    most ``limit``; None when even the last coefficient's exceeds it (the spectrum does not resolve)."""
    tails = 2.0 * np.cumsum(np.abs(spectrum)[::-1])[::-1]
    within = np.flatnonzero(tails <= limit)
    return int(within[0]) if within.size else None


def first_nodes(problem, tolerance: float, march: Callable) -> dict[str, int]:
    """Per automatic parameter measured (:func:`pilot_coordinates`), the nodes its first round starts with.

    Parameters
    ----------
    problem : pgdcli.problem.spec.Problem
        At its first nodes (:func:`pgdcli.adapt.resolution.initial_nodes`).
    tolerance : float
        The absolute tolerance of the promise.
    march : callable
        ``march(problem, name) -> codebook or None``: a march of the pilot's problem along ``name`` (None:
        it failed; that coordinate keeps its nodes).

    Returns
    -------
    dict of str to int
        At least the coordinate's first nodes, at most :data:`PILOT_NODES`.
    """
    names = pilot_coordinates(problem)
    limit = min(TARGET, ROOM / max(1, len(names))) * tolerance / SPECTRUM_SAFETY
    out = {}
    for name in names:
        codebook = march(pilot_problem(problem, name, names), name)
        if codebook is None:
            continue
        spectrum = chebyshev_spectra(codebook).get(name)
        if spectrum is None:
            continue
        first = problem.coordinate(name).nodes
        needed = nodes_from_spectrum(spectrum, limit)
        if needed is not None:
            out[name] = min(PILOT_NODES, max(first, needed))
        else:
            extrapolated = extrapolated_nodes(spectrum, limit)
            if extrapolated is not None:
                out[name] = max(PILOT_NODES, extrapolated)
    return out


def extrapolated_nodes(spectrum: np.ndarray, limit: float) -> int | None:
    """The nodes at which the spectrum's geometric decay (:func:`~pgdcli.checks.resolution.spectrum_decay`),
    extrapolated from its last coefficients, brings them to ``limit``; None when that is beyond
    :data:`~pgdcli.adapt.resolution.MAX_ELEMENT_NODES` (a slower decay is a sharp feature whose elements the
    rounds cut from the first nodes on)."""
    rate = spectrum_decay(spectrum)
    if rate is None or not rate >= MIN_DECAY:
        return None
    last = 2.0 * float(np.abs(spectrum[-2:]).max())
    needed = spectrum.size + np.log(last / limit) / rate
    return int(np.ceil(needed)) if needed <= MAX_ELEMENT_NODES else None

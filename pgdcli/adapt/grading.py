"""Elements graded geometrically toward an end of a parameter's box, where its error concentrates.

A solution that depends on the log-distance to a point at or just beyond an end of
the box (a trajectory leaving an unstable point after a time ~ log(1/x0); a decay
exp(-k t) over a long time, all of whose variation in k lies near k = 0) has
features at every scale toward that end. Cutting the worst element in two, one
level a round, needs a round per scale; elements whose sizes fall geometrically
toward the end, ``a, a + (b - a) q**m, ..., a + (b - a) q, b`` (the geometric mesh of
hp-FEM for corner singularities, ``q`` = :data:`GRADING`), resolve every scale at once
with few nodes each. The automatic resolution grades an end element when the error
measured off the coordinate's nodes peaked near the same end of it two rounds in a row
(:func:`error_end`, :func:`graded_elements`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

__all__ = ["GRADING", "NEAR_END", "MAX_LAYERS", "GRADED_NODES", "error_end", "graded_elements"]

#: Ratio of the sizes of neighbouring graded elements (hp-FEM's geometric meshes use 0.15 to 0.3).
GRADING = 0.2
#: The worst off-node error lies this close to an end of its element, as a fraction of the element, for the
#: error to count as concentrating at that end.
NEAR_END = 0.25
#: Most elements one grading adds: the smallest is GRADING**MAX_LAYERS of the element graded.
MAX_LAYERS = 6
#: Nodes per element after a grading: each element resolves one scale, and more follow by measured decay.
GRADED_NODES = 9


def error_end(c, x: np.ndarray, r: np.ndarray) -> int:
    """Which end of the box the worst off-node error of coordinate ``c`` lies near: -1 (low), 1 (high), 0.

    It counts when the worst point lies in an element that touches that end, within
    :data:`NEAR_END` of the element's size from it.
    """
    if x.size == 0 or not np.isfinite(r).any():
        return 0
    bp = np.asarray(c.breakpoints or c.domain, dtype=float)
    worst = float(x[int(np.nanargmax(r))])
    if worst <= bp[0] + NEAR_END * (bp[1] - bp[0]):
        return -1
    if worst >= bp[-1] - NEAR_END * (bp[-1] - bp[-2]):
        return 1
    return 0


def graded_elements(problem, name: str, end: int, x: np.ndarray, r: np.ndarray):
    """The problem with the end element of ``name`` at ``end`` (-1, 1) graded geometrically toward that end.

    The layers reach one :data:`GRADING` step below the distance of the worst off-node
    error from the end (at least two, at most :data:`MAX_LAYERS`); every element then has
    :data:`GRADED_NODES` nodes (or as many as the coordinate had, if fewer).
    """
    c = problem.coordinate(name)
    bp = np.asarray(c.breakpoints or c.domain, dtype=float)
    outer, inner = (bp[0], bp[1]) if end < 0 else (bp[-1], bp[-2])
    size = abs(inner - outer)
    distance = abs(float(x[int(np.nanargmax(r))]) - outer) / size
    layers = int(np.clip(np.ceil(np.log(max(distance, GRADING ** MAX_LAYERS)) / np.log(GRADING)) + 1, 2, MAX_LAYERS))
    cuts = outer + np.sign(inner - outer) * size * GRADING ** np.arange(1, layers + 1)
    new = tuple(float(v) for v in np.sort(np.concatenate([bp, cuts])))
    graded = dataclasses.replace(c, breakpoints=new, nodes=min(c.nodes, GRADED_NODES))
    coords = tuple(graded if k.name == name else k for k in problem.coordinates)
    return dataclasses.replace(problem, coordinates=coords)

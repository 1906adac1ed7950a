"""The coordinates of a problem as the codebook stores them: domain, nodes, basis, slabs.

A :class:`CoordinateInfo` is what a codebook file records of a coordinate and all that
evaluation needs (its basis); :func:`coordinate_infos` derives them from a parsed problem,
the time coordinate's slabs resolved. numpy only (the query path imports this module).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import SolverError
from ..problem.switches import switch_points
from .basis import make_basis

__all__ = ["CoordinateInfo", "coordinate_infos"]


@dataclass(frozen=True)
class CoordinateInfo:
    """A coordinate of the codebook: name, domain, nodes, discretization and role."""

    name: str
    domain: tuple[float, float]
    nodes: int
    discretization: str = "chebyshev"
    role: str = "parameter"  # 'time' | 'parameter'
    breakpoints: tuple = ()  # slab boundaries of a piecewise Chebyshev coordinate; () = one slab

    def basis(self):
        return make_basis(self.discretization, self.domain, self.nodes, self.breakpoints or None)



def coordinate_infos(problem, *, march: bool):
    """The codebook coordinates of a problem, the time coordinate's slabs resolved.

    ``solver.time_slabs``: an integer N splits a Chebyshev time coordinate into N equal
    slabs of ``nodes`` nodes each; ``auto`` is one slab for the enrichment solver, and for
    the march one slab per accepted step (the provisional single slab returned here is
    replaced once the steps are known).
    """
    slabs = getattr(problem.solver, "time_slabs", 1)
    out = []
    for c in problem.coordinates:
        info = CoordinateInfo(c.name, tuple(c.domain), c.nodes, c.discretization, c.role)
        if len(c.breakpoints) > 2:  # elements: c.nodes per element
            elements = len(c.breakpoints) - 1
            info = CoordinateInfo(c.name, tuple(c.domain), elements * (c.nodes - 1) + 1, c.discretization, c.role,
                                  tuple(c.breakpoints))
        if c.name == problem.time and not march and slabs == "auto" and c.discretization == "chebyshev":
            info = _switch_slabs(problem, c, info)
        if c.name == problem.time and isinstance(slabs, int) and slabs > 1:
            if c.discretization != "chebyshev":
                raise SolverError(f"{problem.source}: solver.time_slabs: slabs need a chebyshev time coordinate, "
                                  f"{c.name!r} is {c.discretization}")
            breakpoints = tuple(np.linspace(c.domain[0], c.domain[1], slabs + 1))
            info = CoordinateInfo(c.name, tuple(c.domain), slabs * (c.nodes - 1) + 1, c.discretization, c.role,
                                  breakpoints)
        out.append(info)
    return out


def _switch_slabs(problem, c, info):
    """The enrichment's time coordinate with a slab boundary at every switch point of a function of time
    alone (``max(t - 1, 0)``): Chebyshev interpolation converges spectrally on each side. The march
    steps across them (its slabs are its steps)."""
    points = switch_points(problem.equations, c.name, tuple(c.domain))
    if not points:
        return info
    breakpoints = (float(c.domain[0]), *points, float(c.domain[1]))
    return CoordinateInfo(c.name, tuple(c.domain), (len(breakpoints) - 1) * (c.nodes - 1) + 1, c.discretization,
                          c.role, breakpoints)

"""``pgd solve`` of a reaction-diffusion system: the exponential march into a codebook.

:func:`solve_pde_march` compiles the split system (:mod:`.pde_system`) on the codebook's nodes,
marches it (:mod:`.pde_march`, ETDRK4) and joins the states at the time nodes into one tensor
train per unknown over ``(time, x, [y], parameters)`` (:func:`pgdcli.algorithms.march.join_and_round`),
each stored as a :class:`~pgdcli.tensors.tt.TT`. With ``solver.time_slabs: auto`` (the default) the time
coordinate has one slab per accepted step, :data:`SLAB_NODES` Chebyshev-Lobatto nodes each (a
degree-4 polynomial per step matches the scheme's order 4); with a number of slabs the steps land
on the time coordinate's nodes. The error gate (:mod:`pgdcli.checks.check`) measures the codebook
against the independent nonlinear method of lines (:mod:`pgdcli.checks.reference_pde_nonlinear`).
"""

from __future__ import annotations

import time as _time

import numpy as np

from ..discretization.coordinates import CoordinateInfo, coordinate_infos
from ..errors import SolverError
from ..tensors.tt import TT
from .march_codebook import SPACE_TIME_FRACTION
from .space_time import join_and_round
from .pde_march import UnderResolved, march_pde
from .pde_system import compile_pde_system

__all__ = ["solve_pde_march", "SLAB_NODES"]

#: Time nodes per step (slab) of the automatic time grid.
SLAB_NODES = 5


def solve_pde_march(problem, tolerance: float, callback=None, learned: dict | None = None):
    """March a reaction-diffusion system; see :func:`pgdcli.driver.solve`.

    ``learned``: as :func:`pgdcli.algorithms.march.solve_march`'s (nothing to carry here).

    Returns
    -------
    pgdcli.algorithms.result.SolveResult
        ``converged`` False, with the reason, when the march could not reach the end.
    """
    from .. import __version__
    from ..codebook.codebook import Codebook
    from .result import SolveResult

    started = _time.perf_counter()
    coords = coordinate_infos(problem, march=True)
    names = [c.name for c in coords]
    bases = {c.name: c.basis() for c in coords if c.name != problem.time}
    system = compile_pde_system(problem, bases, corner_tolerance=tolerance)
    tcoord = coords[names.index(problem.time)]
    auto = getattr(problem.solver, "time_slabs", "auto") == "auto" and tcoord.discretization == "chebyshev"
    # the automatic resolution can add space nodes: stop an under-resolved march early (pde_march.TAIL_ABORT)
    refinable = [x for x in system.modes[:system.space]
                 if problem.coordinate(x).auto and problem.coordinate(x).nodes < problem.solver.max_nodes]
    try:
        result = march_pde(system, tolerance, None if auto else tcoord.basis().nodes,
                           slab_nodes=SLAB_NODES if auto else None, max_steps=problem.solver.max_steps,
                           callback=callback, tail_limit=refinable)
    except SolverError as exc:
        wall = _time.perf_counter() - started
        message = f"not converged: {exc}"
        report = {"converged": False, "status": 3, "message": message, "method": "pde march",
                  "tolerance": float(tolerance), "wall_time": wall, "steps": 0, "pgdcli_version": __version__}
        if isinstance(exc, UnderResolved):
            report["under_resolved"] = exc.coordinate  # pgdcli.adapt refines it and solves again
        order = tuple(names.index(m) for m in [problem.time] + system.modes)
        fields = {u.name: TT(tuple(np.zeros((1, coords[j].nodes, 1)) for j in order), order)
                  for u in problem.unknowns}
        cb = Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                      description=problem.description)
        return SolveResult(cb, False, 3, message, np.array([np.inf]), np.zeros(0, dtype=int), wall)
    states = result.states
    if auto:
        k = names.index(problem.time)
        bp = result.breakpoints.copy()
        bp[0], bp[-1] = tcoord.domain
        coords[k] = CoordinateInfo(tcoord.name, tuple(tcoord.domain), len(states), "chebyshev", tcoord.role,
                                   tuple(float(v) for v in bp))
        assert np.allclose(coords[k].basis().nodes, result.times, rtol=0, atol=1e-12 * max(1.0, abs(bp[-1])))
    size = float(np.prod(system.shape))
    order = tuple(names.index(m) for m in [problem.time] + system.modes)
    fields, ranks = {}, []
    for s, sp in enumerate(system.species):
        train = join_and_round([[per[s] for per in states]], SPACE_TIME_FRACTION * tolerance * np.sqrt(size),
                               np.random.default_rng(7), batched=False)[0]
        fields[sp.name] = TT(tuple(train.cores), order)
        ranks.append(max(train.ranks, default=1))
    wall = _time.perf_counter() - started
    message = (f"converged: reached {problem.time} = {tcoord.domain[1]:.6g} in {result.steps} steps "
               f"({result.rejected} rejected)")
    report = {
        "converged": True, "status": 0, "message": message, "method": "pde march (ETDRK4)",
        "modes": int(max(ranks)), "residual": float(tolerance), "tolerance": float(tolerance),
        "steps": int(result.steps), "rejected_steps": int(result.rejected),
        "step_sizes": np.array(result.step_sizes), "nonlinear_evaluations": int(result.evaluations),
        "max_state_rank": int(result.max_rank), "wall_time": wall, "pgdcli_version": __version__,
    }
    cb = Codebook(coords, fields, name=problem.name, spec_text=problem.source_text, report=report,
                  description=problem.description)
    return SolveResult(cb, True, 0, message, np.array([tolerance]), np.zeros(0, dtype=int), wall)


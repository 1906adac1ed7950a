"""``pgd solve`` of a reaction-diffusion system: the exponential march into a codebook.

:func:`solve_pde_march` compiles the split system (:mod:`.pde_system`) on the codebook's nodes,
marches it (:mod:`.pde_march`, ETDRK4) and joins the states at the time nodes into one tensor
train per unknown over ``(time, x, [y], parameters)`` (:func:`pgdcli.algorithms.space_time.join_and_round`),
each stored as a :class:`~pgdcli.tensors.tt.TT`. With ``solver.time_slabs: auto`` (the default) the time
coordinate has one slab per accepted step, :data:`SLAB_NODES` Chebyshev-Lobatto nodes each (a
degree-4 polynomial per step matches the scheme's order 4); with a number of slabs the steps land
on the time coordinate's nodes. The error gate (:mod:`pgdcli.checks.check`) measures the codebook
against the independent nonlinear method of lines (:mod:`pgdcli.checks.reference_pde_nonlinear`).
"""

from __future__ import annotations

import time as _time

import numpy as np

from .. import __version__
from ..codebook.codebook import Codebook
from ..discretization.coordinates import coordinate_infos
from ..errors import SolverError
from ..tensors.tt import TT
from .march_codebook import SPACE_TIME_FRACTION, march_coordinates, steps_text
from .outcome import Learned, SolverOutcome, Status
from .pde_march import UnderResolved, march_pde
from .pde_system import compile_pde_system
from .space_time import join_and_round

__all__ = ["solve_pde_march", "SLAB_NODES"]

#: Time nodes per step (slab) of the automatic time grid.
SLAB_NODES = 5


def solve_pde_march(problem, tolerance: float, callback=None, learned: Learned = Learned()) -> SolverOutcome:
    """March a reaction-diffusion system; see :func:`pgdcli.driver.solve`.

    ``learned`` is not used: nothing of an earlier solve changes this march.

    Returns
    -------
    SolverOutcome
        Status ``FAILED``, with the reason, when the march could not reach the end; its
        ``under_resolved`` names the space coordinate when its lack of nodes stopped the march.
    """
    started = _time.perf_counter()
    coords = coordinate_infos(problem, march=True)
    bases = {c.name: c.basis() for c in coords if c.name != problem.time}
    system = compile_pde_system(problem, bases, corner_tolerance=tolerance)
    tcoord = problem.time_coordinate
    auto = getattr(problem.solver, "time_slabs", "auto") == "auto" and tcoord.discretization == "chebyshev"
    times = None if auto else coords[[c.name for c in coords].index(problem.time)].basis().nodes
    # the automatic resolution can add space nodes: stop an under-resolved march early (pde_march.TAIL_ABORT)
    refinable = [x for x in system.modes[:system.space]
                 if problem.coordinate(x).auto and problem.coordinate(x).nodes < problem.solver.max_nodes]
    try:
        result = march_pde(system, tolerance, times, slab_nodes=SLAB_NODES if auto else None,
                           max_steps=problem.solver.max_steps, callback=callback, tail_limit=refinable)
    except SolverError as exc:
        return _failed(problem, system, coords, exc, tolerance, _time.perf_counter() - started)
    coords = march_coordinates(problem, result)
    size = float(np.prod(system.shape))
    cores = {}
    for s, sp in enumerate(system.species):
        train = join_and_round([[per[s] for per in result.states]], SPACE_TIME_FRACTION * tolerance * np.sqrt(size),
                               np.random.default_rng(7), batched=False)[0]
        cores[sp.name] = tuple(train.cores)
    wall = _time.perf_counter() - started
    message = (f"converged: reached {problem.time} = {tcoord.domain[1]:.6g} in {result.steps} steps "
               f"({result.rejected} rejected)")
    report = {
        "converged": True, "status": int(Status.CONVERGED), "message": message, "method": "pde march (ETDRK4)",
        "modes": max(max(c.shape[0] for c in train_cores) for train_cores in cores.values()),
        "residual": float(tolerance), "tolerance": float(tolerance),
        "steps": int(result.steps), "rejected_steps": int(result.rejected),
        "step_sizes": np.array(result.step_sizes), "nonlinear_evaluations": int(result.evaluations),
        "max_state_rank": int(result.max_rank), "wall_time": wall,
    }
    cb = _codebook(problem, system, coords, cores, report)
    return SolverOutcome(cb, Status.CONVERGED, message, tolerance, steps_text(problem, result.steps, result.rejected),
                         residuals=np.array([tolerance]), wall_time=wall)


def _failed(problem, system, coords, exc: SolverError, tolerance: float, wall: float) -> SolverOutcome:
    """The outcome of a march that stopped: a placeholder codebook of zeros and the reason."""
    message = f"not converged: {exc}"
    lacking = exc.coordinate if isinstance(exc, UnderResolved) else None
    report = {"converged": False, "status": int(Status.FAILED), "message": message, "method": "pde march",
              "tolerance": float(tolerance), "wall_time": wall, "steps": 0}
    if lacking:
        report["under_resolved"] = lacking
    names = [c.name for c in coords]
    zeros = tuple(np.zeros((1, coords[names.index(m)].nodes, 1)) for m in [problem.time] + system.modes)
    cb = _codebook(problem, system, coords, {u.name: zeros for u in problem.unknowns}, report)
    return SolverOutcome(cb, Status.FAILED, message, tolerance, residuals=np.array([np.inf]), wall_time=wall,
                         under_resolved=lacking)


def _codebook(problem, system, coords, cores: dict, report: dict):
    """The codebook of unknown name -> the cores of its train over ``(time, space..., parameters)``."""
    names = [c.name for c in coords]
    order = tuple(names.index(m) for m in [problem.time] + system.modes)
    report["pgdcli_version"] = __version__
    return Codebook(coords, {name: TT(c, order) for name, c in cores.items()}, name=problem.name,
                    spec_text=problem.source_text, report=report, description=problem.description)

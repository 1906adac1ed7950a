"""Nonlinear problems: a time march of the parameter-separated state.

For equations polynomial in the unknowns (``der(u1) + u2*u3 = 1``), the state
``u(t_n; p)`` is kept as a function of the non-time coordinates ``p`` (initial
conditions, parameters) in tensor-train form (:mod:`pgdcli.tensors.tt`) and advanced
with an explicit embedded Runge-Kutta pair (``solver.integrator``; by default
Dormand-Prince 8(5,3), the coefficients of :class:`scipy.integrate.DOP853`), whose
embedded estimate controls the step size. The right-hand side is evaluated in separated form: products of
unknowns are Hadamard products of tensor trains, and every stage value is
recompressed once by SVD-based rounding with an absolute Frobenius bound, so
ranks stay near those of the solution instead of growing as N^2. Above a small
implicit rank the products are never formed: a warm-started one-site cross on the
state interpolates them (O(n r^3) per core, :mod:`pgdcli.tensors.cross_products`),
falling back to the randomized sketch (O(n r^4), :mod:`pgdcli.tensors.tt_sketch`)
when its sampled error misses the bound. The state is
stored at the nodes of the time coordinate (steps land on them) and the
codebook interpolates between them with the time basis.

Error control, all in the root-mean-square norm over the nodes of the
parameter grid (the Frobenius norm of the tensor divided by the square root
of its size; a Frobenius bound would bound the largest nodal error but grows
as sqrt(grid size), which in six dimensions asks for 512x the accuracy and
ranks to match): local Runge-Kutta error <=
``0.3 * tolerance * h / T`` per step (error per unit step: the local errors
add up to at most 0.3 tolerance), state rounding <= ``0.02 * tolerance`` per
step, stage rounding <= ``0.05 * tolerance`` (its effect on the step is scaled
by ``h``). The report's ``error_estimate`` adds these up over the march; it
does not include the growth of errors through the dynamics (the Lipschitz
factor), and the worst point of the grid can be 5-20 times the RMS: the user's
tolerance is a max abs error, measured against scipy after the march and
enforced by repeating it with a tighter RMS target (:mod:`pgdcli.checks.check`,
:mod:`pgdcli.driver.refinement`).

The pieces: the compiled right-hand side (:mod:`.polynomial_rhs`), the arithmetic of trains
(:mod:`.train_steps`), the steppers (:mod:`.steppers`), the march loop (:mod:`.march_loop`) with
its step control (:mod:`.step_control`) and blow-up prediction (:mod:`.blowup`), and the
codebook's space-time train (:mod:`.space_time`).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field

import numpy as np

from ..progress import MarchStep, emit
from ..tensors.tt import TT, tt_round_many
from .blowup import WATCH_AGREE, blowup_region
from .general_rhs import report_entries
from .polynomial_rhs import NonlinearSystem, compile_system, evaluate_rhs, round_terms
from .space_time import join_and_round
from .cross_march import march_by_cross
from .grid_march import GridMarchFailure, check_forced_grid, fits_grid, grid_region, march_on_grid
from .march_codebook import SPACE_TIME_FRACTION, converged_result, failed_result
from .march_loop import march_steps
from .outcome import Learned, SolverOutcome
from .stepping import Stepper
from .step_control import LOCAL_FRACTION, STAGE_FRACTION, STATE_FRACTION
from .steppers import AUTO, DEFAULT, METHODS, STIFF
from .steppers import stepper as named_stepper
from .stiffness import StiffnessDetected
from .train_steps import MarchFailure, TrainSpace

__all__ = ["NonlinearSystem", "MarchResult", "MarchFailure", "compile_system", "evaluate_rhs", "round_terms",
           "march", "join_and_round", "solve_march", "WATCH_AGREE"]

#: ``solver.march: auto`` sends grids too large for the grid march to the cross of trajectories
#: (:mod:`pgdcli.algorithms.cross_march`) rather than the tensor-train march.
CROSS_BY_DEFAULT = True
#: From this many state values (grid nodes x unknowns) on, ``auto`` tries the cross march first on a grid the
#: grid march could take, with a budget of ``CROSS_BUDGET`` trajectories per grid node: on large grids the cross
#: needs far fewer trajectories than the grid has nodes, but some problems need more (the rigid body at 8^6
#: nodes and 1e-6). A trajectory of the cross costs a fifth to a sixth of a node of the grid march, so the
#: budget stops an unconverged cross about where it has cost what the grid march will
#: (benchmarks/build_speed.py measures both marches).
CROSS_FIRST_VALUES = 2 ** 17
CROSS_BUDGET = 5


@dataclass
class MarchResult:
    """States at the time nodes and what the march did."""

    states: list[list[TT]]  # [time node][unknown]
    steps: int
    rejected: int
    error_estimate: float
    ranks: list[list[tuple[int, ...]]]  # [time node][unknown]
    step_sizes: list[float] = field(default_factory=list)
    times: np.ndarray | None = None  # the time nodes the states are at
    breakpoints: np.ndarray | None = None  # slab boundaries (automatic slabs only)
    roundings: dict = field(default_factory=dict)  # {"exact", "sketched", "redone"}: counts


def march(system: NonlinearSystem, tolerance: float, *, max_rank: int = 400, max_steps: int = 20000,
          callback=None, slab_nodes: int | None = None, stepper: Stepper | None = None) -> MarchResult:
    """Advance the separated state over the time domain with a stepper and its dense output.

    Steps are chosen by the embedded error estimate (not by the time nodes); the state at every
    time node inside a step comes from the stepper's dense output.

    Parameters
    ----------
    system : NonlinearSystem
    tolerance : float
        Error target: root mean square over the nodes of the parameter grid, per
        unknown, of the local errors added up over the march.
    max_rank, max_steps : int
        Caps; exceeding them raises :class:`MarchFailure`.
    callback : callable, optional
        Called after every accepted step with a :class:`~pgdcli.progress.MarchStep`.
    slab_nodes : int, optional
        Automatic time slabs: every accepted step is a slab and the state is
        stored at its ``slab_nodes`` Chebyshev-Lobatto nodes (from 8 on, DOP853's
        dense output, a polynomial of degree 7, is reproduced exactly by the
        codebook's interpolation). Without it, the nodes of the time basis.
    stepper : Stepper, optional
        Default DOP853.

    Raises
    ------
    MarchFailure
        With the time where the march stopped.
    """
    stepper = stepper or named_stepper()
    nodes = system.time_basis.nodes
    span = float(nodes[-1]) - float(nodes[0])
    # tolerance is a root-mean-square error over the parameter grid; the tensor
    # arithmetic works with Frobenius norms, sqrt(grid size) times larger
    frobenius = tolerance * np.sqrt(float(np.prod(system.shape)))
    state_delta = STATE_FRACTION * frobenius
    stats = {"exact": 0, "sketched": 0, "redone": 0, "stage_tightenings": 0}  # roundings, for the report
    # the randomized roundings: same spec, same codebook
    space = TrainSpace(system, STAGE_FRACTION * frobenius, state_delta, span, max_rank, np.random.default_rng(20240607),
                       stats)
    y = tt_round_many(system.initial, absolute=state_delta, max_rank=max_rank)
    states: list = []
    schedule = march_steps(space, stepper, y, nodes, LOCAL_FRACTION * frobenius, states.extend, max_steps=max_steps,
                           callback=callback, slab_nodes=slab_nodes)
    ranks = [[u.ranks for u in st] for st in states]
    error_estimate = schedule.estimate + state_delta  # the rounding of the values at the time nodes (once)
    rms = error_estimate / np.sqrt(float(np.prod(system.shape)))
    return MarchResult(states, len(schedule.steps), schedule.rejected, rms, ranks, schedule.step_sizes,
                       np.array(schedule.times), schedule.breakpoints() if slab_nodes else None, stats)


def solve_march(problem, tolerance: float, callback=None, learned: Learned = Learned()) -> SolverOutcome:
    """Solve a (nonlinear) problem by the separated time march; see :func:`pgdcli.driver.solve`.

    ``solver.march`` chooses the state: the grid's whole array (:mod:`.grid_march`), the cross of
    trajectories (:mod:`.cross_march`) or a tensor train (:func:`march`); ``auto`` takes the grid
    when it fits, the cross first on a large grid. ``learned.cross_abandoned``: a cross ran past
    its budget of trajectories in an earlier solve; a finer grid asks it for more trajectories a
    node, not fewer, so the grid march takes any grid it can hold at once.

    Returns
    -------
    SolverOutcome
        Status ``FAILED``, with a message naming the time (and the region of the domain) where
        the march failed, when it could not reach the end of the time domain;
        ``cross_abandoned`` says why a cross was given up in this solve.
    """
    opts = problem.solver
    started = _time.perf_counter()
    separations: list = []
    system = compile_system(problem, tolerance, separations)
    run = _Run(problem, system, tolerance, separations, callback, started)
    run.stiff = learned.stiff
    march_state = getattr(opts, "march", "auto")  # solver.march: the grid's array or a tensor train
    check_forced_grid(problem)  # the automatic resolution may have grown the grid since the first check
    nodes = int(np.prod(system.shape))
    fits, first = fits_grid(system), nodes * len(system.unknowns) >= CROSS_FIRST_VALUES
    abandoned = None
    if learned.cross_abandoned and fits and march_state == "auto":
        run.cross_note = f"in an earlier solve of the automatic resolution: {learned.cross_abandoned}"
    elif march_state == "cross" or (march_state == "auto" and CROSS_BY_DEFAULT and (first or not fits)):
        # auto on a grid the grid march could take: the cross gets a budget, and the grid march what it left
        found = _solve_by_cross(run, CROSS_BUDGET * nodes if march_state == "auto" and fits else None)
        if found is not None:
            return run.finished(found)
        abandoned = run.cross_note
    if march_state == "grid" or (march_state == "auto" and fits):
        outcome = _solve_on_grid(run)
    else:
        outcome = _solve_by_train(run)
    outcome.cross_abandoned = abandoned
    return run.finished(outcome)


class _Run:
    """One :func:`solve_march`: its problem, compiled system and settings, and what its marches tell.

    Passes the marches' progress events on, and keeps the steps of the last march step for the report
    of a march that fails (0 after a sweep of the cross).
    """

    def __init__(self, problem, system: NonlinearSystem, tolerance: float, separations: list, callback,
                 started: float):
        self.problem, self.system, self.tolerance, self.separations = problem, system, tolerance, separations
        self.callback, self.started = callback, started
        self.steps = 0
        self.cross_note: str | None = None  # why the cross was given up (the grid march's report says it)
        self.stiff: str | None = None  # why the march switched to the stiff stepper
        self.integrator = DEFAULT  # the stepper of the last march
        auto = getattr(problem.solver, "time_slabs", "auto") == "auto"
        # linear time elements: the nodes are the slabs already
        auto = auto and problem.time_coordinate.discretization == "chebyshev"
        self.slab_nodes = problem.time_coordinate.nodes if auto else None
        self.space_time_delta = SPACE_TIME_FRACTION * tolerance * np.sqrt(float(np.prod(system.shape)))

    def __call__(self, event) -> None:
        self.steps = event.steps if isinstance(event, MarchStep) else 0
        emit(self.callback, event)

    def wall(self) -> float:
        return _time.perf_counter() - self.started

    def failed(self, failure, region: str, steps: int | None = None) -> SolverOutcome:
        return failed_result(self.problem, self.system, failure, region, self.tolerance,
                             self.steps if steps is None else steps, self.wall())

    def converged(self, result, trains: list[TT], report: dict) -> SolverOutcome:
        return converged_result(self.problem, self.system, result, trains, report, self.tolerance, self.separations,
                                self.wall())

    def stepped(self, run_march, detects: bool = True):
        """``run_march(stepper)`` with ``solver.integrator``'s stepper, and the report entries that name it.

        With ``auto`` a march held at its stability limit (:class:`~pgdcli.algorithms.stiffness.StiffnessDetected`,
        only where the state has a Jacobian: ``detects``) starts again with the stiff stepper, and so do the
        later solves of the problem (``self.stiff`` from :class:`~pgdcli.algorithms.outcome.Learned`).
        """
        asked = self.problem.solver.integrator
        if asked == AUTO and self.stiff:
            return self._run_with(run_march, STIFF, f"solver.integrator: auto, {self.stiff}")
        try:
            why = ("auto, not stiff" if detects else "auto (stiffness is detected on arrays of nodes, not on "
                                                     "tensor trains)") if asked == AUTO else asked
            return self._run_with(run_march, asked, f"solver.integrator: {why}")
        except StiffnessDetected as exc:
            self.stiff = f"{exc}; marched again with {METHODS[STIFF].title}"
            return self._run_with(run_march, STIFF, f"solver.integrator: auto, {self.stiff}")

    def _run_with(self, run_march, name: str, why: str):
        self.integrator = DEFAULT if name == AUTO else name
        result = run_march(named_stepper(name))
        # ``stiff``: the codebook's reference integrator must be stiff too (the gate, ``pgd verify``)
        return result, {"integrator": self.integrator, "integrator_reason": why,
                        "stiff": int(not getattr(METHODS[self.integrator], "explicit", True))}

    def finished(self, outcome: SolverOutcome) -> SolverOutcome:
        """The outcome, saying which stepper marched when not the default, and whether the problem was stiff."""
        outcome.stiff = self.stiff
        if outcome.converged and self.integrator != DEFAULT:
            outcome.summary += f" with {METHODS[self.integrator].title}" + (" (stiff)" if self.stiff else "")
        return outcome


def _solve_by_train(run: _Run) -> SolverOutcome:
    """:func:`solve_march` with the state a tensor train: :func:`march`."""
    opts, system = run.problem.solver, run.system
    try:
        result, entries = run.stepped(lambda stepper: march(
            system, run.tolerance, max_rank=opts.max_rank, max_steps=opts.max_steps, callback=run,
            slab_nodes=run.slab_nodes, stepper=stepper), detects=False)
    except MarchFailure as failure:
        return run.failed(failure, blowup_region(system, failure.state) if failure.state is not None else "")
    # one unknown at a time: batching would give every unknown the largest ranks of all
    trains = join_and_round([[st[i] for st in result.states] for i in range(len(system.unknowns))],
                            run.space_time_delta, np.random.default_rng(7), batched=False, stats=result.roundings)
    ranks = np.array([[list(r) for r in node] for node in result.ranks], dtype=int)
    return run.converged(result, trains, {**_march_report(result.roundings, ranks), **entries})


def _solve_on_grid(run: _Run) -> SolverOutcome:
    """:func:`solve_march` on a small grid: :func:`pgdcli.algorithms.grid_march.march_on_grid`."""
    system = run.system
    try:
        result, entries = run.stepped(lambda stepper: march_on_grid(
            system, run.tolerance, run.space_time_delta, max_steps=run.problem.solver.max_steps, callback=run,
            slab_nodes=run.slab_nodes, stepper=stepper))
    except GridMarchFailure as failure:
        return run.failed(failure, grid_region(system, failure.values))
    trains = result.trains
    cap = run.problem.solver.max_rank
    if max(max(train.ranks[1:], default=0) for train in trains) >= cap:  # the train march's cap, on the codebook
        failure = GridMarchFailure(f"a tensor-train rank reached solver.max_rank={cap} (raise it)",
                                   float(result.times[-1]), np.zeros((len(trains), 0)))
        return run.failed(failure, "", result.steps)
    # no state trains at the nodes: each node's ranks are at most the parameter bonds of the codebook's train
    bonds = [list(train.ranks[1:]) for train in trains]
    report = {"node_ranks": np.array([bonds] * len(result.times), dtype=int), "march": "grid",
              "grid_chunks": int(result.chunks), **entries}  # no roundings, crosses or products to count
    if run.cross_note is not None:  # auto tried the cross march first
        report["cross_abandoned"] = run.cross_note
    return run.converged(result, trains, report)


def _solve_by_cross(run: _Run, budget: int | None = None) -> SolverOutcome | None:
    """:func:`solve_march` on a large grid: :func:`pgdcli.algorithms.cross_march.march_by_cross`.

    With a ``budget`` (trajectories; the grid march can take the grid), a cross that does not converge
    within it returns None, with the reason in ``run.cross_note``: the caller marches the whole grid instead.
    """
    system, opts = run.system, run.problem.solver
    try:
        result, entries = run.stepped(lambda stepper: march_by_cross(
            system, run.tolerance, run.space_time_delta, max_rank=opts.max_rank, max_steps=opts.max_steps,
            callback=run, slab_nodes=run.slab_nodes, budget=budget, stepper=stepper))
    except GridMarchFailure as failure:
        return run.failed(failure, grid_region(system, failure.values, failure.indices))
    if not result.converged and budget is not None:
        run.cross_note = result.message
        return None
    if not result.converged:
        failure = GridMarchFailure(f"the cross of the trajectories did not converge: {result.message}",
                                   float(result.times[-1]), np.zeros((len(system.unknowns), 0)))
        return run.failed(failure, "", result.steps)
    bonds = [list(train.ranks[1:]) for train in result.trains]
    report = {"node_ranks": np.array([bonds] * len(result.times), dtype=int), "march": "cross",
              "cross_trajectories": int(result.evaluations), "cross_sweeps": int(result.sweeps),
              "cross_error": float(result.cross_error), "pilot_points": int(result.pilot_points), **entries}
    return run.converged(result, result.trains, report)


def _march_report(stats: dict, node_ranks: np.ndarray) -> dict:
    """The report entries of one march: the ranks at the time nodes and what the roundings did."""
    return {
        "march": "train",
        "node_ranks": node_ranks,  # (time nodes, unknowns, bonds)
        # tensor-train roundings: exact (QR + SVD of the explicit sum), randomized (sketched), and the
        # sketches redone with twice the size because the rounded rank came too close to the sketch's
        "roundings_exact": int(stats.get("exact", 0)),
        "roundings_sketched": int(stats.get("sketched", 0)),
        "roundings_redone": int(stats.get("redone", 0)),
        # stage roundings made 10x tighter because their noise, not the step, set the error estimate
        "stage_tightenings": int(stats.get("stage_tightenings", 0)),
        # right-hand sides whose products were interpolated by the one-site cross, and those whose
        # cross missed its sampled error and fell back to the randomized rounding
        "product_crosses": int(stats.get("product_crosses", 0)),
        "product_cross_fallbacks": int(stats.get("product_cross_fallbacks", 0)),
        **report_entries(stats),
    }

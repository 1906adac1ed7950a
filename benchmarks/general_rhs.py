"""Functions of the unknowns: codebook builds beside solve_ivp and teneva's TT-cross, in one run.

    pip install -e '.[benchmark]'                 # teneva, for the black-box TT-cross column
    python benchmarks/general_rhs.py              # every problem below (~5 min on 2 cores)
    python benchmarks/general_rhs.py pendulum     # some of them (--no-paths: without the second table)

For each problem (no node counts; ``sin(th)``, ``v*sqrt(vx**2 + vy**2)``, ``exp(-a*x)``,
``s/(km + s)`` in its equations), the build of the codebook, ``pgdcli.solve`` (automatic
resolution and the error gate included), beside the alternatives that fill the grid of the
codebook's own nodes (every parameter node, every time node; interpolated with the codebook's bases
such a grid is as accurate as the codebook):

- a Python loop of ``solve_ivp`` (DOP853, rtol = atol = 1e-10), one call per grid point, timed on
  at most 200 random points and scaled (``gate_build.time_loop``);
- ONE vectorized ``solve_ivp`` call over all grid points, same tolerances;
- teneva's TT-cross (``teneva.cross``, rank-adaptive maxvol cross) of the tensor
  ``u(t_i, p_j, ...)`` over the same grid (time as one more mode), one cross per unknown, whose
  black box solves the parameter points it asks for with one vectorized ``solve_ivp`` per batch (a
  point is solved once for all unknowns: cached). Its convergence threshold is lowered from 1e-6
  to 1e-8 and 1e-10 until its max error over the whole grid (against the vectorized call) meets the
  tolerance; the time of that run is reported, with its solve_ivp points. Each cross may ask at most
  4 times as many values as the whole tensor has (``m``; values of points already solved are free).

A second table builds a 3- and a 4-parameter problem by the tensor-train march (``solver.march:
train``; the default grid march evaluates on its whole grid anyway) three ways: general terms on
the whole grid (the default up to about 4 parameters), by TT-cross always, and the whole
right-hand side (its polynomial monomials too) by the default path.

The scipy runs use one BLAS thread, as the solver does. The machine is shared: every comparison is
made within this run. The tables are printed and written to benchmarks/results/general_rhs.md.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

import pgdcli
from pgdcli.checks.reference import solve_reference_vectorized
from pgdcli.tensors.tt import TT, tt_sum

from _machine import published
from gate_build import RTOL, ATOL, grid_points, time_loop, time_vectorized

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = {
    "pendulum": ROOT / "problems" / "pendulum.yaml",
    "drag": ROOT / "problems" / "drag.yaml",
    "damped_pendulum": ROOT / "tests" / "user_problems" / "damped_pendulum.yaml",
    "morse": ROOT / "tests" / "user_problems" / "morse.yaml",
    "michaelis": ROOT / "tests" / "user_problems" / "michaelis.yaml",
    "drag3": ROOT / "tests" / "user_problems" / "drag3.yaml",
}


class BlackBox:
    """``u(t_i, p_j)`` of every unknown at grid multi-indices, solving each parameter point once."""

    def __init__(self, problem, axes: list[np.ndarray], times: np.ndarray):
        self.problem, self.axes, self.times = problem, axes, times
        self.names = [c.name for c in problem.parameter_coordinates if c.role != "space"]
        shape = tuple(a.size for a in axes)
        self.values = np.zeros(shape + (len(problem.unknown_names), times.size))  # solved trajectories
        self.solved = np.zeros(shape, dtype=bool)

    def __call__(self, unknown: int, indices: np.ndarray) -> np.ndarray:
        params = tuple(indices[:, 1:].T)
        new = np.unique(indices[~self.solved[params], 1:], axis=0)
        if new.size:
            points = {n: self.axes[k][new[:, k]] for k, n in enumerate(self.names)}
            values = solve_reference_vectorized(self.problem, points, len(new), self.times, rtol=RTOL, atol=ATOL)
            self.values[tuple(new.T)] = np.stack([values[u] for u in self.problem.unknown_names], axis=1)
            self.solved[tuple(new.T)] = True
        return self.values[params + (unknown, indices[:, 0])]

    @property
    def points_solved(self) -> int:
        return int(self.solved.sum())


def _relative_change(Y1, Y2) -> float:
    """``||Y1 - Y2|| / ||Y1||`` of two teneva trains (lists of cores) in O(n r^3) memory and work."""
    a, b = TT(Y1), TT(Y2)
    norm = a.norm()
    return tt_sum([a, b], [1.0, -1.0]).norm() / norm if norm > 0 else 0.0


def load_teneva():
    """teneva with its per-sweep change measured in O(n r^3) memory, or None when it is not installed."""
    try:
        import teneva
    except ImportError:
        return None
    # teneva.cross measures its change per sweep with teneva.accuracy, whose scalar product forms
    # (r, r, n, r, r) arrays: 4 GiB at rank 58 on the pendulum. The same quantity in O(n r^3):
    teneva.accuracy = _relative_change
    return teneva


def cross_full(teneva, f, shape: list[int], e: float, budget: int):
    """teneva's rank-adaptive cross of ``f`` (multi-indices (M, d) -> (M,)) at threshold ``e``.

    Returns the cross's full tensor (``shape``) after rounding at ``e`` and its largest TT rank.
    """
    Y = teneva.cross(f, teneva.rand(shape, 2, seed=1), e=e, m=budget, nswp=30, dr_max=2)
    Y = teneva.truncate(Y, e)
    rank = max(teneva.props.ranks(Y)) if hasattr(teneva, "props") else max(teneva.ranks(Y))
    return teneva.full(Y), rank


def teneva_cross(problem, cb, tolerance: float, reference: dict) -> str:
    """Time of the loosest teneva cross whose max nodal error meets the tolerance, as table text."""
    teneva = load_teneva()
    if teneva is None:
        return "teneva not installed"
    points, times = grid_points(cb, problem)
    names = [c.name for c in problem.parameter_coordinates if c.role != "space"]
    axes = [cb.coordinate(n).basis().nodes for n in names]
    shape = [times.size] + [a.size for a in axes]
    # values asked (cached or not): each solved parameter point gives all its time nodes, so allow a
    # few times the tensor's count; the cost that matters is the points solved (reported)
    budget = 4 * int(np.prod(shape))
    for e in (1e-6, 1e-8, 1e-10):
        box = BlackBox(problem, axes, times)
        started = time.perf_counter()
        worst, ranks = 0.0, []
        for i, u in enumerate(problem.unknown_names):
            full, rank = cross_full(teneva, lambda I: box(i, I), shape, e, budget)  # (T, p1, p2, ...)
            ranks.append(rank)
            exact = np.moveaxis(reference[u].reshape([a.size for a in axes] + [times.size]), -1, 0)
            worst = max(worst, float(np.max(np.abs(full - exact))))
        wall = time.perf_counter() - started
        if worst <= tolerance:
            return (f"{wall:.2f} s (e = {e:.0e}, error {worst:.2g}, ranks <= {max(ranks)}, "
                    f"{box.points_solved} of {int(np.prod(shape[1:]))} points solved)")
    return f"not within the tolerance down to e = 1e-10 (error {worst:.2g}, {wall:.2f} s)"


def row(name: str) -> str:
    problem = pgdcli.load_spec(PROBLEMS[name])
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    build = time.perf_counter() - started
    cb = result.codebook
    if not result.converged or not result.accurate:
        return f"| {name} | {build:.2f} s, refused: {result.message} | | | |"
    points, times = grid_points(cb, problem)
    count = len(next(iter(points.values())))
    with threadpool_limits(1, "blas"):
        loop = time_loop(problem, points, times, False)
        vector = time_vectorized(problem, points, times)
        reference = solve_reference_vectorized(problem, points, count, times, rtol=RTOL, atol=ATOL)
        cross = teneva_cross(problem, cb, cb.report["tolerance"], reference)
    nodes = ", ".join(f"{c.name} {c.nodes}" for c in cb.coordinates)
    return (f"| {name} | {build:.2f} s, error {cb.report['check_error']:.2g} (tolerance "
            f"{cb.report['tolerance']:.0e}); nodes {nodes}; {cb.report.get('crosses', 0)} crosses | "
            f"{loop:.2f} s ({loop / build:.2g}x the build) | {vector:.2f} s ({vector / build:.2g}x) | {cross} |")


#: A 4-parameter damped pendulum (about 45 000 grid nodes): where the cross could pay off.
PENDULUM4 = """
coordinates:
  t: {domain: [0, 1]}
  L: {domain: [0.5, 2]}
  th0: {domain: [0.1, 1.5]}
  w0: {domain: [-1, 1]}
  c: {domain: [0.1, 0.5]}
constants: {grav: 9.81}
unknowns: {th: {initial: th0}, w: {initial: w0}}
equations: ["der(th) = w", "der(w) = -(grav/L)*sin(th) - c*w"]
solver: {tolerance: 1e-6}
"""


def train_march(text: str, source: str):
    """The problem of spec ``text`` marched as tensor trains (``solver.march: train``)."""
    import yaml

    data = yaml.safe_load(text)
    data.setdefault("solver", {})["march"] = "train"
    return pgdcli.parse_spec(yaml.safe_dump(data, sort_keys=False), source=source)


def evaluation_paths():
    """The tensor-train march's ways of evaluating general terms, side by side: whole grid, TT-cross,
    whole right-hand side."""
    from pgdcli.algorithms import general_rhs

    print("\n| problem | whole grid (default) | TT-cross always | whole right-hand side by the default path |")
    print("| --- | --- | --- | --- |")
    defaults = (general_rhs.DENSE_LIMIT, general_rhs.SWEEPS_PER_CROSS, general_rhs.WHOLE_RHS)
    for name, problem in (("drag3", train_march(PROBLEMS["drag3"].read_text(), "drag3.yaml")),
                          ("pendulum, 4 parameters", train_march(PENDULUM4, "pendulum4.yaml"))):
        cells = []
        for dense, sweeps, whole in (defaults, (0, 0, False), (defaults[0], defaults[1], True)):
            general_rhs.DENSE_LIMIT, general_rhs.SWEEPS_PER_CROSS, general_rhs.WHOLE_RHS = dense, sweeps, whole
            started = time.perf_counter()
            result = pgdcli.solve(problem)
            wall = time.perf_counter() - started
            rep = result.codebook.report
            cells.append(f"{wall:.1f} s, error {rep['check_error']:.2g}, {rep.get('cross_evaluations', 0):.3g} "
                         f"values, ranks <= {rep.get('cross_max_rank', 0)}")
        general_rhs.DENSE_LIMIT, general_rhs.SWEEPS_PER_CROSS, general_rhs.WHOLE_RHS = defaults
        print(f"| {name} | " + " | ".join(cells) + " |", flush=True)


def main(names):
    print("| problem | pgdcli build (gate and automatic resolution included) | loop of solve_ivp over the "
          "codebook's grid | one vectorized solve_ivp over it | teneva TT-cross over it, solve_ivp black box |")
    print("| --- | --- | --- | --- | --- |")
    for name in names:
        print(row(name), flush=True)
    if "--no-paths" not in sys.argv:
        evaluation_paths()


if __name__ == "__main__":
    with published(__file__, "Functions of the unknowns beside solve_ivp and teneva's TT-cross"):
        main([a for a in sys.argv[1:] if not a.startswith("--")] or list(PROBLEMS))

"""Codebooks at a checked tolerance on problems written without node counts, beside solve_ivp, in one run.

    python benchmarks/gate_build.py                 # the problems of DEFAULT below
    python benchmarks/gate_build.py sir damped4     # any of tests/user_problems, by name

For each problem (``tests/user_problems/<name>.yaml``: no node counts, tolerance 1e-6 or 1e-8), the
build of the codebook, ``pgdcli.solve`` (automatic resolution and the error gate included), beside
the brute-force alternatives that reach the same accuracy with the same interpolation: the grid of
the codebook's own nodes (every parameter node, every time node), filled by

- a Python loop of ``solve_ivp`` (DOP853, rtol = atol = 1e-10), one call per grid point with
  ``t_eval`` = the time nodes; a random subset of at most 200 points is timed and the time scaled;
- ONE vectorized ``solve_ivp`` call over all grid points (``pgdcli.checks.reference``'s vectorized
  right-hand side), at the same tolerances (problems with space coordinates: a method-of-lines
  sweep, pgdcli's reference at its default tolerances on the codebook's space nodes, timed on a
  subset of at most 8 parameter points and scaled; no vectorized call).

Interpolated with the codebook's own bases, such a grid is as accurate as the codebook (its nodal
values are the exact solution to the reference's accuracy), so the times compare like with like.
Sizes: the codebook file beside the grid's values (points x unknowns x time nodes x 8 bytes).
A refused problem (exit 1 of ``pgd solve``) shows its one-line reason and no grid.

The scipy runs use one BLAS thread, as the solver does. The machine is shared: every comparison is
made within this run. The table is printed and written to benchmarks/results/gate_build.md.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits

import pgdcli
from pgdcli.checks.reference import solve_reference_pde, solve_reference_vectorized

from _machine import published

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "tests" / "user_problems"
LOOP_SAMPLE = 200
RTOL = ATOL = 1e-10


def grid_points(cb, problem):
    """The codebook's parameter nodes as a flat grid (dict of (S,) arrays) and the time nodes."""
    params = [c.name for c in problem.parameter_coordinates if c.role != "space"]
    axes = [cb.coordinate(n).basis().nodes for n in params]
    mesh = np.meshgrid(*axes, indexing="ij") if axes else []
    points = {n: m.reshape(-1) for n, m in zip(params, mesh)}
    times = cb.coordinate(problem.time).basis().nodes
    return points, times


def time_loop(problem, points, times, space: dict | None):
    """Seconds for a loop of solve_ivp over all points (timed on a subset, scaled).

    ``space``: for a PDE, each space coordinate's nodes (one method-of-lines solve per point, its
    values on those nodes); None for an ODE.
    """
    size = len(next(iter(points.values()))) if points else 1
    rng = np.random.default_rng(0)
    subset = rng.choice(size, min(size, 8 if space else LOOP_SAMPLE), replace=False)
    started = time.perf_counter()
    for i in subset:
        one = {n: v[i:i + 1] for n, v in points.items()}
        if space:
            solve_reference_pde(problem, one, space, times, jobs=1)
        else:
            solve_reference_vectorized(problem, one, 1, times, rtol=RTOL, atol=ATOL)
    return (time.perf_counter() - started) * size / subset.size


def time_vectorized(problem, points, times):
    size = len(next(iter(points.values()))) if points else 1
    started = time.perf_counter()
    values = solve_reference_vectorized(problem, points, size, times, rtol=RTOL, atol=ATOL)
    wall = time.perf_counter() - started
    return wall if values is not None else float("nan")


#: As in tests/solve/test_user_problems.py: Van der Pol is refused either way, sooner with this cap.
SETTINGS = {"vanderpol": "  max_nodes: 65\n"}
# linear and polynomial ODE systems, a linear PDE; the other families have their own benchmarks
# (nonseparable.py, general_rhs.py, nonlinear_pde.py)
DEFAULT = ("damped4", "sir", "pendulum_sc", "forced_aux", "vanderpol", "advection_diffusion")


def measure(problem) -> dict:
    """Build the codebook, then fill its grid by a loop of solve_ivp and one vectorized call (seconds, sizes)."""
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    out = {"build": time.perf_counter() - started, "result": result, "cb": result.codebook}
    if not result.converged:
        return out
    cb = result.codebook
    with tempfile.TemporaryDirectory() as tmp:
        out["size"] = cb.save(Path(tmp) / "cb.h5").stat().st_size
    space = any(c.role == "space" for c in cb.coordinates)
    points, times = grid_points(cb, problem)
    out["count"] = count = len(next(iter(points.values()))) if points else 1
    with threadpool_limits(1, "blas"):
        nodes = {c.name: cb.coordinate(c.name).basis().nodes for c in cb.coordinates if c.role == "space"}
        out["loop"] = time_loop(problem, points, times, nodes if space else None)
        out["vector"] = float("nan") if space else time_vectorized(problem, points, times)
    grid_bytes = count * len(cb.unknown_names) * times.size * 8
    if space:
        grid_bytes *= int(np.prod([c.nodes for c in cb.coordinates if c.role == "space"]))
    out["grid_bytes"], out["space"] = grid_bytes, space
    out["nodes"] = ", ".join(f"{c.name} {c.nodes}" + (f" ({len(c.breakpoints) - 1} el.)" if c.breakpoints and
                                                      c.role != "time" else "") for c in cb.coordinates)
    build, vector = out["build"], out["vector"]
    out["vector_text"] = "n/a (PDE)" if space else f"{vector:.2f} s ({vector / build:.2g}x the build)"
    out["build_text"] = (f"{build:.2f} s, error {cb.report['check_error']:.2g} (tolerance "
                         f"{cb.report['tolerance']:.0e}); nodes {out['nodes']}")
    out["loop_text"] = f"{out['loop']:.2f} s ({out['loop'] / build:.2g}x the build)"
    return out


def row(name: str) -> str:
    text = (PROBLEMS / f"{name}.yaml").read_text() + SETTINGS.get(name, "")
    m = measure(pgdcli.parse_spec(text, source=f"{name}.yaml"))
    if not m["result"].converged:
        return f"| {name} | {m['build']:.2f} s, refused: {m['result'].message} | | | | |"
    return (f"| {name} | {m['build_text']} | {m['loop_text']} | {m['vector_text']} | {m['size'] / 1024:.0f} KiB | "
            f"{m['grid_bytes'] / 1024:.0f} KiB ({m['count']} grid points) |")


def print_table(names, row_of, first: str = "problem", last: str = "grid values") -> None:
    """The table's header and one row per problem (stdout, as they finish)."""
    print(f"| {first} | pgdcli build (gate and automatic resolution included) | loop of solve_ivp over the "
          f"codebook's grid | one vectorized solve_ivp over it | codebook file | {last} |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in names:
        print(row_of(name), flush=True)


def main(names):
    print_table(names, row)


if __name__ == "__main__":
    with published(__file__, "Codebooks at a checked tolerance beside solve_ivp over the same grid"):
        main(sys.argv[1:] or DEFAULT)

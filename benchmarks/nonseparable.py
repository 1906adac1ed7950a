"""Non-separable coefficients and second-order equations (issue 14, part b): build time beside scipy, in one run.

    python benchmarks/nonseparable.py                      # forced.yaml and the part-b user problems (~2-4 min)
    python benchmarks/nonseparable.py forced duffing_forced

Same conventions and table as ``benchmarks/gate_build.py`` (whose grid and timing functions are
used): the build of the codebook, ``pgdcli.solve`` (automatic resolution, the separation of the
non-separable coefficients and the error gate included), beside a loop of ``solve_ivp`` (DOP853,
1e-10, timed on at most 200 grid points and scaled) and ONE vectorized ``solve_ivp`` over the grid
of the codebook's own nodes, which interpolated with the same bases is as accurate as the codebook
(PDEs: a method-of-lines sweep, no vectorized call). The last column says how many Kronecker (or
tensor-train) terms each non-separable coefficient needed.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

import pgdcli

from _machine import machine_facts
from gate_build import grid_points, time_loop, time_vectorized

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = {"forced": ROOT / "problems" / "forced.yaml"}
PROBLEMS.update({name: ROOT / "tests" / "user_problems" / f"{name}.yaml" for name in (
    "decaying_forcing", "oscillator_rate", "saturating_relaxation", "duffing_forced", "heat_decaying_source",
    "conduction_variable")})


def row(name: str) -> str:
    problem = pgdcli.load_spec(PROBLEMS[name])
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    build = time.perf_counter() - started
    cb = result.codebook
    if not result.converged:
        return f"| {name} | {build:.2f} s, refused: {result.message} | | | | |"
    with tempfile.TemporaryDirectory() as tmp:
        size = cb.save(Path(tmp) / "cb.h5").stat().st_size
    space = any(c.role == "space" for c in cb.coordinates)
    points, times = grid_points(cb, problem)
    count = len(next(iter(points.values()))) if points else 1
    with threadpool_limits(1, "blas"):
        loop = time_loop(problem, points, times, space)
        vector = float("nan") if space else time_vectorized(problem, points, times)
    nodes = ", ".join(f"{c.name} {c.nodes}" for c in cb.coordinates)
    vec = "n/a (PDE)" if space else f"{vector:.2f} s ({vector / build:.2g}x the build)"
    separated = str(cb.report.get("separated_coefficients", "")).replace("; ", "<br>") or "none"
    method = cb.info()["method"]
    return (f"| {name} ({method}) | {build:.2f} s, error {cb.report['check_error']:.2g} (tolerance "
            f"{cb.report['tolerance']:.0e}); nodes {nodes} | {loop:.2f} s ({loop / build:.2g}x the build) | {vec} | "
            f"{size / 1024:.0f} KiB, {count} grid points | {separated} |")


def main(names):
    print(f"machine: {machine_facts()}", file=sys.stderr)
    print("| problem (solver) | pgdcli build (gate and automatic resolution included) | loop of solve_ivp over the "
          "codebook's grid | one vectorized solve_ivp over it | codebook file | non-separable coefficients |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in names:
        print(row(name), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:] or list(PROBLEMS))

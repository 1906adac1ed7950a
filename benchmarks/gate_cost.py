"""The error gate's share of a build, and its reference solved exactly or integrated, in one run.

For each shipped problem with space coordinates, builds the codebook (``pgdcli.solve``) and reads
the report's ``wall_time`` and ``gate_time`` (the error gate over all the solves). Then times the
gate's method-of-lines reference at the gate's own sample (its parameter points, its reference
nodes) two ways in the same process: as the gate computes it (a linear system whose samples share
one time-invariant operator: one eigendecomposition, split by direction on a 2-D grid when it can
be, exact in time or by exponential quadrature when the sources vary in time) and as an integration (at
the gate's rtol 1e-12 with Radau, the stiff integrator a time-dependent or nonlinear system takes),
with the largest difference between the two.

    python benchmarks/gate_cost.py [--problems heat1d heat2d ...]

The table is printed and written to benchmarks/results/gate_cost.md.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from _machine import published  # benchmarks/ is on sys.path when a script runs

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ("heat1d", "heat2d", "heat2d_source", "moving_heater", "moving_source", "poisson")


def gate_reference(cb, method):
    """``pgd verify`` as the gate runs it (its sample, times and reference nodes), with ``method``."""
    import pgdcli
    from pgdcli.checks.check import PDE_CORNERS, PDE_SAMPLES, PDE_TIMES, reference_space_nodes

    return pgdcli.verify(cb, samples=PDE_SAMPLES, seed=0, times=PDE_TIMES, max_corners=PDE_CORNERS, jobs=1,
                         rtol=1e-12, atol=1e-12, space_nodes=reference_space_nodes(cb), method=method)


def row(name: str) -> list[str]:
    import pgdcli

    problem = pgdcli.load_spec(ROOT / "problems" / f"{name}.yaml")
    result = pgdcli.solve(problem)
    rep = result.codebook.report
    wall, check = float(rep["wall_time"]), float(rep.get("gate_time", np.nan))
    build = f"{wall:.2f} s, gate {check:.2f} s ({100 * check / wall:.0f}%)"
    if problem.time is None:
        return [name, build, "steady: one sparse LU per point", "", ""]
    gate = gate_reference(result.codebook, None)
    if gate.settings["method"] == "BDF":
        return [name, build, f"BDF: {gate.wall_time:.2f} s", "(the same)", ""]
    radau = gate_reference(result.codebook, "Radau")
    diff = max(float(np.nanmax(np.abs(gate.reference[u] - radau.reference[u]))) for u in gate.reference)
    return [name, build, f"{gate.settings['method']}: {gate.wall_time:.2f} s",
            f"Radau: {radau.wall_time:.2f} s ({radau.wall_time / gate.wall_time:.1f}x)", f"{diff:.1e}"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", nargs="+", default=list(PROBLEMS), choices=PROBLEMS)
    options = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    header = ["problem", "build (error gate included)", "gate's reference at its sample",
              "the same integrated", "largest difference"]
    with published(__file__, "The error gate's share of a build; its reference exact or integrated"):
        print("| " + " | ".join(header) + " |")
        print("|" + " --- |" * len(header))
        for name in options.problems:
            print("| " + " | ".join(row(name)) + " |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

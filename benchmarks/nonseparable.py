"""Non-separable coefficients and second-order equations: build time beside scipy, in one run.

    python benchmarks/nonseparable.py                      # forced.yaml and the problems below (~2-4 min)
    python benchmarks/nonseparable.py forced duffing_forced

Same conventions and table as ``benchmarks/gate_build.py`` (whose grid and timing functions are
used, through its ``measure``): the build of the codebook, ``pgdcli.solve`` (automatic resolution, the separation of the
non-separable coefficients and the error gate included), beside a loop of ``solve_ivp`` (DOP853,
1e-10, timed on at most 200 grid points and scaled) and ONE vectorized ``solve_ivp`` over the grid
of the codebook's own nodes, which interpolated with the same bases is as accurate as the codebook
(PDEs: a method-of-lines sweep, no vectorized call). The last column says how many Kronecker (or
tensor-train) terms each non-separable coefficient needed. The table is printed and written to
benchmarks/results/nonseparable.md.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pgdcli

from _machine import published
from gate_build import measure, print_table

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = {"forced": ROOT / "problems" / "forced.yaml"}
PROBLEMS.update({name: ROOT / "tests" / "user_problems" / f"{name}.yaml" for name in (
    "forced_natural", "forced_aux", "decaying_forcing", "oscillator_rate", "saturating_relaxation", "duffing_forced", "heat_decaying_source",
    "conduction_variable")})


def row(name: str) -> str:
    m = measure(pgdcli.load_spec(PROBLEMS[name]))
    if not m["result"].converged:
        return f"| {name} | {m['build']:.2f} s, refused: {m['result'].message} | | | | |"
    cb = m["cb"]
    separated = str(cb.report.get("separated_coefficients", "")).replace("; ", "<br>") or "none"
    return (f"| {name} ({cb.info()['method']}) | {m['build_text']} | {m['loop_text']} | {m['vector_text']} | "
            f"{m['size'] / 1024:.0f} KiB, {m['count']} grid points | {separated} |")


if __name__ == "__main__":
    with published(__file__, "Non-separable coefficients and second-order equations beside solve_ivp"):
        print_table(sys.argv[1:] or list(PROBLEMS), row, "problem (solver)", "non-separable coefficients")

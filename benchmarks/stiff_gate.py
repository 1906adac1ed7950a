"""The error gate's reference on stiff and non-stiff codebooks: DOP853 always, or the method the gate chooses.

    python benchmarks/stiff_gate.py

The gate integrates its reference with scipy's DOP853 unless the problem is stiff at the check sample
(``pgdcli.checks.stiffness``: the Jacobian's fastest decay rate against the rate the solution
varies at), when it takes Radau. For each problem the codebook is built once (``pgdcli.solve``; the
RC filter with the enrichment at fixed nodes, as the automatic resolution's first solves build it),
then the gate (``check_codebook``) is timed on it twice in the same process: with DOP853 forced, and
with the method the estimate chooses (the estimate's own time, also given apart, included). Both
measure the same error: the table gives the difference between their max abs errors. A run under
2 s is repeated three times more and the median taken; longer ones run once, the chosen method
first.

- rc_filter: ``tau v1' = sin(w t) - v1``, ``v2' = (v1 - v2)/2``, tau in [1e-3, 3e-3], w in [0.5, 2],
  t in [0, 20] (decay rates up to 1e3; an explicit method is held to steps of ~1e-3);
- stiff_lowpass: ``tau v' = a cos(3t) - v`` from its slow manifold, tau in [2e-4, 4e-4] (the
  enrichment builds it within its tolerance);
- pendulum, spring: shipped non-stiff problems (the choice is DOP853: the estimate is the only cost).

The machine is shared: compare the ratios, measured in one run. The table is printed and written to
benchmarks/results/stiff_gate.md.
"""

from __future__ import annotations

import dataclasses
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _machine import cell, markdown_table, published  # noqa: E402

RC_FILTER = """
name: rc_filter
coordinates:
  t: {domain: [0, 20], nodes: 65}
  w: {domain: [0.5, 2], nodes: 17}
  tau: {domain: [0.001, 0.003], nodes: 9}
unknowns:
  v1: {initial: 1}
  v2: {initial: 0}
equations:
  - "tau*der(v1) = sin(w*t) - v1"
  - "der(v2) = 0.5*(v1 - v2)"
solver:
  method: pgd
  tolerance: 1e-6
"""

STIFF_LOWPASS = """
name: stiff_lowpass
coordinates:
  t: {domain: [0, 2]}
  tau: {domain: [0.0002, 0.0004]}
  a: {domain: [0.5, 1.5], nodes: 3}
unknowns:
  v: {initial: "a/(1 + 9*tau**2)"}
  q: {initial: 0}
equations:
  - "tau*der(v) = a*cos(3*t) - v"
  - "der(q) = v - q"
solver:
  method: pgd
  tolerance: 1e-6
"""


def problems():
    import pgdcli

    yield "rc_filter", pgdcli.parse_spec(RC_FILTER, source="rc_filter.yaml")
    yield "stiff_lowpass", pgdcli.parse_spec(STIFF_LOWPASS, source="stiff_lowpass.yaml")
    for name in ("pendulum", "spring"):
        yield name, pgdcli.load_spec(ROOT / "problems" / f"{name}.yaml")


def timed(func, repeats: int = 3):
    """``func()`` and its wall time: one run when it takes 2 s or more, else the median of ``repeats`` runs
    after it (a first call pays one-time costs: the codebook's evaluation caches, imports)."""
    start = time.perf_counter()
    value = func()
    seconds = time.perf_counter() - start
    if seconds >= 2.0:
        return value, seconds
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        func()
        runs.append(time.perf_counter() - start)
    return value, float(np.median(runs))


def row(name: str, problem) -> list[str]:
    import pgdcli
    from pgdcli.checks.check import check_codebook, reference_stiffness

    result = pgdcli.solve(problem)
    cb = result.codebook
    # no source text: the gate's reference is not reused between the two checks
    bare = dataclasses.replace(problem, source_text="")
    # the chosen method first: a first call's one-time costs count against it
    choice, seconds_estimate = timed(lambda: reference_stiffness(bare, cb))
    chosen, seconds_chosen = timed(lambda: check_codebook(bare, cb, stiff=reference_stiffness(bare, cb)))
    explicit, seconds_explicit = timed(lambda: check_codebook(bare, cb, stiff=False))
    estimate = (f"{choice.decay_rate:.3g} / {choice.stability_steps:.2g} / {choice.accuracy_steps:.2g}"
                if np.isfinite(choice.stability_steps) else choice.text())
    return [name, f"{cb.report.get('method', '?')}, {cb.coordinate(problem.time).nodes} time nodes", estimate,
            "Radau" if choice.stiff else "DOP853", f"{seconds_estimate:.2f}", f"{seconds_explicit:.2f}",
            f"{seconds_chosen:.2f}", f"{seconds_explicit / seconds_chosen:.1f}x",
            f"{abs(explicit.error - chosen.error):.1e} (of {chosen.error:.2g})"]


def main() -> int:
    from threadpoolctl import threadpool_limits

    header = ["problem", "codebook", "decay rate / stability steps / accuracy steps", "chosen", "estimate (s)",
              "DOP853 gate (s)", "chosen gate (s)", "DOP853 / chosen", "max errors differ by"]
    with published(__file__, "The error gate with DOP853 and with the method it chooses"), threadpool_limits(1):
        rows = [row(name, problem) for name, problem in problems()]
        print(markdown_table([[cell(v) for v in r] for r in rows], header))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

"""The error gate's share of every shipped problem's build, in one run.

    python benchmarks/gate_share.py                 # every problem in problems/
    python benchmarks/gate_share.py hotplate heat2d # some of them

Each problem is built from its spec by ``pgdcli.solve`` in a fresh process (its first solve; the
solver's and the gate's imports are done before the clock starts: scipy.stats, whose Sobol points
the gate of a PDE draws, alone takes about a second to import), and the codebook's report gives
the part of the build spent measuring the codebooks against the independent reference
(``gate_time``: every check of every round; the event and phase checks of ``bounce`` and
``landing`` are not in it). The gate is what makes a tolerance a promise; its share says what the
promise costs. A build past ``--timeout`` seconds is stopped and says so.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _machine import cell, published  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = sorted(p.stem for p in (ROOT / "problems").glob("*.yaml"))

_BUILD = """
import json, sys, time, numpy as np, pgdcli, pgdcli.driver, scipy.integrate
import pgdcli.checks.check, pgdcli.checks.verify, scipy.stats  # imports are not the build's, nor the gate's
problem = pgdcli.load_spec(sys.argv[1])
started = time.perf_counter()
result = pgdcli.solve(problem)
wall = time.perf_counter() - started
rep = result.codebook.report
nodes = ", ".join(f"{c.name} {c.nodes}" for c in result.codebook.coordinates)
print(json.dumps({"wall": wall, "gate": float(rep.get("gate_time", np.nan)),
                  "accurate": result.accurate, "nodes": nodes, "message": result.message[:160]}))
"""


def build(name: str, timeout: float) -> dict | None:
    """The build's report numbers, or None past ``timeout`` seconds."""
    try:
        run = subprocess.run([sys.executable, "-c", _BUILD, str(ROOT / "problems" / f"{name}.yaml")],
                             capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return None
    if run.returncode != 0:
        return {"error": (run.stderr.strip().splitlines() or ["failed"])[-1]}
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help="problems (default: every one in problems/)")
    parser.add_argument("--timeout", type=float, default=400.0, help="seconds per build (default 400)")
    options = parser.parse_args()
    unknown = sorted(set(options.names) - set(PROBLEMS))
    if unknown:
        parser.error(f"unknown problems {unknown}; choose from {', '.join(PROBLEMS)}")
    with published(__file__, "The error gate's share of each shipped problem's build"):
        print("| problem | build | error gate | gate / build | within tolerance | nodes |")
        print("| --- | --- | --- | --- | --- | --- |")
        shares = []
        for name in options.names or PROBLEMS:
            got = build(name, options.timeout)
            if got is None:
                print(f"| {name} | stopped after {options.timeout:.0f} s | | | | |", flush=True)
                continue
            if "error" in got:
                print(f"| {name} | failed: {cell(got['error'])} | | | | |", flush=True)
                continue
            share = got["gate"] / got["wall"] if got["wall"] > 0 else float("nan")
            shares.append(share)
            verdict = {True: "yes", False: "refused", None: "not checked"}[got["accurate"]]
            print(f"| {name} | {got['wall']:.2f} s | {got['gate']:.2f} s | {100 * share:.0f}% | {verdict} "
                  f"| {cell(got['nodes'])} |", flush=True)
        if shares:
            print(f"\nLargest share {100 * max(shares):.0f}%; {sum(s > 0.5 for s in shares)} of {len(shares)} "
                  f"builds spend more than half of their time in the gate.")


if __name__ == "__main__":
    main()

"""The enrichment beside the tensor-train solver on the shipped linear problems, in one run.

    python benchmarks/linear_solvers.py                       # every shipped linear problem (tens of minutes)
    python benchmarks/linear_solvers.py heat1d suspension     # some of them

Each problem is solved from its spec three times, by ``pgdcli.solve`` with ``solver.method`` set to
``pgd`` (the enrichment alone), ``amen`` (the tensor-train solver alone) and ``auto`` (the
enrichment, falling back), automatic resolution and the error gate included; each build in a fresh
process (no reference reused from another build), one run each (the builds take seconds to minutes,
so the ratio is what to read, on a shared machine). A refused
build is shown with its time and the first words of its reason. Prints the machine, the date
and the command on stderr, the table on stdout, and writes it to ``benchmarks/linear_solvers.md``
when every shipped linear problem ran.
"""

from __future__ import annotations

import dataclasses
import datetime
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import pgdcli
from pgdcli.driver import check_solvable

from _machine import machine_facts

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ROOT / "problems"


def linear_problems() -> list[str]:
    """The shipped problems that go to the linear solvers (not the march)."""
    names = []
    for path in sorted(PROBLEMS.glob("*.yaml")):
        p = pgdcli.load_spec(path)
        s = p.solver
        if not check_solvable(p, s.tolerance, s.relative_tolerance, s.max_modes):
            names.append(path.stem)
    return names


def _build(name: str, method: str) -> dict:
    """One build in this (fresh) process: seconds, and what the report says."""
    problem = pgdcli.load_spec(PROBLEMS / f"{name}.yaml")
    problem = dataclasses.replace(problem, solver=dataclasses.replace(problem.solver, method=method))
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    seconds = time.perf_counter() - started
    report = result.codebook.report
    return {"seconds": seconds, "converged": bool(result.converged), "message": result.message,
            "ratio": float(report.get("check_ratio", float("nan"))), "method": str(report.get("method", "?"))}


def build(name: str, method: str) -> dict:
    """A build in a fresh process: no reference computed by an earlier build is reused."""
    with ProcessPoolExecutor(max_workers=1, mp_context=multiprocessing.get_context("spawn")) as pool:
        return pool.submit(_build, name, method).result()


def cell(b: dict) -> str:
    if not b["converged"]:
        return f"{b['seconds']:.1f} s, refused: {' '.join(b['message'].split()[:8])}..."
    return f"{b['seconds']:.1f} s, error {b['ratio']:.2g} x tol"


def row(name: str) -> str:
    pgd, amen, auto = build(name, "pgd"), build(name, "amen"), build(name, "auto")
    return (f"| {name} | {cell(pgd)} | {cell(amen)} | {amen['seconds'] / pgd['seconds']:.2g} | "
            f"{cell(auto)}, {auto['method']} |")


def main(names: list[str]) -> None:
    command = "python benchmarks/linear_solvers.py " + " ".join(sys.argv[1:])
    head = (f"machine: {machine_facts()}\ndate: {datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC\n"
            f"command: {command.strip()}\n")
    print(head, file=sys.stderr)
    lines = ["| problem | enrichment (pgd) | tensor-train (amen) | amen / pgd time | auto, which ran |",
             "| --- | --- | --- | --- | --- |"]
    print("\n".join(lines), flush=True)
    for name in names:
        lines.append(row(name))
        print(lines[-1], flush=True)
    if set(names) >= set(linear_problems()):
        (Path(__file__).with_suffix(".md")).write_text("```\n" + head + "```\n\n" + "\n".join(lines) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:] or linear_problems())

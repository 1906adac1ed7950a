"""Builds and checks on a Dask LocalCluster of 1 and 2 workers beside the same work in this process.

    python benchmarks/cluster_scaling.py                    # rigid body 10-D build + verify at 1e4 points
    python benchmarks/cluster_scaling.py --repeats 3        # medians of 3 runs each (default 1)
    python benchmarks/cluster_scaling.py --chain            # also the 15-coordinate chain, built on 2 workers
    python benchmarks/cluster_scaling.py --problem SPEC     # another spec (a smoke run: a small one)

Configurations, in one process, interleaved run by run:

- **here**: ``pgdcli.solve`` / ``pgdcli.verify(jobs=1)`` as without a cluster (one process; verify
  also with its default pool of 2 processes, the alternative a user has today);
- **dask N**: the same with ``executor=`` a ``distributed.Client`` of a ``LocalCluster`` of N worker
  processes, one thread each (started once, before the runs; its start is reported apart).

What is distributed is measured apart from what is not: the executor is wrapped by a timer of the
time spent in its ``map``/``as_completed`` (the cross march's batches of trajectories, the
reference's chunks, from the first task out to the last result in); the rest of the wall time is
serial (the pilot march, the cross's linear algebra, the split and rounding, the error gate's
vectorized reference, verify's sampling and codebook values). Every cluster build is checked equal
to the build here, bit for bit.

The cost model for N workers: ``T(N) = S + D(1) rounds(N) / (rounds(1) e)``, with S the serial
seconds, D(1) the distributed seconds on one worker, rounds(N) the rounds of tasks on N workers
(the tasks of one call of the executor run N at a time; the calls, one core's fibres of a half sweep
each, one after another: a build cannot use more workers than a call has batches) and e the
efficiency measured from 1 to 2 workers; on this machine the client shares the 2 cores with the
workers, so e is a lower bound. The bytes of the tasks' results (the values of the trajectories
the cross uses, sent back to the calling process) are counted too. ``--chain`` also builds problems/chain15.yaml on 2 workers
and checks it with pgd verify and with solve_ivp at random points (the chain written from its
physics). The table is printed and written to
``benchmarks/results/cluster_scaling.md``.
"""

from __future__ import annotations

import argparse
import datetime as _dt
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import pgdcli
from pgdcli import executors

from _machine import machine_facts

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results" / "cluster_scaling.md"


class Timed(executors.Executor):
    """An executor's tasks, timed: seconds from a map's first task out to its last result in, and the
    tasks of every map (or as_completed) call."""

    def __init__(self, inner: executors.Executor):
        super().__init__()
        self.inner, self.workers, self.seconds, self.tasks, self.bytes = inner, inner.workers, 0.0, 0, 0
        self.calls: list[int] = []

    def submit(self, fn, *args):
        return self.inner.submit(fn, *args)

    def _timed(self, results):
        start = time.perf_counter()
        self.calls.append(0)
        try:
            for value in results:
                self.tasks += 1
                self.calls[-1] += 1
                self.bytes += getattr(value, "nbytes", 0)  # a task's result, sent back to this process
                yield value
        finally:
            self.seconds += time.perf_counter() - start

    def map(self, fn, items):
        return self._timed(self.inner.map(fn, items))

    def as_completed(self, fn, items):
        return self._timed(self.inner.as_completed(fn, items))


def same_codebook(a, b) -> bool:
    def arrays(field):
        return [np.asarray(v) for v in vars(field).values() if isinstance(v, np.ndarray)] + \
            [np.asarray(c) for v in vars(field).values() if isinstance(v, (list, tuple)) for c in v]

    return all(len(arrays(a.fields[u])) == len(arrays(b.fields[u])) and
               all(np.array_equal(x, y) for x, y in zip(arrays(a.fields[u]), arrays(b.fields[u])))
               for u in a.fields)


def timed_run(work, inner) -> dict:
    timed = Timed(inner)
    start = time.perf_counter()
    value = work(timed)
    wall = time.perf_counter() - start
    return {"wall": wall, "distributed": timed.seconds, "serial": wall - timed.seconds, "tasks": timed.tasks,
            "calls": [k for k in timed.calls if k], "bytes": timed.bytes, "value": value}


def build(problem, inner) -> dict:
    found = timed_run(lambda executor: pgdcli.solve(problem, executor=executor), inner)
    assert found["value"].converged, found["value"].message
    return found


def check(codebook, inner, points: int) -> dict:
    found = timed_run(lambda executor: pgdcli.verify(codebook, samples=points, max_corners=0, times=16,
                                                     executor=executor), inner)
    found["error"] = max(s.max_abs_error for s in found["value"].unknowns.values())
    return found


def median(runs: list[dict], key: str) -> float:
    return statistics.median(r[key] for r in runs)


def gigabytes(count: int) -> str:
    """Bytes of the tasks' results as GB ('-' where the executor hands out futures, as for verify)."""
    return f"{count / 1e9:.2f}" if count else "-"


def rounds(calls: list[int], workers: int) -> int:
    """Rounds of tasks on ``workers``: a call's tasks run ``workers`` at a time, the calls one after another."""
    return sum(-(-k // workers) for k in calls)


def table(name: str, runs: dict, here_key: str, lines: list[str], in_runs: bool) -> None:
    lines += [f"### {name}", "", "| configuration | wall s | distributed s | serial s | batches | results GB | vs here |",
              "| --- | ---: | ---: | ---: | ---: | ---: | ---: |"]
    here = median(runs[here_key], "wall")
    for label, found in runs.items():
        lines.append(f"| {label} | {median(found, 'wall'):.1f} | {median(found, 'distributed'):.1f} | "
                     f"{median(found, 'serial'):.1f} | {found[0]['tasks']} | {gigabytes(found[0]['bytes'])} | "
                     f"{here / median(found, 'wall'):.2f}x |")
    d1, d2 = median(runs["dask 1"], "distributed"), median(runs["dask 2"], "distributed")
    serial = median(runs["dask 2"], "serial")
    calls = runs["dask 1"][0]["calls"]
    # each call's tasks spread over N workers; e: the efficiency measured from 1 to 2 workers
    efficiency = min(1.0, d1 * rounds(calls, 2) / (d2 * rounds(calls, 1)))
    lines += ["", f"Distributed part, 1 -> 2 workers: {d1:.1f} s -> {d2:.1f} s, **{d1 / d2:.2f}x**; serial part "
                  f"{serial:.1f} s. The batches come in {len(calls)} calls of {min(calls)} to {max(calls)} "
                  f"(median {statistics.median(calls):.0f}); on the cluster "
                  + ("a call's batches go out as runs of consecutive batches, two tasks a worker at most"
                     if in_runs else "each batch is one task")
                  + ": a worker beyond a call's batches waits.", "",
              "Cost model T(N) = S + D(1) rounds(N) / (rounds(1) e), rounds(N) = the sum over the calls of "
              f"ceil(batches / N), e = {efficiency:.2f} measured from 1 to 2 workers:", "",
              "| workers | predicted wall s | vs here |", "| ---: | ---: | ---: |"]
    for n in (1, 2, 4, 8, 16, 64, 256):
        wall = serial + d1 * rounds(calls, n) / rounds(calls, 1) / (efficiency if n > 1 else 1.0)
        lines.append(f"| {n} | {wall:.1f} | {here / wall:.2f}x |")
    lines += [f"| limit | {serial:.1f} (the serial part) | {here / serial:.2f}x |", ""]


def chain_rhs(p: dict):
    """The chain of problems/chain15.yaml written from its physics (three bodies between two walls on
    springs of force k e + beta e^3 at extension e, damped, the first driven by A cos(2 t)), not from the
    spec: ``rhs(t, y)`` of y = (x1, x2, x3, v1, v2, v3)."""
    k, masses = np.array([p["k1"], p["k2"], p["k3"], p["k4"]]), np.array([1.0, p["m2"], 1.0])

    def rhs(t, y):
        x, v = y[:3], y[3:]
        extension = np.array([x[0], x[1] - x[0], x[2] - x[1], -x[2]])
        force = k * extension + p["beta"] * extension ** 3
        drive = np.array([p["A"] * np.cos(2.0 * t), 0.0, 0.0])
        return np.concatenate([v, (force[1:] - force[:-1] - p["c"] * v + drive) / masses])

    return rhs


def chain_against_solve_ivp(codebook, count: int, seed: int = 15) -> float:
    """Largest difference of the chain's codebook from solve_ivp (DOP853, rtol = atol = 1e-12) at
    ``count`` random points of its box, 21 times each."""
    from scipy.integrate import solve_ivp

    rng, times, worst = np.random.default_rng(seed), np.linspace(0.0, 1.0, 21), 0.0
    names = [c.name for c in codebook.coordinates if c.name != "t"]
    for _ in range(count):
        p = {n: rng.uniform(*codebook.coordinate(n).domain) for n in names}
        y0 = [p[n] for n in ("x10", "x20", "x30", "v10", "v20", "v30")]
        ref = solve_ivp(chain_rhs(p), (0.0, 1.0), y0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=times)
        got = codebook.evaluate({"t": times, **p})
        worst = max(worst, max(float(np.max(np.abs(got[u] - ref.y[i])))
                               for i, u in enumerate(("x1", "x2", "x3", "v1", "v2", "v3"))))
    return worst


def chain_lines(two) -> list[str]:
    """problems/chain15.yaml built on ``two`` workers, checked by pgd verify and by solve_ivp."""
    chain = pgdcli.load_spec(ROOT / "problems" / "chain15.yaml")
    found = build(chain, two)
    codebook = found["value"].codebook
    report = codebook.report
    verified = check(codebook, two, 1000)
    ranks = max(max(field.ranks) for field in codebook.fields.values())
    return [f"### {chain.name}: {len(chain.coordinates)} coordinates on 2 workers", "",
            f"built in {found['wall']:.0f} s ({found['distributed']:.0f} s distributed, "
            f"{report.get('cross_trajectories', 0):,} trajectories, largest rank {ranks}), max error "
            f"{report['check_error']:.2e} at the gate's {int(report['check_points'])} points (tolerance "
            f"{report['tolerance']:.0e}); pgd verify at 1,000 points: {verified['error']:.2e} in "
            f"{verified['wall']:.0f} s; solve_ivp at 200 random points: {chain_against_solve_ivp(codebook, 200):.2e}",
            ""]


def header(args, facts: dict, started: dict) -> list[str]:
    """The table's first lines: date, command, machine and its load, what was run."""
    return ["# Builds and checks on a Dask LocalCluster", "",
            f"- date: {_dt.datetime.now().isoformat(timespec='minutes')}",
            f"- command: python benchmarks/cluster_scaling.py {' '.join(sys.argv[1:])}",
            f"- machine: {facts}",
            f"- load average (1, 5, 15 min) after the runs: {' '.join(f'{x:.2f}' for x in os.getloadavg())}",
            f"- medians of {args.repeats} run(s); cluster start: {started[1]:.1f} s (1 worker), {started[2]:.1f} s "
            f"(2 workers), not counted",
            "- every cluster build equal to the build here, bit for bit; every verify's reference too", ""]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--points", type=int, default=10_000, help="verify's parameter points")
    parser.add_argument("--chain", action="store_true", help="also build problems/chain15.yaml on 2 workers")
    parser.add_argument("--problem", type=Path, default=ROOT / "problems" / "rigid_body10.yaml")
    args = parser.parse_args()
    from distributed import Client, LocalCluster

    problem = pgdcli.load_spec(args.problem)
    facts = machine_facts()
    print(f"machine: {facts}", file=sys.stderr)
    clusters, started = {}, {}
    for n in (1, 2):
        t0 = time.perf_counter()
        local = LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0",
                             silence_logs=50)
        client = Client(local)
        client.run(lambda: __import__("pgdcli.algorithms.cross_march"))  # imports done before the timing
        clusters[f"dask {n}"], started[n] = (local, client), time.perf_counter() - t0
    warm = pgdcli.solve(pgdcli.load_spec(ROOT / "problems" / "coupled.yaml"))  # imports before the timing
    pgdcli.verify(warm.codebook, samples=8, times=2, jobs=1)
    builds: dict = {"here": [], "dask 1": [], "dask 2": []}
    checks: dict = {"here, 1 process": [], "here, pool of 2": [], "dask 1": [], "dask 2": []}
    for repeat in range(args.repeats):
        builds["here"].append(build(problem, executors.SERIAL))
        for label, (_, client) in clusters.items():
            builds[label].append(build(problem, executors.as_executor(client)))
            assert same_codebook(builds[label][-1]["value"].codebook, builds["here"][0]["value"].codebook)
        codebook = builds["here"][0]["value"].codebook
        checks["here, 1 process"].append(check(codebook, executors.SERIAL, args.points))
        with executors.ProcessExecutor(2) as pool:
            checks["here, pool of 2"].append(check(codebook, pool, args.points))
        for label, (_, client) in clusters.items():
            checks[label].append(check(codebook, executors.as_executor(client), args.points))
        for runs in (builds, checks):
            print({k: round(v[-1]["wall"], 1) for k, v in runs.items()}, file=sys.stderr)
    here_check = checks["here, 1 process"][0]["value"]
    for label in checks:
        for u in here_check.reference:
            assert np.array_equal(checks[label][0]["value"].reference[u], here_check.reference[u]), label
    lines = header(args, facts, started)
    result = builds["here"][0]["value"]
    table(f"Build of {problem.name} ({len(problem.coordinates)} coordinates, "
          f"{result.codebook.report.get('cross_trajectories', 0):,} trajectories)", builds, "here", lines, in_runs=True)
    table(f"pgd verify at {args.points:,} parameter points x {len(here_check.times)} times "
          f"(max error {checks['dask 2'][0]['error']:.2e})", checks, "here, 1 process", lines, in_runs=False)
    if args.chain:
        lines += chain_lines(executors.as_executor(clusters["dask 2"][1]))
    for local, client in clusters.values():
        client.close()
        local.close()
    text = "\n".join(lines)
    print(text)
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text(text + "\n")


if __name__ == "__main__":
    main()

"""Speed of the time marches (grid, cross, train) before and after a change, side by side in one process.

    python benchmarks/march_speed.py --before /tmp/pgd_before/pgdcli [--repeats 3] [--out table.md]
    python benchmarks/march_speed.py --integrators          # DOP853 against bs32, this checkout only

With ``--before`` (a checkout's package folder, loaded as ``pgdcli_before`` beside the installed
``pgdcli``), each march of problems/rigid_body.yaml, problems/coupled.yaml and a pendulum with its
general term ``sin(th)`` is timed with both versions on the same compiled system, alternating run by
run after a warm-up (medians; the solve's check and codebook are not included), and the codebook
trains of the two are compared (largest difference of their values at 2000 random grid nodes;
0 means the same arithmetic). With ``--integrators``, the grid march of each problem with each
stepper of ``solver.integrator`` at the march targets 1e-4 and 1e-6 (coupled, the pendulum,
problems/logistic.yaml): steps, time, and the error at the grid nodes against scipy's ``solve_ivp``
(DOP853, rtol = atol = 1e-12) at 40 random nodes.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _machine import machine_facts  # noqa: E402
from layout_speed import load_before  # noqa: E402

PENDULUM = """
name: pendulum_grid
coordinates:
  t: {domain: [0, 3], nodes: 8}
  L: {domain: [0.5, 2], nodes: 32}
  th0: {domain: [0.1, 2.5], nodes: 32}
constants: {grav: 9.81}
unknowns:
  th: {initial: th0}
  w: {initial: 0}
equations:
  - "der(th) = w"
  - "der(w) = -(grav/L)*sin(th)"
solver:
  tolerance: 1e-6
"""
# (name, marches timed): the train march (its state at the end compared) only where it takes seconds
CASES = (("rigid_body", ("grid", "cross")), ("coupled", ("grid", "cross", "train")), ("pendulum", ("grid", "cross")))
# the integrators' comparison: grids the grid march takes in seconds
INTEGRATOR_CASES = ("coupled", "pendulum", "logistic")
INTEGRATOR_TOLERANCES = (1e-4, 1e-6)  # the grid march's (RMS) target
CLOCK = time.process_time
TARGET = 0.7  # the march's first target, as a share of the tolerance (the solve's CHECK_FIRST)


def problem_of(package, name: str):
    if name == "pendulum":
        return package.parse_spec(PENDULUM, source="pendulum_grid.yaml")
    return package.load_spec(ROOT / "problems" / f"{name}.yaml")


def march_runner(package, name: str, march: str, stepper=None):
    """``run() -> list of trains`` for one march of one problem with one version of the package."""
    from importlib import import_module

    algorithms = import_module(f"{package.__name__}.algorithms")
    cross_march = import_module(f"{algorithms.__name__}.cross_march")
    grid_march = import_module(f"{algorithms.__name__}.grid_march")
    march_module = import_module(f"{algorithms.__name__}.march")
    problem = problem_of(package, name)
    tolerance = TARGET * problem.solver.tolerance
    system = march_module.compile_system(problem, tolerance)
    slab_nodes = problem.time_coordinate.nodes
    delta = 0.1 * tolerance * np.sqrt(float(np.prod(system.shape)))
    extra = {} if stepper is None else {"stepper": stepper}
    if march == "grid":
        return lambda: grid_march.march_on_grid(system, tolerance, delta, slab_nodes=slab_nodes, **extra).trains
    if march == "cross":
        return lambda: cross_march.march_by_cross(system, tolerance, delta, slab_nodes=slab_nodes, **extra).trains
    return lambda: march_module.march(system, tolerance, slab_nodes=slab_nodes, **extra).states[-1]


def alternate(runs: dict, repeats: int) -> tuple[dict, dict]:
    """``({label: median seconds}, {label: last result})``, the labels' runs interleaved.

    Seconds of the process's CPU time (:data:`CLOCK`): the marches run on one BLAS thread, and on a
    shared machine the wall-clock time measures the other work as much as this one.
    """
    times = {label: [] for label in runs}
    results = {label: run() for label, run in runs.items()}  # warm-up
    for i in range(repeats):
        order = list(runs.items()) if i % 2 == 0 else list(runs.items())[::-1]
        for label, run in order:
            start = CLOCK()
            results[label] = run()
            times[label].append(CLOCK() - start)
    return {label: statistics.median(v) for label, v in times.items()}, results


def difference(a, b) -> float:
    """Largest difference of two lists of trains (one per unknown) at random grid nodes."""
    rng = np.random.default_rng(0)
    worst = 0.0
    for ta, tb in zip(a, b):
        idx = [rng.integers(0, c.shape[1], 2000) for c in ta.cores]
        values = [np.array([_at(t, [i[k] for i in idx]) for k in range(2000)]) for t in (ta, tb)]
        worst = max(worst, float(np.max(np.abs(values[0] - values[1]))))
    return worst


def _at(train, index) -> float:
    vector = np.ones(1)
    for core, i in zip(train.cores, index):
        vector = vector @ core[:, i, :]
    return float(vector[0])


def compare_versions(before, after, repeats: int) -> list[str]:
    rows = ["| problem | march | before | after | after/before | max abs difference |", "|---|---|---|---|---|---|"]
    for name, marches in CASES:
        for march in marches:
            runs = {"before": march_runner(before, name, march), "after": march_runner(after, name, march)}
            medians, results = alternate(runs, repeats)
            rows.append(f"| {name} | {march} | {medians['before']:.3f} s | {medians['after']:.3f} s | "
                        f"{medians['after'] / medians['before']:.3f} | "
                        f"{difference(results['before'], results['after']):.1e} |")
            print(rows[-1], flush=True)
    return rows


def compare_integrators(package, repeats: int) -> list[str]:
    from pgdcli.algorithms.steppers import METHODS

    rows = ["| problem | march target | integrator | steps | grid march | error at 40 nodes |", "|---|---|---|---|---|---|"]
    for name in INTEGRATOR_CASES:
        for tolerance in INTEGRATOR_TOLERANCES:
            for key, method in METHODS.items():
                row = _integrator_row(package, name, tolerance, method(), repeats)
                rows.append(row)
                print(row, flush=True)
    return rows


def _integrator_row(package, name: str, tolerance: float, stepper, repeats: int) -> str:
    from scipy.integrate import solve_ivp

    from pgdcli.algorithms.grid_march import march_on_grid
    from pgdcli.algorithms.grid_steps import GridMarchFailure, GridRhs, initial_values
    from pgdcli.algorithms.march import compile_system

    problem = problem_of(package, name)
    system = compile_system(problem, tolerance)
    delta = 0.1 * tolerance * np.sqrt(float(np.prod(system.shape)))
    holder = {}

    def run():
        holder["result"] = march_on_grid(system, tolerance, delta, slab_nodes=problem.time_coordinate.nodes,
                                         stepper=stepper)

    try:
        medians, _ = alternate({"run": run}, repeats)
    except GridMarchFailure as failure:
        return f"| {name} | {tolerance:.0e} | {stepper.name} | {failure} | | |"
    result = holder["result"]
    rng = np.random.default_rng(1)
    nodes = np.stack([rng.integers(0, n, 40) for n in system.shape], axis=1)
    rhs, y0 = GridRhs(system, nodes), initial_values(system, nodes)
    reference = [solve_ivp(lambda t, y, k=k: _one_node(rhs, k, t, y), (result.times[0], result.times[-1]), y0[:, k],
                           method="DOP853", rtol=1e-12, atol=1e-12, t_eval=result.times).y for k in range(40)]
    got = [np.array([_time_series(train, node) for train in result.trains]) for node in nodes]
    error = max(float(np.max(np.abs(g - r))) for g, r in zip(got, reference))
    return (f"| {name} | {tolerance:.0e} | {stepper.name} | {result.steps} | {medians['run']:.3f} s | "
            f"{error:.1e} |")


def _time_series(train, node) -> np.ndarray:
    """A space-time train's values at all its times (first mode) and one grid node."""
    vector = np.ones(1)
    for core, i in zip(train.cores[:0:-1], node[::-1]):
        vector = core[:, i, :] @ vector
    return train.cores[0][0] @ vector


def _one_node(rhs, k: int, t: float, y: np.ndarray) -> np.ndarray:
    """The right-hand side at node ``k`` of a GridRhs over a batch, for one state."""
    Y = np.zeros((len(y), len(rhs.indices)))
    Y[:, k] = y
    return rhs(t, Y)[:, k]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, help="the package folder of the version before")
    parser.add_argument("--integrators", action="store_true", help="compare the steppers of this checkout")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--out", type=Path, help="also write the table (Markdown) here")
    options = parser.parse_args()
    if not options.before and not options.integrators:
        parser.error("give --before PATH or --integrators")
    sys.path.insert(0, str(ROOT))
    from threadpoolctl import threadpool_limits

    import pgdcli as after

    facts = machine_facts()
    header = [f"machine: {facts['processor']}, {facts['cpus']} CPUs, load {facts['load']}, numpy {facts['numpy']}, "
              f"scipy {facts['scipy']}, {facts['blas']}", f"date: {datetime.date.today()}",
              "times: medians of the process's CPU time, BLAS on one thread",
              f"command: python benchmarks/march_speed.py {' '.join(sys.argv[1:])}", ""]
    print("\n".join(header), flush=True)
    with threadpool_limits(1):  # as the solve does
        if options.before:
            rows = compare_versions(load_before(options.before), after, options.repeats)
        else:
            rows = compare_integrators(after, options.repeats)
    if options.out:
        options.out.write_text("\n".join(header + rows) + "\n")


if __name__ == "__main__":
    main()

"""Sobol indices of shipped nonlinear problems: the codebook's exact ones beside sampling estimates, in one run.

    python benchmarks/sensitivity_speed.py             # logistic, pendulum, drag, rigid body (~10 minutes)
    python benchmarks/sensitivity_speed.py --quick     # 2^12 base samples only
    python benchmarks/sensitivity_speed.py --problems pendulum --samples 12,14,16

Solves each problem into a temporary directory (its solve time is reported apart: it is paid
once), then at the same times:

- **pgdcli**: ``Codebook.sensitivity`` (first-order and total indices of every input, every
  unknown), median of 7 runs;
- **scipy**: ``scipy.stats.sobol_indices`` on the problem integrated by ``solve_ivp``
  (``pgdcli.checks.reference.solve_reference``: DOP853, rtol 1e-10, every sample of a chunk in
  one vectorized call, the fastest way to run it here), n (d + 2) model runs for 2^m base samples;
- **SALib** (when installed, the ``benchmark`` extra): Saltelli sampling and ``sobol.analyze``
  on the same model, n (d + 2) runs (first and total order only).

Each sampling row gives its time, the time ratio to pgdcli, and the largest difference of its
indices from the exact ones (their sampling error: it halves for 4x the samples). The machine
may be shared: times are medians within this run, and ratios compare runs made side by side.
Prints a Markdown table (docs/sensitivity.md quotes it); ``--output FILE`` also writes it.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from _machine import markdown_table, median_seconds, report  # benchmarks/ is on sys.path

ROOT = Path(__file__).resolve().parents[1]
TIMES = {"logistic": [0.5, 1.0, 2.0], "pendulum": [0.5, 1.5, 3.0], "drag": [0.5, 1.0, 2.0],
         "coupled": [0.1, 0.25, 0.5], "rigid_body": [0.25, 0.5, 1.0]}


def fmt_time(seconds: float) -> str:
    if seconds < 1:
        return f"{seconds * 1e3:.1f} ms"
    if seconds < 120:
        return f"{seconds:.2f} s"
    return f"{seconds / 60:.1f} min"


def model_of(cb, inputs, times):
    """(d, n) inputs -> (outputs, n): every unknown at every time, by solve_ivp (the independent reference)."""
    from pgdcli.checks.reference import solve_reference
    from pgdcli.problem.spec import parse_spec

    problem = parse_spec(cb.spec_text, source=cb.name)

    def model(x):
        result = solve_reference(problem, dict(zip(inputs, x)), np.asarray(times, dtype=float), rtol=1e-10,
                                 atol=1e-12)
        if not np.all(result.success):
            raise SystemExit(f"{cb.name}: the reference failed at some samples")
        return np.concatenate([result.values[u].T for u in cb.unknown_names])

    return model


def scipy_run(model, domains, n):
    from scipy import stats

    result = stats.sobol_indices(func=model, n=n, rng=np.random.default_rng(1),
                                 dists=[stats.uniform(lo, hi - lo) for lo, hi in domains])
    return result.first_order, result.total_order


def salib_run(model, inputs, domains, n):
    from SALib.analyze import sobol as analyze
    from SALib.sample import sobol as sample

    problem = {"num_vars": len(inputs), "names": list(inputs), "bounds": [list(d) for d in domains]}
    x = sample.sample(problem, n, calc_second_order=False, seed=1)
    y = model(x.T)  # (outputs, samples)
    first, total = [], []
    for row in y:
        s = analyze.analyze(problem, row, calc_second_order=False, seed=1)
        first.append(s["S1"])
        total.append(s["ST"])
    return np.array(first), np.array(total)


def measure(name: str, directory: Path, exponents: list[int], rows: list) -> None:
    import pgdcli

    start = time.perf_counter()
    result = pgdcli.solve(pgdcli.load_spec(ROOT / "problems" / f"{name}.yaml"))
    solve_time = time.perf_counter() - start
    cb = result.codebook
    times = TIMES[name]
    exact = cb.sensitivity(times=times)
    ours = median_seconds(lambda: cb.sensitivity(times=times), 7)
    first = np.concatenate([exact.first[u] for u in cb.unknown_names])
    total = np.concatenate([exact.total[u] for u in cb.unknown_names])
    label = f"{name} ({len(exact.inputs)} inputs, {len(cb.unknown_names)} unknowns, {len(times)} times)"
    rows.append((label, "pgdcli: Codebook.sensitivity (exact)", "-", fmt_time(ours), "1", "0",
                 f"solve once: {fmt_time(solve_time)}"))
    model = model_of(cb, exact.inputs, times)
    domains = [cb.coordinate(n).domain for n in exact.inputs]
    d = len(exact.inputs)
    for m in exponents:
        n = 2**m
        start = time.perf_counter()
        f, t = scipy_run(model, domains, n)
        elapsed = time.perf_counter() - start
        error = max(np.max(np.abs(f - first)), np.max(np.abs(t - total)))
        rows.append((label, f"scipy.stats.sobol_indices on solve_ivp, n = 2^{m}", f"{n * (d + 2)}", fmt_time(elapsed),
                     f"{elapsed / ours:.0f}", f"{error:.1e}", ""))
        try:
            start = time.perf_counter()
            f, t = salib_run(model, exact.inputs, domains, n)
            elapsed = time.perf_counter() - start
        except ImportError:
            continue
        error = max(np.max(np.abs(f - first)), np.max(np.abs(t - total)))
        rows.append((label, f"SALib Saltelli + sobol.analyze on solve_ivp, n = 2^{m}", f"{n * (d + 2)}",
                     fmt_time(elapsed), f"{elapsed / ours:.0f}", f"{error:.1e}", ""))
    print(f"{name}: done", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--problems", default="logistic,pendulum,drag,rigid_body")
    parser.add_argument("--samples", default="12,14", help="exponents m of the 2^m base samples")
    parser.add_argument("--quick", action="store_true", help="2^12 base samples only")
    parser.add_argument("--output", type=Path, help="also write the table to this file")
    args = parser.parse_args()
    exponents = [12] if args.quick else [int(m) for m in args.samples.split(",")]
    rows: list = []
    with tempfile.TemporaryDirectory() as directory:
        for name in args.problems.split(","):
            measure(name, Path(directory), exponents, rows)
    header = ("problem", "method", "model runs", "time", "x pgdcli", "max |index - exact|", "note")
    report("sensitivity_speed.py", markdown_table(rows, header), output=args.output)


if __name__ == "__main__":
    main()

"""Speed of the package before and after a reorganization, side by side in one process.

    python benchmarks/layout_speed.py --before /tmp/pgd_before/src/pgdcli [--repeats 5]

Loads a second copy of the package from ``--before`` (a checkout's package folder) under the name
``pgdcli_before`` next to the installed ``pgdcli``, and times the same work with both, alternating
run by run after one warm-up run each, in alternating order (medians): the build of problems/coupled.yaml and problems/logistic.yaml (tensor-train
march + check) and problems/spring.yaml (PGD enrichment + check), and on the codebook each built
(loaded by both versions from the same file): one point in-process, a batch of 1e5 random points,
``evaluate_grid`` on ~1e6 points. A reorganization that keeps the numerics should give ratios near 1
(the machine is shared and noisy; only a ratio far from 1 in both directions of a rerun means
something). Also checks that both give the same values (max abs difference).
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
PROBLEMS = ("coupled", "logistic", "spring")


def load_before(folder: Path):
    spec = importlib.util.spec_from_file_location("pgdcli_before", folder / "__init__.py",
                                                  submodule_search_locations=[str(folder)])
    module = importlib.util.module_from_spec(spec)
    sys.modules["pgdcli_before"] = module
    spec.loader.exec_module(module)
    return module


def alternate(runs: dict, repeats: int) -> dict:
    """``{label: median seconds}``, the labels' runs interleaved so that load drifts hit all alike."""
    times = {label: [] for label in runs}
    for run in runs.values():  # warm-up: imports, caches
        run()
    for i in range(repeats):
        order = list(runs.items()) if i % 2 == 0 else list(runs.items())[::-1]  # neither always first
        for label, run in order:
            t = time.perf_counter()
            run()
            times[label].append(time.perf_counter() - t)
    return {label: statistics.median(v) for label, v in times.items()}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True, help="the package folder of the version before")
    parser.add_argument("--repeats", type=int, default=5)
    options = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    import pgdcli as after

    before = load_before(options.before)
    versions = {"before": before, "after": after}
    rows = []
    rng = np.random.default_rng(0)
    with tempfile.TemporaryDirectory(prefix="pgd-layout-") as tmp:
        for name in PROBLEMS:
            path = ROOT / "problems" / f"{name}.yaml"
            builds = alternate({k: (lambda v=v: v.solve(v.load_spec(path))) for k, v in versions.items()},
                               options.repeats)
            rows.append((name, "build (solve + check), median", builds))
            out = Path(tmp) / f"{name}.h5"
            after.solve(after.load_spec(path)).codebook.save(out)
            books = {k: v.Codebook.load(out) for k, v in versions.items()}
            cb = books["after"]
            lows = np.array([c.domain[0] for c in cb.coordinates])
            highs = np.array([c.domain[1] for c in cb.coordinates])
            point = {c.name: float(x) for c, x in zip(cb.coordinates, (lows + highs) / 2)}
            batch = {c.name: rng.uniform(lo, hi, 100_000) for c, lo, hi in zip(cb.coordinates, lows, highs)}
            per_axis = max(2, int(round(1e6 ** (1 / len(cb.coordinates)))))
            axes = {c.name: np.linspace(lo, hi, per_axis) for c, lo, hi in zip(cb.coordinates, lows, highs)}

            def one_point(b):
                for _ in range(200):
                    b(**point)

            rows.append((name, "200 single points in-process", alternate(
                {k: (lambda b=b: one_point(b)) for k, b in books.items()}, options.repeats)))
            rows.append((name, "batch of 1e5 random points", alternate(
                {k: (lambda b=b: b.evaluate(batch)) for k, b in books.items()}, options.repeats)))
            rows.append((name, f"evaluate_grid {per_axis}^{len(axes)} points", alternate(
                {k: (lambda b=b: b.evaluate_grid(axes)) for k, b in books.items()}, options.repeats)))
            diff = max(float(np.max(np.abs(books["after"].evaluate(batch)[u] - books["before"].evaluate(batch)[u])))
                       for u in cb.unknown_names)
            rows.append((name, "max |after - before| over the batch", {"before": diff, "after": diff}))
    print("| problem | measure | before | after | after/before |")
    print("|---|---|---|---|---|")
    for name, what, t in rows:
        if what.startswith("max |"):
            print(f"| {name} | {what} | | {t['after']:.1e} | |")
            continue
        print(f"| {name} | {what} | {t['before'] * 1e3:.1f} ms | {t['after'] * 1e3:.1f} ms | "
              f"{t['after'] / t['before']:.2f} |")


if __name__ == "__main__":
    main()

"""Speed of the problem layer and the linear PGD solver before and after a reorganization, side by side.

    python benchmarks/problem_layer_speed.py --before /tmp/pgd_before/pgdcli [--repeats 7]

Loads a second copy of the package from ``--before`` (a checkout's package folder) under the name
``pgdcli_before`` next to the installed ``pgdcli`` (as ``layout_speed.py`` does) and times, alternating
run by run after a warm-up (medians):

- ``parse_spec`` of every shipped problem (the parse stage of ``pgd solve``), all problems per run;
- for the shipped problems the linear PGD solver takes: ``discretize`` (``discretization/linear.py``)
  and ``run_enrichment`` (``algorithms/enrichment.py``) at the spec's nodes (or the automatic first
  ones) and tolerance, without the check.

Also checks that both versions give the same residual history (max relative difference).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

import threadpoolctl

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from layout_speed import alternate, load_before  # noqa: E402

LINEAR = ("relaxation", "spring", "parametric", "forced", "heat1d", "heat2d", "heat2d_source", "poisson")


def modules(prefix: str):
    spec = importlib.import_module(f"{prefix}.problem.spec")
    linear = importlib.import_module(f"{prefix}.discretization.linear")
    enrichment = importlib.import_module(f"{prefix}.algorithms.enrichment")
    return spec, linear, enrichment


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--before", type=Path, required=True, help="the package folder of the version before")
    parser.add_argument("--repeats", type=int, default=7)
    options = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    load_before(options.before)
    versions = {"before": modules("pgdcli_before"), "after": modules("pgdcli")}
    texts = {path.stem: path.read_text() for path in sorted((ROOT / "problems").glob("*.yaml"))}

    def parse_all(spec):
        for name, text in texts.items():
            spec.parse_spec(text, source=f"problems/{name}.yaml", name=name)

    rows = [("all shipped problems", f"parse_spec x {len(texts)}", alternate(
        {k: (lambda m=m: parse_all(m[0])) for k, m in versions.items()}, options.repeats))]
    with threadpoolctl.threadpool_limits(1):  # as pgdcli.solve runs the solver
        for name in LINEAR:
            if name not in texts:
                continue
            problems = {k: m[0].parse_spec(texts[name], source=name, name=name) for k, m in versions.items()}
            rows.append((name, "discretize", alternate(
                {k: (lambda m=m, p=problems[k]: m[1].discretize(p)) for k, m in versions.items()}, options.repeats)))
            discs = {k: m[1].discretize(problems[k]) for k, m in versions.items()}
            opts = problems["after"].solver
            runs = {k: (lambda m=m, d=discs[k]: m[2].run_enrichment(d, opts, opts.tolerance, opts.max_modes, None))
                    for k, m in versions.items()}
            rows.append((name, "run_enrichment", alternate(runs, options.repeats)))
            histories = {k: run()[1] for k, run in runs.items()}
            same = len(histories["before"]) == len(histories["after"])
            diff = max(abs(a - b) / max(abs(b), 1e-300) for a, b in zip(histories["after"], histories["before"]))
            rows.append((name, f"residual history: {len(histories['after'])} values, "
                               f"{'same length' if same else 'LENGTHS DIFFER'}, max rel diff", diff))
    print("| problem | measure | before | after | after/before |")
    print("|---|---|---|---|---|")
    for name, what, t in rows:
        if not isinstance(t, dict):
            print(f"| {name} | {what} | | {t:.1e} | |")
            continue
        print(f"| {name} | {what} | {t['before'] * 1e3:.1f} ms | {t['after'] * 1e3:.1f} ms | "
              f"{t['after'] / t['before']:.2f} |")


if __name__ == "__main__":
    main()

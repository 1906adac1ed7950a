"""Regenerate the documentation's pictures: docs/figures/<kind>.png and docs/figures/fit.png.

    python docs/figures/make_figures.py        # needs the plot extra: pip install -e '.[plot]'

Solves the problems it needs into a temporary directory (problems/spring.yaml and the fitting
tutorial's docs/examples/enzyme.yaml, some seconds), then draws one picture of each kind of
``pgd plot`` with its code path (:func:`pgdcli.plot.files.render`), and the fitting tutorial's fit
of a synthetic progress curve with ``pgd fit --plot``'s (:func:`pgdcli.inference.report.plot_fit`).
The equivalent commands are printed as it goes.
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
DPI = 100

# kind -> (problem, pgd plot options as render() keywords)
FIGURES = {
    "modes": ("spring", {"count": 6}),
    "convergence": ("spring", {}),
    "solution": ("spring", {"at": ["k=1,c=0.1", "k=2.5", "k=4,c=0.5"], "reference": True}),
    "error": ("spring", {"over": "t,k"}),
}


def _command(problem: str, kind: str, options: dict) -> str:
    parts = [f"pgd plot codebooks/{problem}.h5 --kind {kind}"]
    for key, value in options.items():
        if value is True:
            parts.append(f"--{key}")
        elif isinstance(value, list):
            parts.extend(f"--{key} {v}" for v in value)
        else:
            parts.append(f"--{key} {value}")
    parts.append(f"--dpi {DPI} -o docs/figures/{kind}.png")
    return " ".join(parts)


def main() -> int:
    from pgdcli import load_spec, solve
    from pgdcli.plot.files import render

    with tempfile.TemporaryDirectory(prefix="pgd-figures-") as tmp:
        codebooks: dict[str, Path] = {}
        for kind, (problem, options) in FIGURES.items():
            if problem not in codebooks:
                started = time.perf_counter()
                result = solve(load_spec(ROOT / "problems" / f"{problem}.yaml"))
                if not result.converged:
                    print(f"error: {problem}: {result.message}", file=sys.stderr)
                    return 1
                codebooks[problem] = result.codebook.save(Path(tmp) / f"{problem}.h5")
                print(f"solved {problem} in {time.perf_counter() - started:.1f} s", file=sys.stderr)
            print(_command(problem, kind, options), file=sys.stderr)
            path = render(codebooks[problem], kind, HERE / f"{kind}.png", dpi=DPI,
                          warn=lambda m: print(f"warning: {m}", file=sys.stderr), **options)
            print(path)
    print(fit_figure())
    return 0


def fit_figure() -> Path:
    """The fitting tutorial's picture: its codebook, its data (seed 0) and its fit."""
    import importlib.util

    import numpy as np
    from pgdcli import fit, load_spec, solve
    from pgdcli.inference.report import plot_fit

    examples = ROOT / "docs" / "examples"
    spec = importlib.util.spec_from_file_location("enzyme_data", examples / "enzyme_data.py")
    data_module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(data_module)
    result = solve(load_spec(examples / "enzyme.yaml"))
    if not result.converged:
        raise SystemExit(f"enzyme: {result.message}")
    times = np.linspace(0.0, 10.0, 21)
    s = data_module.progress_curve(1.2, 2.0, 8.0, times) + np.random.default_rng(0).normal(0.0, 0.05, times.size)
    print("python docs/examples/enzyme_data.py > progress.csv", file=sys.stderr)
    print("pgd fit codebooks/enzyme.h5 progress.csv --sigma s=0.05 --plot docs/figures/fit.png", file=sys.stderr)
    return plot_fit(fit(result.codebook, {"t": times, "s": s}, sigma={"s": 0.05}), HERE / "fit.png", dpi=DPI)


if __name__ == "__main__":
    sys.exit(main())

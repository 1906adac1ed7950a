"""Regenerate the README's pictures of ``pgd plot``: docs/figures/<kind>.png.

    python docs/figures/make_figures.py

Solves the shipped problems it needs into a temporary directory (a few
seconds), then draws one picture of each kind with the same code path as
``pgd plot`` (:func:`pgdcli.plot.figures.render`). The equivalent commands are
printed as it goes.
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
    from pgdcli.plot.figures import render

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
    return 0


if __name__ == "__main__":
    sys.exit(main())

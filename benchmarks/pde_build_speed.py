"""Build time of the 2D heat codebook beside a sweep of method-of-lines solves, in one run.

Solves problems/heat2d.yaml (x, y space; t; kappa, g, q parameters) into a codebook (median of 3
builds) and, in the same run, times the alternative a user would otherwise run: one method-of-lines
solve (``pgdcli.checks.reference.solve_reference_pde``: strong-form Chebyshev collocation on the same
number of nodes per space coordinate as the codebook, BDF at rtol 1e-8) per point of the
parameter grid (the codebook's kappa x g x q nodes), storing the solution at the codebook's time
nodes. A seeded subset of the grid is timed and scaled (printed). Both are checked against the
exact solution at random points (the MOL sweep through its own interpolation at the nodes of
its grid); sizes: codebook floats vs the grid's values (x nodes x y nodes x t nodes x grid points).

    python benchmarks/pde_build_speed.py [--subset N]

The table is printed and written to benchmarks/results/pde_build_speed.md.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def exact(x, y, t, k, g, q):
    return (g * x + np.exp(-2 * k * np.pi**2 * t) * np.sin(np.pi * x) * np.cos(np.pi * y)
            + q * (1 - np.exp(-k * np.pi**2 * t)) * np.sin(np.pi * x) / (k * np.pi**2))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--subset", type=int, default=8, help="grid points timed for the sweep (default 8)")
    options = parser.parse_args()
    sys.path.insert(0, str(ROOT))
    import pgdcli
    from pgdcli.checks.reference import solve_reference_pde

    problem = pgdcli.load_spec(ROOT / "problems" / "heat2d.yaml")
    builds, result = [], None
    for _ in range(3):
        t0 = time.perf_counter()
        result = pgdcli.solve(problem)
        builds.append(time.perf_counter() - t0)
    build = statistics.median(builds)
    cb = result.codebook
    nodes = {c.name: c.basis().nodes for c in cb.coordinates}
    grid = np.array(np.meshgrid(nodes["kappa"], nodes["g"], nodes["q"], indexing="ij")).reshape(3, -1)
    n_grid = grid.shape[1]
    rng = np.random.default_rng(0)
    pick = rng.choice(n_grid, size=min(options.subset, n_grid), replace=False)
    params = {"kappa": grid[0, pick], "g": grid[1, pick], "q": grid[2, pick]}
    t0 = time.perf_counter()
    ref = solve_reference_pde(problem, params, None, nodes["t"], space_nodes={"x": nodes["x"].size, "y": nodes["y"].size},
                              rtol=1e-8, atol=1e-10, jobs=1)
    per_point = (time.perf_counter() - t0) / pick.size
    sweep = per_point * n_grid
    # accuracy at the reference's own nodes (its grid), at the timed grid points
    xs, ys = ref.space_points["x"], ref.space_points["y"]
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    err_mol = err_pgd = 0.0
    for s in range(pick.size):
        k, g, q = grid[:, pick[s]]
        for i, t in enumerate(nodes["t"]):
            truth = exact(X, Y, t, k, g, q)
            err_mol = max(err_mol, float(np.max(np.abs(ref.values["u"][s, i] - truth))))
            err_pgd = max(err_pgd, float(np.max(np.abs(cb(x=X, y=Y, t=t, kappa=k, g=g, q=q)["u"] - truth))))
    p = {c.name: rng.uniform(*c.domain, 20000) for c in cb.coordinates}
    err_random = float(np.max(np.abs(cb(**p)["u"] - exact(p["x"], p["y"], p["t"], p["kappa"], p["g"], p["q"]))))
    floats = sum(m.size for m in cb.fields["u"].factors) + cb.fields["u"].weights.size
    grid_values = nodes["x"].size * nodes["y"].size * nodes["t"].size * n_grid
    rows = [
        ("build: solve(heat2d.yaml), median of 3", f"{build:.2f} s", f"MOL sweep over {n_grid} grid points: "
         f"{sweep:.1f} s ({per_point:.2f} s per point, {pick.size} timed)", f"{sweep / build:.1f}x", ">= 100x",
         "yes" if sweep / build >= 100 else "NO"),
        ("max abs error vs exact, at the timed grid points x t nodes", f"{err_pgd:.2e}", f"MOL: {err_mol:.2e}", "", "", ""),
        ("max abs error vs exact, 20000 random points", f"{err_random:.2e}", "", "", "<= 1e-8",
         "yes" if err_random <= 1e-8 else "NO"),
        ("size: codebook floats vs grid values", f"{floats}", f"{grid_values}", f"{100 * floats / grid_values:.2f}%",
         "", ""),
        ("modes", f"{cb.fields['u'].rank}", "", "", "", ""),
    ]
    header = ("measure", "pgdcli", "beside (same run)", "ratio", "target", "met")
    widths = [max(len(str(r[i])) for r in rows + [header]) for i in range(6)]
    print("| " + " | ".join(h.ljust(w) for h, w in zip(header, widths)) + " |")
    print("|" + "|".join("-" * (w + 2) for w in widths) + "|")
    for r in rows:
        print("| " + " | ".join(str(v).ljust(w) for v, w in zip(r, widths)) + " |")
    return 0


if __name__ == "__main__":
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from _machine import published

    with published(__file__, "PDE build speed: the 2-D heat codebook beside a method-of-lines sweep"):
        main()

"""The shipped problems' builds beside the sweep a user would run instead, in one run.

    python benchmarks/reach.py                          # the seven problems below (see the table's wall time)
    python benchmarks/reach.py hotplate suspension      # some of them
    python benchmarks/reach.py --budget 120             # seconds of sweeping per problem before it is stopped
    python benchmarks/reach.py --solvers                # enrichment vs tensor-train solver, every linear problem
    python benchmarks/reach.py --solvers hotplate       # ... on some of them

Each problem is built from its spec by ``pgdcli.solve`` (no node counts in the specs: automatic resolution
and the error gate included) and its codebook's error measured at 300 check points against an independent
reference; beside it, the alternative a user would pick, its error measured at the same points:

- PDEs (moving_source, moving_heater, hotplate, brusselator_pde, allen_cahn2d): a Chebyshev method of lines
  written in numpy over a parameter grid, stacked into one BDF ``solve_ivp`` call (rtol = atol = 1e-3 x the
  tolerance, exact sparse Jacobian; grids beyond 2e5 unknowns in chunks of their points), interpolated in
  space and over the parameters by Chebyshev interpolation, in time by the dense output
  (``reaction_diffusion.measure``; check points: 5 parameter samples x 4 times x 15 space points, reference
  ``pgdcli.checks.reference_pde_nonlinear``);
- suspension: one vectorized DOP853 ``solve_ivp`` over a Chebyshev (w, c) grid (rtol = atol = 1e-3 x the
  tolerance), interpolated likewise (30 parameter samples x 10 times, reference DOP853 at rtol 1e-12);
- robertson: one vectorized BDF ``solve_ivp`` over a k1 grid with cubic interpolation (``stiff_build``).

The PDE sweeps start on the codebook's own node counts (a favourable start, which a user would have to
find), the suspension's on 9 x 5 nodes; each doubles them until it meets the tolerance at the check points, or until ``--budget`` seconds of
sweeping have passed (then it is stopped, and the table says so; a chunked sweep gives a lower bound on the
whole sweep's time from its chunks, all of one size, and the ratio uses it). One run each: the builds take minutes
on a shared machine, so read the ratios.

``--solvers`` instead runs ``linear_solvers.row`` (each build in a fresh process, ``solver.method`` pgd,
amen and auto) and writes ``results/reach-solvers.md``.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _machine import cell, markdown_table, published  # noqa: E402

import pgdcli  # noqa: E402

PDES = ("moving_source", "moving_heater", "hotplate", "brusselator_pde", "allen_cahn2d")
PROBLEMS = ("moving_source", "moving_heater", "suspension", "brusselator_pde", "allen_cahn2d", "robertson",
            "hotplate")


def pde_row(name: str, budget: float) -> tuple:
    from reaction_diffusion import measure

    m = measure(name, budget)
    build = _build_text(m["result"], m["build"], m.get("error"), m["tol"])
    if "error" not in m:
        return (name, build, "-", "-")
    met = m["sweep_error"] <= m["tol"]
    error = f"error {m['sweep_error']:.2g}" if np.isfinite(m["sweep_error"]) else "stopped"
    sweep = (f"{m['sweep']:.1f} s, {m['grid']} grid points, {error}"
             + ("" if met else f" (NOT within the tolerance; {m['total']:.0f} s of sweeping, the budget)")
             + f"; tried {'; '.join(m['tries'])}")
    bound = re.search(r"at least (\d+) s", m["tries"][-1])
    slower = (int(bound.group(1)) if bound else m["total"]) / m["build"]
    return (name, build, sweep, f"{m['sweep'] / m['build']:.2g}" if met else f"> {slower:.2g}")


def _build_text(result, seconds: float, error, tol: float) -> str:
    if error is None:
        return f"refused after {seconds:.1f} s: {result.message}"
    report = result.codebook.report
    nodes = ", ".join(f"{c.name} {c.nodes}" for c in result.codebook.coordinates)
    gate = report.get("check_time")
    gate = f" (gate {gate:.0f} s)" if isinstance(gate, (int, float)) else ""
    return (f"{seconds:.1f} s{gate}, error {error:.2g} (tolerance {tol:g}); {report.get('method', '?')}; "
            f"nodes {nodes}")


def suspension_rhs(w: np.ndarray, c: np.ndarray):
    """The quarter car for S stacked (w, c): state (4 S,) = (zs, zu, zs', zu') per sample."""
    ks, kt, mu, amplitude = 20.0, 120.0, 0.1, 0.02

    def rhs(t, y):
        zs, zu, vs, vu = y.reshape(4, -1)
        spring = ks * (zs - zu) + c * (vs - vu)
        return np.concatenate([vs, vu, -spring, (spring - kt * (zu - amplitude * np.sin(w * t))) / mu])

    return rhs


def suspension_row(budget: float) -> tuple:
    from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights
    from nonlinear_pde import cheb

    problem = pgdcli.load_spec(ROOT / "problems" / "suspension.yaml")
    tol, (t0, t1) = problem.solver.tolerance, problem.time_coordinate.domain
    rng = np.random.default_rng(9)
    w, c = rng.uniform(2.0, 12.0, 30), rng.uniform(0.5, 2.0, 30)
    times = np.sort(rng.uniform(t0, t1, 10))
    with threadpool_limits(1):
        exact = solve_ivp(suspension_rhs(w, c), (t0, t1), np.zeros(120), method="DOP853", rtol=1e-12, atol=1e-14,
                          t_eval=times).y.reshape(4, 30, -1)[:2]
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    build = time.perf_counter() - started
    got = [result.codebook.evaluate({"t": np.tile(times, 30), "w": np.repeat(w, 10), "c": np.repeat(c, 10)})[u]
           for u in ("zs", "zu")]
    error = float(np.abs(np.stack(got).reshape(2, 30, 10) - exact).max())
    nw, nc = 9, 5  # doubled (n -> 2n - 1) until the interpolation meets the tolerance
    spent, tries, deadline = 0.0, [], time.perf_counter() + budget
    while True:
        gw, gc = cheb(nw, 2.0, 12.0)[0], cheb(nc, 0.5, 2.0)[0]
        W, C = (g.ravel() for g in np.meshgrid(gw, gc, indexing="ij"))
        started = time.perf_counter()
        with threadpool_limits(1):
            sol = solve_ivp(suspension_rhs(W, C), (t0, t1), np.zeros(4 * W.size), method="DOP853", rtol=1e-3 * tol,
                            atol=1e-3 * tol, t_eval=times)
        grid = sol.y.reshape(4, nw, nc, -1)[:2]
        rows_w = barycentric_matrix(gw, chebyshev_weights(nw), w)
        rows_c = barycentric_matrix(gc, chebyshev_weights(nc), c)
        values = np.einsum("sa,sb,qabt->qst", rows_w, rows_c, grid)
        seconds = time.perf_counter() - started
        spent += seconds
        sweep_error = float(np.abs(values - exact).max())
        tries.append(f"{nw} x {nc}: {sweep_error:.2g}")
        if sweep_error <= tol or time.perf_counter() > deadline:
            break
        nw, nc = 2 * nw - 1, 2 * nc - 1
    met = sweep_error <= tol
    sweep = (f"{seconds:.1f} s, {nw * nc} grid points, error {sweep_error:.2g}"
             + ("" if met else f" (NOT within the tolerance; {spent:.0f} s of sweeping, the budget)")
             + f"; tried {'; '.join(tries)}")
    return ("suspension", _build_text(result, build, error, tol), sweep,
            f"{seconds / build:.2g}" if met else f"> {spent / build:.2g}")


def robertson_row(budget: float) -> tuple:
    import stiff_build

    t, k = stiff_build.points()
    ref = stiff_build.reference(t, k)
    text, ours = stiff_build.build(t, k, ref)
    text = text.replace(" x the promise", " x the tolerance")
    theirs_text, theirs = stiff_build.interpolated(t, k, ref, "BDF", budget)
    return ("robertson", f"{text} (tolerance 1e-10 + 1e-6 |u|)", theirs_text.replace(" x the promise", " x the tolerance"),
            f"{theirs / ours:.2g}" if np.isfinite(theirs) else f"> {budget / ours:.2g}")


def reach(names: list[str], budget: float) -> None:
    with published(__file__, "Builds of the shipped problems beside a user's sweep over a parameter grid"):
        rows = []
        for name in names:
            row = (suspension_row(budget) if name == "suspension" else robertson_row(budget) if name == "robertson"
                   else pde_row(name, budget))
            rows.append(tuple(cell(v) for v in row))
            print(f"{name}: {row}", file=sys.stderr, flush=True)
        print(markdown_table(rows, ("problem", "pgdcli build (gate included), its error at 300 points",
                                    "the sweep that met the tolerance at the same points", "sweep / build")))


def solvers(names: list[str]) -> None:
    from linear_solvers import linear_problems, row

    linear = linear_problems()
    names = [n for n in names if n in linear] or linear
    with published(__file__, "The enrichment beside the tensor-train solver, shipped linear problems", "solvers"):
        print("| problem | enrichment (pgd) | tensor-train (amen) | amen / pgd time | auto, which ran |")
        print("| --- | --- | --- | --- | --- |")
        for name in names:
            print(row(name), flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"problems (default: {', '.join(PROBLEMS)})")
    parser.add_argument("--budget", type=float, default=60.0, help="seconds of sweeping per problem (default 60)")
    parser.add_argument("--solvers", action="store_true", help="the enrichment vs the tensor-train solver instead")
    options = parser.parse_args()
    if options.solvers:
        solvers(options.names)
    else:
        unknown = sorted(set(options.names) - set(PROBLEMS))
        if unknown:
            parser.error(f"unknown problems {unknown}; choose from {', '.join(PROBLEMS)}")
        reach(options.names or list(PROBLEMS), options.budget)


if __name__ == "__main__":
    main()

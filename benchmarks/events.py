"""Event times: the landing of a ball with drag, a pgdcli build beside a user's sweep of solve_ivp events.

    python benchmarks/events.py                 # problems/landing.yaml (landing and apex times)
    python benchmarks/events.py --budget 120    # seconds of sweeping before the sweep is stopped

pgdcli builds ``problems/landing.yaml`` (automatic resolution, the error gate and the events' own check
included); its event times are measured at 300 random points plus the corners of (v0, c) against
``solve_ivp``'s event location (DOP853, rtol 1e-12, atol 1e-14), one trajectory per point.

The alternative a user would pick: ``solve_ivp`` with the same events at every point of a (v0, c) grid
(rtol = atol = 1e-3 x the tolerance; scipy locates events per trajectory, so one call per point), then
interpolation to the check points: on a Chebyshev grid by barycentric interpolation (the best a user can
do for a smooth function; ``RegularGridInterpolator(method="cubic")`` on a uniform grid stalls near 1e-5
here), the grid doubled (n -> 2n - 1) from 9 x 9 until both event times meet the tolerance, or the budget
runs out. Then 1e4 queries of the landing time: ``Codebook.event_times`` on an array beside the
interpolation's matrix products on that grid. One run; read the ratios.
"""

from __future__ import annotations

import argparse
import itertools
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _machine import markdown_table, median_seconds, published  # noqa: E402

import pgdcli  # noqa: E402
from nonlinear_pde import cheb  # noqa: E402
from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights  # noqa: E402

G = 9.81
V0, C, T_END = (5.0, 10.0), (0.0, 0.2), 2.5


def _events(v0: float, c: float, rtol: float, atol: float) -> tuple[float, float]:
    """(landing, apex) of one trajectory by solve_ivp's event location."""
    def landing(t, s):
        return s[0]

    def apex(t, s):
        return s[1]

    landing.direction = -1
    sol = solve_ivp(lambda t, s: [s[1], -G - c * s[1] * abs(s[1])], (0.0, T_END), [0.0, v0], method="DOP853",
                    rtol=rtol, atol=atol, events=[landing, apex])
    return float(sol.t_events[0][sol.t_events[0] > 1e-9][0]), float(sol.t_events[1][0])


def check_points(n: int = 300, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    corners = np.array(list(itertools.product(V0, C)))
    return np.vstack([np.column_stack([rng.uniform(*V0, n), rng.uniform(*C, n)]), corners])


def interpolate(v0: np.ndarray, c: np.ndarray, values: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Barycentric interpolation of grid values (n, n) on the Chebyshev grid (v0, c) at points (P, 2)."""
    rows_v = barycentric_matrix(v0, chebyshev_weights(v0.size), points[:, 0])
    rows_c = barycentric_matrix(c, chebyshev_weights(c.size), points[:, 1])
    return np.einsum("pa,ab,pb->p", rows_v, values, rows_c)


def sweep(points: np.ndarray, reference: np.ndarray, tol: float, budget: float):
    """The Chebyshev grid sweep, doubled until it meets ``tol``: (seconds of the last sweep, n, error, tries,
    total, grid)."""
    n, tries, spent, deadline = 9, [], 0.0, time.perf_counter() + budget
    while True:
        v0, c = cheb(n, *V0)[0], cheb(n, *C)[0]
        started = time.perf_counter()
        grid = np.array([[_events(a, b, 1e-3 * tol, 1e-3 * tol) for b in c] for a in v0])
        interpolated = np.column_stack([interpolate(v0, c, grid[:, :, k], points) for k in range(2)])
        seconds = time.perf_counter() - started
        spent += seconds
        error = float(np.abs(interpolated - reference).max())
        tries.append(f"{n} x {n}: {error:.2g} in {seconds:.1f} s")
        if error <= tol or time.perf_counter() > deadline:
            return seconds, n, error, tries, spent, (v0, c, grid)
        n = 2 * n - 1


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=120.0, help="seconds of sweeping (default 120)")
    options = parser.parse_args()
    with published(__file__, "Event times: a build beside a sweep of solve_ivp events"), threadpool_limits(1):
        problem = pgdcli.load_spec(ROOT / "problems" / "landing.yaml")
        tol = problem.solver.tolerance
        points = check_points()
        reference = np.array([_events(a, b, 1e-12, 1e-14) for a, b in points])
        started = time.perf_counter()
        result = pgdcli.solve(problem)
        build = time.perf_counter() - started
        cb = result.codebook
        got = cb.event_times({"v0": points[:, 0], "c": points[:, 1]})
        error = float(np.abs(np.column_stack([got["landing"], got["apex"]]) - reference).max())
        seconds, n, sweep_error, tries, spent, (v0, c, grid) = sweep(points, reference, tol, options.budget)
        met = sweep_error <= tol
        rows = [("build", f"{build:.1f} s (gate and events' check {cb.report.get('gate_time', float('nan')):.1f} s); "
                          f"error {error:.2g} at {len(points)} points (tolerance {tol:g})",
                 f"{seconds:.1f} s for {n} x {n} trajectories, error {sweep_error:.2g}"
                 + ("" if met else f" (NOT within the tolerance after {spent:.0f} s)") + "; tried " + "; ".join(tries),
                 f"{seconds / build:.2g}" if met else f"> {spent / build:.2g}")]
        q = np.random.default_rng(4).uniform((V0[0], C[0]), (V0[1], C[1]), (10_000, 2))
        ours = median_seconds(lambda: cb.event_times({"v0": q[:, 0], "c": q[:, 1]}, ["landing"]), 5)
        theirs = median_seconds(lambda: interpolate(v0, c, grid[:, :, 0], q), 5)
        rows.append(("1e4 landing times", f"{ours * 1e3:.2f} ms (Codebook.event_times)",
                     f"{theirs * 1e3:.2f} ms (barycentric interpolation on the {n} x {n} grid)",
                     f"{theirs / ours:.2g}"))
        print(markdown_table(rows, ("task", "pgdcli", "the sweep a user would run", "sweep / pgdcli")))


if __name__ == "__main__":
    main()

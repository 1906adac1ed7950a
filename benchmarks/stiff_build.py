"""A stiff problem's build beside what a user would do instead, side by side in one process.

    python benchmarks/stiff_build.py [--budget 120]

problems/robertson.yaml (Robertson's kinetics, the rate k1 a coordinate, t in [0, 1000], tolerance
1e-10 + 1e-6 |u|) is built by ``pgdcli.solve`` (the automatic switch to RODAS4, the error gate and the
automatic resolution included), and compared with:

- one vectorized ``solve_ivp`` sweep (BDF, then Radau; analytic block-diagonal Jacobian, rtol 1e-9, atol
  1e-14) over a uniform k1 grid, read on a time grid (uniform in log(1 + t)) and interpolated by cubic
  ``RegularGridInterpolator``; both grids doubled until the interpolation meets the same promise at the
  evaluation points (the table gives the sweep that met it, and all the sweeps it took);
- the explicit march on the same spec (``solver.integrator: dop853``), and scipy's explicit DOP853 on
  one k1, each stopped after ``--budget`` seconds.

Errors are measured at 300 random points (t biased to the transient) against Radau at rtol 1e-11 with
the analytic Jacobian. Times are wall-clock medians of one run on a shared machine: read the ratios.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import RegularGridInterpolator
from scipy.sparse import block_diag

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _machine import cell, markdown_table, published  # noqa: E402

SPEC = ROOT / "problems" / "robertson.yaml"
T_END, K_DOMAIN, TOL, REL = 1000.0, (0.02, 0.08), 1e-10, 1e-6


class TimeUp(Exception):
    pass


def robertson(k1: np.ndarray, deadline: float | None = None):
    """Right-hand side and block-diagonal Jacobian of S Robertson systems (state (3 S,))."""
    S = k1.size

    def rhs(t, y):
        if deadline is not None and time.perf_counter() > deadline:
            raise TimeUp(t)
        y1, y2, y3 = y.reshape(S, 3).T
        return np.stack([-k1 * y1 + 1e4 * y2 * y3, k1 * y1 - 1e4 * y2 * y3 - 3e7 * y2 ** 2, 3e7 * y2 ** 2],
                        axis=1).reshape(-1)

    def jac(t, y):
        _, y2, y3 = y.reshape(S, 3).T
        return block_diag([np.array([[-k, 1e4 * c, 1e4 * b], [k, -1e4 * c - 6e7 * b, -1e4 * b], [0, 6e7 * b, 0]])
                           for k, b, c in zip(k1, y2, y3)], format="csc")

    return rhs, jac


def sweep(k1: np.ndarray, times: np.ndarray, method: str, rtol: float, atol: float) -> np.ndarray:
    """All k1 in one solve_ivp call, read at ``times``: shape (3, len(k1), len(times))."""
    rhs, jac = robertson(k1)
    sol = solve_ivp(rhs, (0.0, float(times[-1])), np.tile([1.0, 0.0, 0.0], k1.size), method=method, rtol=rtol,
                    atol=atol, jac=jac, t_eval=times)
    return sol.y.reshape(k1.size, 3, times.size).transpose(1, 0, 2)


def points(seed: int = 5, n: int = 300):
    rng = np.random.default_rng(seed)
    return T_END * rng.random(n) ** 4, rng.uniform(*K_DOMAIN, n)


def reference(t: np.ndarray, k: np.ndarray) -> np.ndarray:
    rhs, jac = robertson(k)
    sol = solve_ivp(rhs, (0.0, T_END), np.tile([1.0, 0.0, 0.0], k.size), method="Radau", rtol=1e-11, atol=1e-16,
                    jac=jac, dense_output=True)
    return np.stack([sol.sol(ti)[3 * i:3 * i + 3] for i, ti in enumerate(t)], axis=1)


def ratio(values: np.ndarray, ref: np.ndarray) -> float:
    """The largest error over the promise ``TOL + REL |u|``."""
    return float((np.abs(values - ref) / (TOL + REL * np.abs(ref))).max())


def build(t, k, ref) -> tuple[str, float]:
    import pgdcli

    start = time.perf_counter()
    result = pgdcli.solve(pgdcli.load_spec(SPEC))
    seconds = time.perf_counter() - start
    values = result.codebook.evaluate({"t": t, "k1": k})
    r = ratio(np.stack([values[u] for u in ("y1", "y2", "y3")]), ref)
    nodes = ", ".join(f"{c.name} {c.nodes}" for c in result.codebook.coordinates)
    return (f"{seconds:.2f} s, {r:.2g} x the promise at 300 points; {result.codebook.report['integrator']}, "
            f"nodes {nodes}"), seconds


def interpolated(t, k, ref, method: str, budget: float) -> tuple[str, float]:
    """Doubling sweeps until cubic interpolation meets the promise: the last sweep's time, and all of them."""
    n, m, spent = 9, 65, 0.0
    while spent < budget:
        k_grid = np.linspace(*K_DOMAIN, n)
        t_grid = np.expm1(np.linspace(0.0, np.log1p(T_END), m))
        start = time.perf_counter()
        values = sweep(k_grid, t_grid, method, 1e-9, 1e-14)
        fits = [RegularGridInterpolator((k_grid, t_grid), values[i], method="cubic") for i in range(3)]
        seconds = time.perf_counter() - start
        spent += seconds
        r = ratio(np.stack([fit(np.stack([k, t], axis=1)) for fit in fits]), ref)
        if r <= 1.0:
            return (f"{seconds:.2f} s for k1 {n} x t {m} ({r:.2g} x the promise); {spent:.1f} s with the "
                    f"coarser sweeps"), seconds
        n, m = 2 * n - 1, 2 * m - 1
    return f"stopped after {spent:.0f} s (k1 {n} x t {m}, {r:.2g} x the promise)", float("nan")


def explicit_march(budget: float) -> str:
    import pgdcli

    text = SPEC.read_text().replace("relative_tolerance: 1e-6", "relative_tolerance: 1e-6\n  integrator: dop853")
    start = time.perf_counter()
    result = pgdcli.solve(pgdcli.parse_spec(text, source="robertson.yaml"))
    return f"{time.perf_counter() - start:.2f} s: {result.message}"


def explicit_scipy(budget: float) -> str:
    rhs, _ = robertson(np.array([0.04]), time.perf_counter() + budget)
    start = time.perf_counter()
    try:
        sol = solve_ivp(rhs, (0.0, T_END), [1.0, 0.0, 0.0], method="DOP853", rtol=1e-9, atol=1e-14)
    except TimeUp as up:
        return f"stopped after {budget:.0f} s at t = {up.args[0]:.3g} of {T_END:g} (one k1)"
    return f"{time.perf_counter() - start:.2f} s for one k1, {sol.t.size} steps"


def main(budget: float) -> None:
    t, k = points()
    ref = reference(t, k)
    with published(__file__, "A stiff problem: Robertson's kinetics, k1 a coordinate, t in [0, 1000]"):
        text, ours = build(t, k, ref)
        rows = [("pgdcli build of problems/robertson.yaml (gate included)", cell(text), "1")]
        for method in ("BDF", "Radau"):
            text, theirs = interpolated(t, k, ref, method, budget)
            rows.append((f"one vectorized solve_ivp {method} sweep + cubic interpolation", cell(text),
                         f"{theirs / ours:.2g}" if np.isfinite(theirs) else "-"))
        rows.append(("explicit march (solver.integrator: dop853)", cell(explicit_march(budget)), "-"))
        rows.append(("scipy DOP853 (rtol 1e-9), one k1", cell(explicit_scipy(budget)), "-"))
        print(markdown_table(rows, ("what", "result", "time / pgdcli build")))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--budget", type=float, default=120.0, help="seconds before an alternative is stopped")
    main(parser.parse_args().budget)

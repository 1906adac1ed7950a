"""Reaction-diffusion systems and two space coordinates: codebook builds beside a vectorized method-of-lines sweep.

    python benchmarks/reaction_diffusion.py                     # the problems in DEFAULT
    python benchmarks/reaction_diffusion.py brusselator_pde     # some of them
    python benchmarks/reaction_diffusion.py gray_scott fisher2d # the ones whose check takes long
    python benchmarks/reaction_diffusion.py --out table.md      # where the table is written

For each problem (no node counts), the build of the codebook, ``pgdcli.solve`` (automatic resolution
and the error gate included), and its max error at 300 random points (5 parameter samples x 4 times x
15 space points) against the independent nonlinear reference (``pgdcli.checks.reference_pde_nonlinear``),
beside the alternative a user would write: ONE ``solve_ivp`` call (BDF, rtol = atol = 1e-3 x the
tolerance, the exact sparse block-diagonal Jacobian) of a method of lines written here in numpy
(Chebyshev collocation, the boundary values eliminated, the reaction vectorized over the grid) over
all points of a parameter grid stacked into one system, its values interpolated in space and over the
parameters with Chebyshev (barycentric) interpolation and in time by the solver's dense output. The
sweep starts on the codebook's own node counts (space and parameters: a favourable start, which a user
would have to find) and doubles them (``n -> 2n - 1``) until its error at the same 300 points meets the
tolerance; the time of that last sweep is quoted, and the total with the coarser tries.

The table is printed and written (``--out``, default ``benchmarks/results/reaction_diffusion.md``) with
the machine's facts, the date and the command. The scipy runs use one BLAS thread, as the solver does.
"""

from __future__ import annotations

import datetime
import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

import pgdcli
from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_pde

from _machine import machine_facts
from nonlinear_pde import cheb

ROOT = Path(__file__).resolve().parents[1]
USER = ROOT / "tests" / "user_problems"
MAX_DOUBLINGS = 3
#: Run without names. Gray-Scott (t up to 20, slim pulses) and 2-D Fisher-KPP (a front from a corner) are
#: run only when named: the error gate's reference needs 513 nodes (1-D) and 57 x 57 nodes (2-D, dense
#: LU factorizations) on every sample to agree to a thousandth of the tolerance: builds of tens of
#: minutes, far beyond the others.
DEFAULT = ("brusselator_pde", "allen_cahn2d", "predator_prey")


# Each problem: spec, per-species diffusion c_s(p), reaction F_s(U, p) and its derivatives dF_s/dU_r (numpy,
# U a list of arrays (G, n[, n]), p parameter arrays broadcast to U), zero-flux or value conditions with data.
PROBLEMS = {
    "brusselator_pde": dict(
        path=ROOT / "problems" / "brusselator_pde.yaml",
        diffusion=lambda p: [0.02, 0.01],
        reaction=lambda U, p: [1 - (p["B"] + 1) * U[0] + U[0] ** 2 * U[1], p["B"] * U[0] - U[0] ** 2 * U[1]],
        jacobian=lambda U, p: [[-(p["B"] + 1) + 2 * U[0] * U[1], U[0] ** 2],
                               [p["B"] - 2 * U[0] * U[1], -U[0] ** 2]],
        values=lambda p: [(1.0, 1.0), (p["B"], p["B"])]),
    "allen_cahn2d": dict(
        path=ROOT / "problems" / "allen_cahn2d.yaml",
        diffusion=lambda p: [p["eps"] ** 2],
        reaction=lambda U, p: [U[0] - U[0] ** 3],
        jacobian=lambda U, p: [[1 - 3 * U[0] ** 2]],
        values=None),
    "predator_prey": dict(
        path=USER / "predator_prey.yaml",
        diffusion=lambda p: [0.005, 0.01],
        reaction=lambda U, p: [U[0] * (1 - U[0]) - U[0] * U[1] / (U[0] + 0.3),
                               p["b"] * U[0] * U[1] / (U[0] + 0.3) - 0.4 * U[1]],
        jacobian=lambda U, p: [[1 - 2 * U[0] - 0.3 * U[1] / (U[0] + 0.3) ** 2, -U[0] / (U[0] + 0.3)],
                               [p["b"] * 0.3 * U[1] / (U[0] + 0.3) ** 2, p["b"] * U[0] / (U[0] + 0.3) - 0.4]],
        values=None),
    "fisher2d": dict(
        path=USER / "fisher2d.yaml",
        diffusion=lambda p: [0.05],
        reaction=lambda U, p: [p["r"] * U[0] * (1 - U[0])],
        jacobian=lambda U, p: [[p["r"] * (1 - 2 * U[0])]],
        values=None),
    "gray_scott": dict(
        path=USER / "gray_scott.yaml",
        diffusion=lambda p: [0.002, 0.001],
        reaction=lambda U, p: [-U[0] * U[1] ** 2 + p["F"] * (1 - U[0]), U[0] * U[1] ** 2 - (p["F"] + 0.06) * U[1]],
        jacobian=lambda U, p: [[-U[1] ** 2 - p["F"], -2 * U[0] * U[1]], [U[1] ** 2, 2 * U[0] * U[1] - p["F"] - 0.06]],
        values=None),
}


class Sweep:
    """The method of lines of one problem on ``n`` nodes per space coordinate, for G stacked parameter points.

    Conditions: zero flux on every side (``values`` None) or values at both ends of the one space
    coordinate (``values(p)``: per species, the data at the low and high end).
    """

    def __init__(self, problem, spec: dict, n: int, grid: dict):
        self.space = [co for co in problem.coordinates if co.role == "space"]
        self.d, self.n, self.spec = len(self.space), n, spec
        self.x = [cheb(n, *co.domain)[0] for co in self.space]
        D = [cheb(n, *co.domain)[1] for co in self.space]
        self.D2 = [Da @ Da for Da in D]
        self.G = next(iter(grid.values())).size
        shape = (self.G,) + (1,) * self.d
        self.p = {k: v.reshape(shape) for k, v in grid.items()}
        self.q = len(problem.unknowns)
        kind = "gradient" if spec["values"] is None else "value"
        B, inner = np.array([0, n - 1]), np.arange(1, n - 1)
        self.Z = []  # per space axis (the same conditions for every species on it)
        for Da in D:
            C = np.eye(n)[B] if kind == "value" else Da[B]
            Z = np.zeros((n, n - 2))
            Z[inner, np.arange(n - 2)] = 1
            Z[B] = -np.linalg.solve(C[:, B], C[:, inner])
            self.Z.append(Z)
        self.lift = [0.0] * self.q
        if spec["values"] is not None:  # one space coordinate: the linear lift of the data, per parameter point
            s = (self.x[0] - self.x[0][0]) / (self.x[0][-1] - self.x[0][0])
            for k, (lo, hi) in enumerate(spec["values"](self.p)):
                self.lift[k] = np.broadcast_to(lo, shape) * (1 - s) + np.broadcast_to(hi, shape) * s
        mesh = np.meshgrid(*self.x, indexing="ij")
        values = {co.name: m for co, m in zip(self.space, mesh)}
        values.update({k: v for k, v in self.p.items()})
        u0 = [np.broadcast_to(u.initial.evaluate(**{c: values[c] for c in u.initial.coordinates}), (self.G,) +
                              (n,) * self.d) for u in problem.unknowns]
        self.y0 = np.concatenate([(u - L)[(slice(None),) + (slice(1, -1),) * self.d].ravel()
                                  for u, L in zip(u0, self.lift)])
        self.m = (n - 2) ** self.d
        self.L = self._laplacian()

    def _along(self, M, U, a):
        return np.moveaxis(np.tensordot(M, U, axes=(1, 1 + a)), 0, 1 + a)

    def full(self, y):
        W = y.reshape((self.q, self.G) + (self.n - 2,) * self.d)
        out = []
        for k in range(self.q):
            U = W[k]
            for a in range(self.d):
                U = self._along(self.Z[a], U, a)
            out.append(U + self.lift[k])
        return out

    def rhs(self, t, y):
        U = self.full(y)
        F = self.spec["reaction"](U, self.p)
        c = self.spec["diffusion"](self.p)
        inner = (slice(None),) + (slice(1, -1),) * self.d
        out = []
        for k in range(self.q):
            lap = sum(self._along(D2, U[k], a) for a, D2 in enumerate(self.D2))
            out.append((c[k] * lap + F[k])[inner].ravel())
        return np.concatenate(out)

    def _laplacian(self):
        """The eliminated Laplacian (m, m) on one parameter point's interior values, sparse."""
        ops = [sp.csr_matrix((D2 @ Z)[1:-1]) for D2, Z in zip(self.D2, self.Z)]
        if self.d == 1:
            return ops[0]
        eye = sp.identity(self.n - 2, format="csr")
        return sp.kron(ops[0], eye) + sp.kron(eye, ops[1])

    def jac(self, t, y):
        U = self.full(y)
        J = self.spec["jacobian"](U, self.p)
        c = [np.broadcast_to(np.asarray(ck, dtype=float).reshape(-1), (self.G,))
             for ck in self.spec["diffusion"](self.p)]
        inner = (slice(None),) + (slice(1, -1),) * self.d
        rows = []
        for k in range(self.q):
            row = []
            for r in range(self.q):
                diag = np.broadcast_to(J[k][r], U[0].shape)[inner].reshape(self.G, -1)
                blocks = [sp.diags(diag[g]) + (c[k][g] * self.L if k == r else 0) for g in range(self.G)]
                row.append(sp.block_diag(blocks, format="csr"))
            rows.append(row)
        return sp.bmat(rows, format="csc")

    def values_at(self, sol, times, points, samples, axes):
        """The sweep at (samples S, times T, points P): interpolated over the parameter grid ``axes``."""
        from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights

        w = chebyshev_weights(self.n)
        W = [barycentric_matrix(x, w, points[:, a]) for a, x in enumerate(self.x)]
        weights = [_bary(nodes, samples[name]) for name, nodes in axes.items()]  # (S, c_a) each
        out = np.empty((self.q, weights[0].shape[0], times.size, points.shape[0]))
        for j, t in enumerate(times):
            U = self.full(sol(t))
            for k in range(self.q):
                V = np.tensordot(weights[0], U[k].reshape([a.size for a in axes.values()] + [self.n] * self.d),
                                 axes=(1, 0))  # (S, c_2, ..., space...)
                for wa in weights[1:]:
                    V = np.einsum("sc,sc...->s...", wa, V)
                out[k, :, j] = V @ W[0].T if self.d == 1 else np.einsum("sij,pi,pj->sp", V, W[0], W[1])
        return out


def _bary(nodes, x):
    """Rows (len(x), len(nodes)) interpolating at x from Chebyshev-Lobatto ``nodes`` (ascending, any interval)."""
    from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights

    return barycentric_matrix(nodes, chebyshev_weights(nodes.size), np.asarray(x, dtype=float))


def sweep(problem, spec, n: int, counts: dict, tol: float, samples, times, points):
    """One stacked solve on ``n`` space nodes and ``counts`` parameter nodes: (seconds, values at the points)."""
    params = [co for co in problem.coordinates if co.role == "parameter"]
    axes = {co.name: cheb(counts[co.name], *co.domain)[0] for co in params}
    mesh = np.meshgrid(*axes.values(), indexing="ij")
    grid = {name: g.ravel() for name, g in zip(axes, mesh)}
    m = Sweep(problem, spec, n, grid)
    started = time.perf_counter()
    sol = solve_ivp(m.rhs, problem.time_coordinate.domain, m.y0, method="BDF", jac=m.jac, rtol=1e-3 * tol,
                    atol=1e-3 * tol, dense_output=True)
    wall = time.perf_counter() - started
    if sol.status != 0:
        return wall, None
    return wall, m.values_at(sol.sol, times, points, samples, axes)


def run_problem(name: str) -> str:
    spec = PROBLEMS[name]
    problem = pgdcli.load_spec(spec["path"])
    tol = problem.solver.tolerance
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    build = time.perf_counter() - started
    cb = result.codebook
    if not result.accurate:
        return f"| {name} | refused after {build:.1f} s: {result.message} | | | |"
    rng = np.random.default_rng(14)
    params = [co for co in problem.coordinates if co.role == "parameter"]
    space = [co for co in problem.coordinates if co.role == "space"]
    samples = {co.name: rng.uniform(*co.domain, 5) for co in params}
    times = np.sort(rng.uniform(*problem.time_coordinate.domain, 4))
    points = np.stack([rng.uniform(*co.domain, 15) for co in space], axis=1)
    ref = solve_reference_nonlinear_pde(problem, samples, times, points if len(space) > 1 else points[:, 0])
    names = list(problem.unknown_names)
    exact = np.stack([ref.values[u] for u in names])  # (q, S, T, P)
    T = np.repeat(times, points.shape[0])
    err = 0.0
    for s in range(5):
        where = {problem.time: T, **{co.name: np.tile(points[:, a], times.size) for a, co in enumerate(space)},
                 **{k: np.full(T.size, v[s]) for k, v in samples.items()}}
        got = cb.evaluate(where)
        err = max(err, max(float(np.abs(got[u].reshape(times.size, -1) - exact[i, s]).max())
                           for i, u in enumerate(names)))
    nodes = {co.name: cb.coordinate(co.name).nodes for co in problem.coordinates if co.name != problem.time}
    n, counts = nodes[space[0].name], {co.name: nodes[co.name] for co in params}
    total, tries = 0.0, []
    with threadpool_limits(1):
        for _ in range(MAX_DOUBLINGS + 1):
            wall, values = sweep(problem, spec, n, counts, tol, samples, times, points)
            total += wall
            sweep_err = np.inf if values is None else float(np.abs(values - exact).max())
            tries.append(f"{n} x {'x'.join(str(c) for c in counts.values())}: {sweep_err:.2g}")
            if sweep_err <= tol:
                break
            n, counts = 2 * n - 1, {k: 2 * c - 1 for k, c in counts.items()}
    grid = int(np.prod(list(counts.values())))
    met = "" if sweep_err <= tol else "NOT within the tolerance: "
    return (f"| {name} | {build:.1f} s, {err:.2g} (tolerance {tol:g}); nodes {nodes} | {met}{wall:.1f} s "
            f"({wall / build:.2g}x the build; {total:.1f} s with the coarser tries), {grid} grid points, "
            f"{sweep_err:.2g} | {'; '.join(tries)} |")


def main(argv):
    out = Path(argv[argv.index("--out") + 1]) if "--out" in argv else ROOT / "benchmarks" / "results" / \
        "reaction_diffusion.md"
    names = [a for a in argv if a in PROBLEMS] or list(DEFAULT)
    facts = machine_facts()
    lines = [f"`python benchmarks/reaction_diffusion.py {' '.join(argv)}`".replace(" `", "`"),
             f"{datetime.date.today().isoformat()}; " + ", ".join(f"{k}: {v}" for k, v in facts.items()), "",
             "| problem | pgdcli build, error at 300 points; nodes | one stacked solve_ivp (BDF) over a parameter "
             "grid, its error at the same points | sweeps tried (space nodes x parameter nodes: error) |",
             "| --- | --- | --- | --- |"]
    for line in lines:
        print(line, flush=True)
    for name in names:
        row = run_problem(name)
        print(row, flush=True)
        lines.append(row)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main(sys.argv[1:])

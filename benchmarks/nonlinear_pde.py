"""Nonlinear PDEs in one space coordinate: codebook builds beside method-of-lines sweeps, in one run.

    python benchmarks/nonlinear_pde.py                  # every problem below
    python benchmarks/nonlinear_pde.py fisher nagumo    # some of them
    python benchmarks/nonlinear_pde.py --schemes        # ETDRK4 against Lawson RK4 on fixed nodes

For each problem (no node counts), the build of the codebook, ``pgdcli.solve`` (automatic resolution
and the error gate included), and its max error at 300 random points against the independent
nonlinear reference (``pgdcli.checks.reference_pde_nonlinear``), beside the alternatives a user would
write, which fill the grid of the codebook's own parameter nodes (interpolated with the codebook's
bases such a grid is as accurate as the codebook):

- a Python loop of ``solve_ivp`` (Radau, rtol = atol = 1e-9, the exact Jacobian) of a method of lines
  written here in numpy (Chebyshev collocation on the codebook's ``x`` node count, boundary rows
  eliminated), one call per parameter grid point, timed on at most 24 points and scaled;
- ONE ``solve_ivp`` call over all parameter grid points stacked into one system (BDF, sparse
  block-diagonal Jacobian), same tolerances;
- teneva's TT-cross (``teneva.cross``) of the nodal tensor ``u(t_i, x_j, p_k, ...)`` over the
  codebook's time, x and parameter nodes, whose black box solves each parameter point it asks for
  once (the loop's Radau method of lines, cached: one solve gives the point's whole (t, x) field).
  Its threshold is lowered from 1e-6 to 1e-8 and 1e-10 until its max error over the whole nodal
  tensor, against the stacked call's values there, meets the problem's tolerance; the time of that
  run is reported, with its ranks and the parameter points it solved (``general_rhs.teneva_cross``
  for the ODE problems). Time and x stay separate modes: the tensor is then smooth in each of its
  modes, and the cross's cost, the parameter points it solves, depends on the parameter modes only;

and the error of each alternative at the same 300 random points (the loop's values interpolated over
the parameters with the codebook's bases: the error of the sweep on this grid).

``--schemes``: the PDE march on fixed nodes with ETDRK4 and with the Lawson RK4 (steps, evaluations of
the nonlinear part, time, error). The scipy runs use one BLAS thread, as the solver does. The table
is printed and written to benchmarks/results/nonlinear_pde.md (``--schemes``: nonlinear_pde-schemes.md).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

import pgdcli
from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_pde

from _machine import published
from general_rhs import cross_full, load_teneva

ROOT = Path(__file__).resolve().parents[1]
RTOL = ATOL = 1e-9
LOOP_POINTS = 24

# u_t = c(p) u_xx + f(u, u_x, p): the problems' right-hand sides written here in numpy (x-independent f)
PROBLEMS = {
    "fisher": (ROOT / "problems" / "fisher.yaml", lambda p: p["D"],
               lambda u, ux, p: p["r"] * u * (1 - u), lambda u, ux, p: (p["r"] * (1 - 2 * u), 0 * u)),
    "burgers": (ROOT / "problems" / "burgers.yaml", lambda p: p["nu"],
                lambda u, ux, p: -u * ux, lambda u, ux, p: (-ux, -u)),
    "allen_cahn": (ROOT / "tests" / "user_problems" / "allen_cahn.yaml", lambda p: p["eps"],
                   lambda u, ux, p: u - u ** 3, lambda u, ux, p: (1 - 3 * u ** 2, 0 * u)),
    "nagumo": (ROOT / "tests" / "user_problems" / "nagumo.yaml", lambda p: 0.02 + 0 * p["a"],
               lambda u, ux, p: 4 * u * (1 - u) * (u - p["a"]),
               lambda u, ux, p: (4 * (-3 * u ** 2 + 2 * (1 + p["a"]) * u - p["a"]), 0 * u)),
}


def cheb(n: int, a: float, b: float):
    """Chebyshev-Lobatto points (ascending) on [a, b] and the differentiation matrix (Trefethen's cheb)."""
    k = np.arange(n)
    x = -np.cos(np.pi * k / (n - 1))
    c = np.where((k == 0) | (k == n - 1), 2.0, 1.0) * (-1.0) ** k
    X = x[:, None] - x[None, :]
    D = np.outer(c, 1 / c) / (X + np.eye(n))
    D -= np.diag(D.sum(axis=1))
    return a + (b - a) * (x + 1) / 2, D * 2 / (b - a)


class Mol:
    """Method of lines of one problem on n nodes, for S stacked parameter points."""

    def __init__(self, problem, n: int, params: dict, c, f, df):
        self.xc = next(co for co in problem.coordinates if co.role == "space")
        self.x, self.D = cheb(n, *self.xc.domain)
        self.n, self.p, self.c, self.f, self.df = n, params, c(params)[:, None], f, df
        u = problem.unknowns[0]
        C, g = np.zeros((2, n)), np.zeros(2)
        for side, bc in enumerate(u.boundary[self.xc.name]):
            node = 0 if side == 0 else n - 1
            C[side] = np.eye(n)[node] if bc.kind == "value" else self.D[node]
            g[side] = 0.0 if bc.value.is_zero else bc.value.constant_value
        B, I = [0, n - 1], np.arange(1, n - 1)
        self.Z = np.zeros((n, n - 2))
        self.Z[I, np.arange(n - 2)] = 1
        self.Z[B] = -np.linalg.solve(C[:, B], C[:, I])
        self.h = np.zeros(n)
        self.h[B] = np.linalg.solve(C[:, B], g)
        self.S = next(iter(params.values())).size
        self.pc = {k: v[:, None] for k, v in params.items()}
        X = np.broadcast_to(self.x, (self.S, n))
        self.y0 = u.initial.evaluate(**{self.xc.name: X}, **self.pc)[:, 1:-1] * np.ones((self.S, n - 2))

    def full(self, y):
        return y.reshape(self.S, -1) @ self.Z.T + self.h

    def rhs(self, t, y):
        U = self.full(y)
        Ux, Uxx = U @ self.D.T, U @ (self.D @ self.D).T
        return (self.c * Uxx + self.f(U, Ux, self.pc))[:, 1:-1].ravel()

    def jac(self, t, y):
        U = self.full(y)
        a, b = self.df(U, U @ self.D.T, self.pc)
        blocks = [((self.c[s] * (self.D @ self.D) + a[s][:, None] * np.eye(self.n) + b[s][:, None] * self.D)
                   @ self.Z)[1:-1] for s in range(self.S)]
        return sp.block_diag(blocks, format="csc") if self.S > 1 else blocks[0]


class FieldBox:
    """``u(t_i, x_j, p_k, ...)`` at nodal multi-indices, one Radau method-of-lines solve per parameter point."""

    def __init__(self, name, problem, n: int, axes: list[np.ndarray], names: list[str], times: np.ndarray):
        self.name, self.problem, self.n, self.axes, self.names, self.times = name, problem, n, axes, names, times
        shape = tuple(a.size for a in axes)
        self.values = np.zeros(shape + (times.size, n))  # each solved point's (t, x) field
        self.solved = np.zeros(shape, dtype=bool)

    def __call__(self, indices: np.ndarray) -> np.ndarray:
        params = tuple(indices[:, 2:].T)
        _, c, f, df = PROBLEMS[self.name]
        for point in np.unique(indices[~self.solved[params], 2:], axis=0):
            m = Mol(self.problem, self.n, {nm: a[k:k + 1] for nm, a, k in zip(self.names, self.axes, point)}, c, f, df)
            sol = solve_ivp(m.rhs, self.problem.time_coordinate.domain, m.y0.ravel(), method="Radau", jac=m.jac,
                            rtol=RTOL, atol=ATOL, t_eval=self.times)
            self.values[tuple(point)] = sol.y.T @ m.Z.T + m.h  # (T, n)
            self.solved[tuple(point)] = True
        return self.values[params + (indices[:, 0], indices[:, 1])]


def teneva_column(name, problem, cb, params, n: int, exact: np.ndarray) -> str:
    """The loosest teneva cross over the nodal tensor meeting the tolerance against ``exact`` (T, X, p...)."""
    teneva = load_teneva()
    if teneva is None:
        return "teneva not installed"
    names = [co.name for co in params]
    axes = [co.basis().nodes for co in params]
    times = cb.coordinate(problem.time).basis().nodes
    shape = list(exact.shape)
    budget = 4 * int(np.prod(shape))  # values asked, cached or not; the cost is the points solved
    total = 0.0  # the looser thresholds' runs too: a user would not know the threshold beforehand
    for e in (1e-6, 1e-8, 1e-10):
        box = FieldBox(name, problem, n, axes, names, times)
        started = time.perf_counter()
        full, rank = cross_full(teneva, box, shape, e, budget)
        wall = time.perf_counter() - started
        total += wall
        worst = float(np.max(np.abs(full - exact)))
        if worst <= problem.solver.tolerance:
            break
    met = "" if worst <= problem.solver.tolerance else "NOT within the tolerance down to e = 1e-10: "
    return (f"{met}{wall:.1f} s ({total:.1f} s with the looser e tried) (e = {e:.0e}, nodal error {worst:.2g}, ranks <= {rank}, "
            f"{int(box.solved.sum())} of {box.solved.size} points solved)")


def alternatives(name, problem, cb, samples, times, points):
    """Loop and vectorized sweeps over the codebook's parameter grid: times and errors at the points."""
    _, c, f, df = PROBLEMS[name]
    params = [co for co in cb.coordinates if co.role == "parameter"]
    grids = np.meshgrid(*[co.basis().nodes for co in params], indexing="ij")
    grid = {co.name: g.ravel() for co, g in zip(params, grids)}
    n = cb.coordinate(next(co.name for co in problem.coordinates if co.role == "space")).nodes
    G = next(iter(grid.values())).size
    t_span = problem.time_coordinate.domain
    rng = np.random.default_rng(0)
    picked = rng.choice(G, size=min(LOOP_POINTS, G), replace=False)
    started = time.perf_counter()
    for s in picked:
        m = Mol(problem, n, {k: v[s:s + 1] for k, v in grid.items()}, c, f, df)
        solve_ivp(m.rhs, t_span, m.y0.ravel(), method="Radau", jac=m.jac, rtol=RTOL, atol=ATOL)
    loop = (time.perf_counter() - started) * G / picked.size
    m = Mol(problem, n, grid, c, f, df)
    started = time.perf_counter()
    sol = solve_ivp(m.rhs, t_span, m.y0.ravel(), method="BDF", jac=m.jac, rtol=RTOL, atol=ATOL, dense_output=True)
    vectorized = time.perf_counter() - started
    times_n = cb.coordinate(problem.time).basis().nodes
    exact = np.stack([m.full(sol.sol(t)).reshape([co.nodes for co in params] + [n]) for t in times_n])
    cross = teneva_column(name, problem, cb, params, n, np.moveaxis(exact, -1, 1))  # (T, X, p...)
    # the sweep's error at the random points: its grid values interpolated like the codebook's
    from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights
    W = barycentric_matrix(m.x, chebyshev_weights(n), points)
    errors = []
    for k, t in enumerate(times):
        U = m.full(sol.sol(t)).reshape([co.nodes for co in params] + [n])  # (p1, ..., x)
        vals = U @ W.T  # (p..., P)
        for s in range(next(iter(samples.values())).size):
            v = vals
            for co in params:
                v = np.tensordot(co.basis().interpolation_matrix(np.array([samples[co.name][s]]))[0], v, axes=(0, 0))
            errors.append(v)
    return loop, vectorized, cross, np.array(errors), G, n


def run_problem(name: str) -> str:
    path = PROBLEMS[name][0]
    problem = pgdcli.load_spec(path)
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    build = time.perf_counter() - started
    cb = result.codebook
    if not result.accurate:
        return f"| {name} | refused after {build:.1f} s: {result.message} | | | | |"
    rng = np.random.default_rng(14)
    params = [co for co in problem.coordinates if co.role == "parameter"]
    samples = {co.name: rng.uniform(*co.domain, 5) for co in params}
    times = np.sort(rng.uniform(*problem.time_coordinate.domain, 6))
    xc = next(co for co in problem.coordinates if co.role == "space")
    points = rng.uniform(*xc.domain, 10)
    ref = solve_reference_nonlinear_pde(problem, samples, times, points).values["u"]  # (S, T, P)
    T, X = np.meshgrid(times, points, indexing="ij")
    err = max(float(np.abs(cb.evaluate({problem.time: T.ravel(), xc.name: X.ravel(),
                                        **{k: np.full(T.size, v[s]) for k, v in samples.items()}})["u"]
                               .reshape(T.shape) - ref[s]).max()) for s in range(5))
    with threadpool_limits(1):
        loop, vec, cross, sweep, G, n = alternatives(name, problem, cb, samples, times, points)
    sweep = sweep.reshape(len(times), 5, -1).transpose(1, 0, 2)
    sweep_err = float(np.abs(sweep - ref).max())
    return (f"| {name} | {build:.1f} s, {err:.2g} (tol {problem.solver.tolerance:g}); {G} grid points x {n} x nodes "
            f"| {loop:.1f} s ({loop / build:.2g}x the build) | {vec:.2f} s ({vec / build:.2g}x) | {sweep_err:.2g} "
            f"| {cross} |")


def schemes():
    from pgdcli.algorithms.pde_march import compile_pde_system, march_pde
    from pgdcli.discretization.basis import make_basis

    rows = []
    for name, nodes in (("fisher", {"x": 49, "D": 17, "r": 17}), ("burgers_mild", {"x": 49, "nu": 9})):
        text = (ROOT / "problems" / f"{name.split('_')[0]}.yaml").read_text()
        if name == "burgers_mild":
            text = text.replace("[0.01, 0.1]", "[0.05, 0.1]")
        problem = pgdcli.parse_spec(text, source=f"{name}.yaml")
        bases = {co.name: make_basis("chebyshev", co.domain, nodes[co.name]) for co in problem.coordinates
                 if co.name in nodes}
        system = compile_pde_system(problem, bases)
        times = np.array([0.25, 0.5, 1.0]) * problem.time_coordinate.domain[1]
        rng = np.random.default_rng(1)
        samples = {co.name: rng.uniform(*co.domain, 4) for co in problem.coordinates if co.role == "parameter"}
        x = rng.uniform(0, 1, 30)
        ref = solve_reference_nonlinear_pde(problem, samples, times, x).values["u"]
        for scheme in ("etdrk4", "lawson4"):
            started = time.perf_counter()
            with threadpool_limits(1):
                out = march_pde(system, 1e-6, times, scheme=scheme)
            wall = time.perf_counter() - started
            err = 0.0
            for k, s in enumerate(out.states):
                cores = s[0].cores  # the one species' train
                left = np.einsum("pi,aib->pb", bases["x"].interpolation_matrix(x), cores[0])
                right = None
                for m, core in zip(system.modes[1:], cores[1:]):
                    piece = np.einsum("sj,ajb->sab", bases[m].interpolation_matrix(samples[m]), core)
                    right = piece if right is None else np.einsum("sab,sbc->sac", right, piece)
                err = max(err, float(np.abs(np.einsum("pa,sab->sp", left, right) - ref[:, k]).max()))
            rows.append(f"| {name} {nodes} | {scheme} | {out.steps} ({out.rejected} rejected) | {out.evaluations} "
                        f"| {wall:.1f} s | {err:.2g} |")
    return rows


def main(argv):
    if "--schemes" in argv:
        print("| problem, nodes | scheme | steps | N evaluations | time | max error (360 points) |")
        print("| --- | --- | --- | --- | --- | --- |")
        for row in schemes():
            print(row, flush=True)
        return
    names = [a for a in argv if a in PROBLEMS] or list(PROBLEMS)
    print("| problem | pgdcli build, error at 300 points | loop of solve_ivp (MOL, Radau) | one stacked solve_ivp "
          "(BDF) | sweep's error at the same points | teneva TT-cross over the nodal tensor (t, x, p...), "
          "Radau black box |")
    print("| --- | --- | --- | --- | --- | --- |")
    for name in names:
        print(run_problem(name), flush=True)


if __name__ == "__main__":
    if "--schemes" in sys.argv:
        with published(__file__, "Nonlinear PDE march: ETDRK4 beside Lawson RK4", variant="schemes"):
            main(sys.argv[1:])
    else:
        with published(__file__, "Nonlinear PDEs beside method-of-lines sweeps and teneva's TT-cross"):
            main(sys.argv[1:])

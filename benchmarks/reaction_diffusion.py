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
#: Most unknowns of one stacked solve (BDF's sparse LU): a larger grid is swept in chunks of its points.
CHUNK_UNKNOWNS = 200_000
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
    # linear heat with a source of space and time: ``source(X, t, p)`` (X the space mesh), ``kinds`` per axis
    "moving_source": dict(
        path=ROOT / "problems" / "moving_source.yaml",
        diffusion=lambda p: [p["kappa"]], reaction=lambda U, p: [0.0 * U[0]], jacobian=lambda U, p: [[0.0]],
        source=lambda X, t, p: [np.exp(-(X[0] - 0.5 - p["v"] * t) ** 2 / 0.01)],
        values=None, kinds=("value",)),
    "moving_heater": dict(
        path=ROOT / "problems" / "moving_heater.yaml",
        diffusion=lambda p: [p["kappa"]], reaction=lambda U, p: [0.0 * U[0]], jacobian=lambda U, p: [[0.0]],
        source=lambda X, t, p: [np.sin(np.pi * X[0]) * np.exp(-((X[0] - 0.3 - p["v"] * t) ** 2 + (X[1] - 0.5) ** 2)
                                                               / 0.04)],
        values=None, kinds=("value", "gradient")),
    "hotplate": dict(
        path=ROOT / "problems" / "hotplate.yaml",
        diffusion=lambda p: [0.1], reaction=lambda U, p: [0.0 * U[0]], jacobian=lambda U, p: [[0.0]],
        source=lambda X, t, p: [p["A"] * np.exp(-((X[0] - p["a"]) ** 2 + (X[1] - p["b"]) ** 2) / 0.01)],
        values=None, kinds=("value", "value")),
}


class TimeUp(Exception):
    """A sweep stopped at its deadline."""


class Sweep:
    """The method of lines of one problem on ``n`` nodes per space coordinate, for G stacked parameter points.

    Conditions: zero flux on every side (``values`` None) or values at both ends of the one space
    coordinate (``values(p)``: per species, the data at the low and high end).
    """

    def __init__(self, problem, spec: dict, n: int, grid: dict, deadline: float = float("inf")):
        self.space = [co for co in problem.coordinates if co.role == "space"]
        self.d, self.n, self.spec = len(self.space), n, spec
        self.x = [cheb(n, *co.domain)[0] for co in self.space]
        D = [cheb(n, *co.domain)[1] for co in self.space]
        self.D2 = [Da @ Da for Da in D]
        self.G = next(iter(grid.values())).size
        shape = (self.G,) + (1,) * self.d
        self.p = {k: v.reshape(shape) for k, v in grid.items()}
        self.q = len(problem.unknowns)
        kinds = spec.get("kinds") or ("gradient" if spec["values"] is None else "value",) * self.d
        B, inner = np.array([0, n - 1]), np.arange(1, n - 1)
        self.Z = []  # per space axis (the same conditions for every species on it)
        for Da, kind in zip(D, kinds):
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
        self.mesh, self.deadline = mesh, deadline
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
        if time.perf_counter() > self.deadline:
            raise TimeUp(t)
        U = self.full(y)
        F = self.spec["reaction"](U, self.p)
        if "source" in self.spec:
            F = [f + g for f, g in zip(F, self.spec["source"](self.mesh, t, self.p))]
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


def values_at(parts, times, points, samples, axes):
    """The sweep at (samples S, times T, points P), interpolated over the parameter grid ``axes``.

    ``parts``: ``(Sweep, dense solution)`` of consecutive chunks of the grid's points."""
    from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights

    first = parts[0][0]
    w = chebyshev_weights(first.n)
    W = [barycentric_matrix(x, w, points[:, a]) for a, x in enumerate(first.x)]
    weights = [_bary(nodes, samples[name]) for name, nodes in axes.items()]  # (S, c_a) each
    out = np.empty((first.q, weights[0].shape[0], times.size, points.shape[0]))
    for j, t in enumerate(times):
        full = [m.full(sol(t)) for m, sol in parts]
        for k in range(first.q):
            U = np.concatenate([f[k] for f in full])
            V = np.tensordot(weights[0], U.reshape([a.size for a in axes.values()] + [first.n] * first.d),
                             axes=(1, 0))  # (S, c_2, ..., space...)
            for wa in weights[1:]:
                V = np.einsum("sc,sc...->s...", wa, V)
            out[k, :, j] = V @ W[0].T if first.d == 1 else np.einsum("sij,pi,pj->sp", V, W[0], W[1])
    return out


def _bary(nodes, x):
    """Rows (len(x), len(nodes)) interpolating at x from Chebyshev-Lobatto ``nodes`` (ascending, any interval)."""
    from pgdcli.checks.collocation import barycentric_matrix, chebyshev_weights

    return barycentric_matrix(nodes, chebyshev_weights(nodes.size), np.asarray(x, dtype=float))


def sweep(problem, spec, n: int, counts: dict, tol: float, samples, times, points, deadline: float = float("inf")):
    """Stacked solves on ``n`` space nodes and ``counts`` parameter nodes: ``(seconds, values at the points, note)``.

    The grid's points are stacked into solves of at most :data:`CHUNK_UNKNOWNS` unknowns (one solve when
    they fit). Past ``deadline`` (``time.perf_counter()``), the values are None and the note says how far
    the sweep went."""
    params = [co for co in problem.coordinates if co.role == "parameter"]
    axes = {co.name: cheb(counts[co.name], *co.domain)[0] for co in params}
    mesh = np.meshgrid(*axes.values(), indexing="ij")
    grid = {name: g.ravel() for name, g in zip(axes, mesh)}
    size = mesh[0].size
    d = sum(co.role == "space" for co in problem.coordinates)
    per = max(1, CHUNK_UNKNOWNS // ((n - 2) ** d * len(problem.unknowns)))
    starts = range(0, size, per)
    parts, started = [], time.perf_counter()
    for k, lo in enumerate(starts):
        started_chunk = time.perf_counter()
        m = Sweep(problem, spec, n, {name: g[lo:lo + per] for name, g in grid.items()}, deadline)
        try:
            sol = solve_ivp(m.rhs, problem.time_coordinate.domain, m.y0, method="BDF", jac=m.jac, rtol=1e-3 * tol,
                            atol=1e-3 * tol, dense_output=True)
        except TimeUp as up:
            # the chunks are of one size: each takes about as long as the finished ones, and longer than
            # the one stopped has run so far
            wall, done = time.perf_counter() - started, time.perf_counter() - started_chunk
            each = max(done, (wall - done) / k if k else 0.0)
            return (wall, None, f"stopped at its budget in solve {k + 1} of {len(starts)} (at t = {up.args[0]:.3g}); "
                    f"all {len(starts)}: at least {len(starts) * each:.0f} s")
        if sol.status != 0:
            return time.perf_counter() - started, None, sol.message
        parts.append((m, sol.sol))
    wall = time.perf_counter() - started
    return wall, values_at(parts, times, points, samples, axes), f"{len(starts)} solve(s)"


def check_points(problem, seed: int = 14):
    """5 parameter samples x 4 times x 15 space points (300 points), and the reference's values (q, S, T, P)."""
    rng = np.random.default_rng(seed)
    params = [co for co in problem.coordinates if co.role == "parameter"]
    space = [co for co in problem.coordinates if co.role == "space"]
    samples = {co.name: rng.uniform(*co.domain, 5) for co in params}
    times = np.sort(rng.uniform(*problem.time_coordinate.domain, 4))
    points = np.stack([rng.uniform(*co.domain, 15) for co in space], axis=1)
    ref = solve_reference_nonlinear_pde(problem, samples, times, points if len(space) > 1 else points[:, 0])
    return samples, times, points, np.stack([ref.values[u] for u in problem.unknown_names])


def codebook_error(problem, cb, samples, times, points, exact) -> float:
    """Max abs error of the codebook at the check points."""
    space = [co for co in problem.coordinates if co.role == "space"]
    T = np.repeat(times, points.shape[0])
    err = 0.0
    for s in range(exact.shape[1]):
        where = {problem.time: T, **{co.name: np.tile(points[:, a], times.size) for a, co in enumerate(space)},
                 **{k: np.full(T.size, v[s]) for k, v in samples.items()}}
        got = cb.evaluate(where)
        err = max(err, max(float(np.abs(got[u].reshape(times.size, -1) - exact[i, s]).max())
                           for i, u in enumerate(problem.unknown_names)))
    return err


def measure(name: str, budget: float = float("inf")) -> dict:
    """The build and its error at 300 points; the sweeps, doubled until one meets the tolerance or ``budget``
    seconds of sweeping have passed."""
    spec = PROBLEMS[name]
    problem = pgdcli.load_spec(spec["path"])
    tol = problem.solver.tolerance
    started = time.perf_counter()
    result = pgdcli.solve(problem)
    out = {"build": time.perf_counter() - started, "tol": tol, "result": result}
    if not result.accurate:
        return out
    cb = result.codebook
    samples, times, points, exact = check_points(problem)
    out["error"] = codebook_error(problem, cb, samples, times, points, exact)
    out["nodes"] = nodes = {co.name: cb.coordinate(co.name).nodes for co in problem.coordinates
                            if co.name != problem.time}
    space = [co for co in problem.coordinates if co.role == "space"]
    n, counts = nodes[space[0].name], {co.name: nodes[co.name] for co in problem.coordinates if co.role == "parameter"}
    total, tries, deadline = 0.0, [], time.perf_counter() + budget
    with threadpool_limits(1):
        for _ in range(MAX_DOUBLINGS + 1):
            wall, values, note = sweep(problem, spec, n, counts, tol, samples, times, points, deadline)
            total += wall
            sweep_err = np.inf if values is None else float(np.abs(values - exact).max())
            tries.append(f"{n} x {'x'.join(str(c) for c in counts.values())}: "
                         + (f"{sweep_err:.2g}" if values is not None else note))
            if sweep_err <= tol or time.perf_counter() > deadline:
                break
            n, counts = 2 * n - 1, {k: 2 * c - 1 for k, c in counts.items()}
    out.update(sweep=wall, total=total, sweep_error=sweep_err, grid=int(np.prod(list(counts.values()))), tries=tries)
    return out


def run_problem(name: str) -> str:
    m = measure(name)
    if "error" not in m:
        return f"| {name} | refused after {m['build']:.1f} s: {m['result'].message} | | | |"
    met = "" if m["sweep_error"] <= m["tol"] else "NOT within the tolerance: "
    return (f"| {name} | {m['build']:.1f} s, {m['error']:.2g} (tolerance {m['tol']:g}); nodes {m['nodes']} | {met}"
            f"{m['sweep']:.1f} s ({m['sweep'] / m['build']:.2g}x the build; {m['total']:.1f} s with the coarser tries), "
            f"{m['grid']} grid points, {m['sweep_error']:.2g} | {'; '.join(m['tries'])} |")


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

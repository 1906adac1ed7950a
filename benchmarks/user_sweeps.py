"""Builds of problems written as a user would (no node counts) beside the sweep a user would run instead.

    python benchmarks/user_sweeps.py                    # every problem below
    python benchmarks/user_sweeps.py rossler kuramoto   # some of them
    python benchmarks/user_sweeps.py --budget 60        # seconds of sweeping per problem before it stops

Each problem is a spec written here from its physics (tolerance 1e-6, no node counts), and beside it the
same equations written in numpy. pgdcli builds the codebook (``pgdcli.solve``: automatic resolution and the
error gate included); the alternative is one vectorized DOP853 ``solve_ivp`` over a uniform grid of the
parameters (every grid point's state stacked in one call, rtol = atol = 1e-3 x the tolerance, output on a
uniform time grid), interpolated by tensor-product cubic splines over the parameters and the time
(:func:`tensor_spline`; the interpolants' construction is not counted). Its grid starts at 9 points per parameter and 65 times and doubles both until its
error meets the tolerance at the check points, or until ``--budget`` seconds of sweeping have passed. Both
are measured at the same 200 random points of the box (parameters and time), against solve_ivp (DOP853,
rtol = atol = 1e-12) at each point. Imports and a first small solve of each are done before any timing.

A build refused for lack of nodes whose message names the ``solver.max_nodes`` predicted to meet the
tolerance is built again with it, as a user would, and both builds are counted. The ratio is the sweep that
met the tolerance (without its coarser tries) over the build: above 1, pgdcli is faster. One run each; read the ratios, not the seconds, on a shared machine.
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.integrate import solve_ivp
from scipy.interpolate import NdBSpline, make_interp_spline

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from _machine import markdown_table, published  # noqa: E402

import pgdcli  # noqa: E402
from pgdcli.problem.spec import parse_spec  # noqa: E402

TOLERANCE = 1e-6
CHECK_POINTS = 200


@dataclass
class UserProblem:
    """A spec, and the same model in numpy: ``rhs(t, y, p)`` with ``y`` (q, G) and ``p`` (d, G) arrays,
    ``initial(p)`` (q, G); ``span`` the time domain, ``box`` the parameters' (low, high)."""

    spec: str
    rhs: Callable
    initial: Callable
    span: tuple
    box: dict


def _spec(name, description, t1, box, unknowns, equations) -> str:
    coords = "\n".join(f"  {p}: {{domain: [{lo}, {hi}]}}" for p, (lo, hi) in box.items())
    unk = "\n".join(f"  {u}: {{initial: \"{v}\"}}" for u, v in unknowns.items())
    eqs = "\n".join(f"  - \"{e}\"" for e in equations)
    return (f"name: {name}\ndescription: \"{description}\"\ncoordinates:\n  t: {{domain: [0, {t1}]}}\n{coords}\n"
            f"unknowns:\n{unk}\nequations:\n{eqs}\nsolver:\n  tolerance: {TOLERANCE}\n")


def _rossler() -> UserProblem:
    box = {"c": (4.0, 6.0)}
    spec = _spec("rossler", "Rossler attractor's first turns, c as a coordinate", 5, box,
                 {"x": "1", "y": "1", "z": "0"},
                 ["der(x) = -y - z", "der(y) = x + 0.2*y", "der(z) = 0.2 + z*(x - c)"])
    return UserProblem(spec, lambda t, y, p: np.stack([-y[1] - y[2], y[0] + 0.2 * y[1], 0.2 + y[2] * (y[0] - p[0])]),
                       lambda p: np.stack([np.ones_like(p[0]), np.ones_like(p[0]), np.zeros_like(p[0])]), (0, 5), box)


def _kuramoto() -> UserProblem:
    box = {"K": (0.0, 2.0)}
    w = (1.0, 1.5, 2.0)
    spec = _spec("kuramoto", "three Kuramoto oscillators, coupling K as a coordinate", 10, box,
                 {"a": "0", "b": "1", "c": "2"},
                 [f"der(a) = {w[0]} + K/3*(sin(b - a) + sin(c - a))",
                  f"der(b) = {w[1]} + K/3*(sin(a - b) + sin(c - b))",
                  f"der(c) = {w[2]} + K/3*(sin(a - c) + sin(b - c))"])

    def rhs(t, y, p):
        k = p[0] / 3
        return np.stack([w[i] + k * sum(np.sin(y[j] - y[i]) for j in range(3) if j != i) for i in range(3)])

    return UserProblem(spec, rhs, lambda p: np.stack([np.zeros_like(p[0]), np.ones_like(p[0]),
                                                      2 * np.ones_like(p[0])]), (0, 10), box)


def _pendulum() -> UserProblem:
    box = {"th0": (0.1, 0.5)}
    spec = _spec("damped_pendulum", "a damped pendulum released from th0", 10, box, {"th": "th0", "w": "0"},
                 ["der(th) = w", "der(w) = -sin(th) - 0.1*w"])
    return UserProblem(spec, lambda t, y, p: np.stack([y[1], -np.sin(y[0]) - 0.1 * y[1]]),
                       lambda p: np.stack([p[0], np.zeros_like(p[0])]), (0, 10), box)


def _fitzhugh() -> UserProblem:
    box = {"a": (0.6, 0.8), "b": (0.7, 0.9)}
    spec = _spec("fitzhugh", "FitzHugh-Nagumo neuron driven by I = 0.5, a and b as coordinates", 20, box,
                 {"v": "-1", "w": "1"},
                 ["der(v) = v - v**3/3 - w + 0.5", "der(w) = 0.08*(v + a - b*w)"])
    return UserProblem(spec, lambda t, y, p: np.stack([y[0] - y[0] ** 3 / 3 - y[1] + 0.5,
                                                       0.08 * (y[0] + p[0] - p[1] * y[1])]),
                       lambda p: np.stack([-np.ones_like(p[0]), np.ones_like(p[0])]), (0, 20), box)


def _enzyme() -> UserProblem:
    box = {"vmax": (0.5, 2.0), "km": (0.5, 5.0)}
    spec = _spec("enzyme2", "Michaelis-Menten depletion of s0 = 8, vmax and km as coordinates", 10, box,
                 {"s": "8", "p": "0"}, ["der(s) = -vmax*s/(km + s)", "der(p) = vmax*s/(km + s)"])

    def rhs(t, y, p):
        rate = p[0] * y[0] / (p[1] + y[0])
        return np.stack([-rate, rate])

    return UserProblem(spec, rhs, lambda p: np.stack([8 * np.ones_like(p[0]), np.zeros_like(p[0])]), (0, 10), box)


def _projectile() -> UserProblem:
    box = {"v0": (10.0, 30.0), "a": (0.2, 1.3)}
    spec = _spec("projectile2", "a ball with quadratic drag 0.02, launch speed v0 and angle a", 2, box,
                 {"x": "0", "y": "0", "vx": "v0*cos(a)", "vy": "v0*sin(a)"},
                 ["der(x) = vx", "der(y) = vy", "der(vx) = -0.02*vx*sqrt(vx**2 + vy**2)",
                  "der(vy) = -9.81 - 0.02*vy*sqrt(vx**2 + vy**2)"])

    def rhs(t, y, p):
        speed = np.sqrt(y[2] ** 2 + y[3] ** 2)
        return np.stack([y[2], y[3], -0.02 * y[2] * speed, -9.81 - 0.02 * y[3] * speed])

    return UserProblem(spec, rhs, lambda p: np.stack([0 * p[0], 0 * p[0], p[0] * np.cos(p[1]), p[0] * np.sin(p[1])]),
                       (0, 2), box)


def _reactor() -> UserProblem:
    box = {"E": (4.0, 8.0), "B": (0.1, 0.3)}
    spec = _spec("reactor", "an exothermic batch reactor: Arrhenius rate exp(E (1 - 1/T)), heat release B", 5, box,
                 {"c": "1", "T": "1"},
                 ["der(c) = -exp(E*(1 - 1/T))*c", "der(T) = B*exp(E*(1 - 1/T))*c - 0.5*(T - 1)"])

    def rhs(t, y, p):
        rate = np.exp(p[0] * (1 - 1 / y[1])) * y[0]
        return np.stack([-rate, p[1] * rate - 0.5 * (y[1] - 1)])

    return UserProblem(spec, rhs, lambda p: np.stack([np.ones_like(p[0]), np.ones_like(p[0])]), (0, 5), box)


PROBLEMS = {"rossler": _rossler, "kuramoto": _kuramoto, "damped_pendulum": _pendulum, "fitzhugh": _fitzhugh,
            "enzyme2": _enzyme, "projectile2": _projectile, "reactor": _reactor}


def stacked(problem: UserProblem, params: np.ndarray):
    """The right-hand side of every parameter point's state in one vector: ``params`` (d, G)."""
    G = params.shape[1]

    def fun(t, y):
        return problem.rhs(t, y.reshape(-1, G), params).reshape(-1)

    return fun, problem.initial(params).reshape(-1)


def check_points(problem: UserProblem, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(params (d, P), times (P,), reference (q, P))``: random points and solve_ivp at each (1e-12)."""
    lo, hi = np.array([b[0] for b in problem.box.values()]), np.array([b[1] for b in problem.box.values()])
    params = lo[:, None] + (hi - lo)[:, None] * rng.uniform(size=(lo.size, CHECK_POINTS))
    times = rng.uniform(*problem.span, CHECK_POINTS)
    reference = np.empty((problem.initial(params[:, :1]).shape[0], CHECK_POINTS))
    for k in range(CHECK_POINTS):
        fun, y0 = stacked(problem, params[:, k:k + 1])
        sol = solve_ivp(fun, problem.span, y0, method="DOP853", rtol=1e-12, atol=1e-12, t_eval=[times[k]])
        reference[:, k] = sol.y[:, 0]
    return params, times, reference


def sweep(problem: UserProblem, nodes: int, times: int):
    """One vectorized solve_ivp over the uniform grid (``nodes`` per parameter, ``times`` output times): the
    interpolants per unknown and the seconds it took."""
    axes = [np.linspace(lo, hi, nodes) for lo, hi in problem.box.values()]
    grid = np.stack([g.ravel() for g in np.meshgrid(*axes, indexing="ij")])
    t = np.linspace(*problem.span, times)
    start = time.perf_counter()
    fun, y0 = stacked(problem, grid)
    sol = solve_ivp(fun, problem.span, y0, method="DOP853", rtol=1e-3 * TOLERANCE, atol=1e-3 * TOLERANCE, t_eval=t)
    seconds = time.perf_counter() - start
    values = sol.y.reshape(-1, grid.shape[1], times)  # (q, G, T)
    shape = tuple(a.size for a in axes) + (times,)
    return [tensor_spline((*axes, t), v.reshape(shape)) for v in values], seconds


def tensor_spline(axes, values: np.ndarray) -> NdBSpline:
    """The tensor-product cubic spline interpolating ``values`` on the grid of ``axes`` (not-a-knot ends),
    its coefficients solved one axis at a time. (RegularGridInterpolator's cubic method solves them all at
    once, iteratively by default: it stops near 1e-6 relative and then misses the grid's own values by as
    much, 4e-6 on sin x cos t; a direct sparse solve of the whole system runs out of memory on these grids.)"""
    c, knots = np.asarray(values, dtype=float), []
    for a, x in enumerate(axes):
        spline = make_interp_spline(x, np.moveaxis(c, a, 0), k=3, axis=0)
        c, knots = np.moveaxis(spline.c, 0, a), knots + [spline.t]
    return NdBSpline(tuple(knots), c, 3)


def row(name: str, budget: float) -> tuple:
    problem = PROBLEMS[name]()
    params, times, reference = check_points(problem, np.random.default_rng(7))
    spec, build, refusals = parse_spec(problem.spec, source=f"{name}.yaml"), 0.0, []
    while True:
        start = time.perf_counter()
        result = pgdcli.solve(spec)
        build += time.perf_counter() - start
        hint = re.search(r"solver\.max_nodes: (\d+) is predicted", result.message or "")
        if result.accurate or hint is None or refusals:
            break
        # refused, with the setting that would meet the tolerance: a user follows the hint (both builds counted)
        refusals.append(f"refused at first ({build:.2f} s), then built with solver.max_nodes {hint.group(1)}")
        spec = parse_spec(problem.spec + f"  max_nodes: {hint.group(1)}\n", source=f"{name}.yaml")
    if not result.accurate:
        return name, len(problem.box), f"refused in {build:.2f} s: {result.message}", "", ""
    got = result.codebook.evaluate({"t": times, **{p: params[i] for i, p in enumerate(problem.box)}})
    error = max(float(np.max(np.abs(got[u] - reference[i]))) for i, u in enumerate(spec.unknown_names))
    nodes = ", ".join(f"{c.name} {c.nodes}" for c in result.codebook.coordinates)
    build_text = "; ".join([f"{build:.2f} s, error {error:.1e}", *refusals, f"nodes {nodes}"])
    tried, swept, met = [], 0.0, None
    nodes, count = 9, 65
    points = np.vstack([params, times[None]]).T
    while swept < budget:
        interpolants, seconds = sweep(problem, nodes, count)
        swept += seconds
        err = max(float(np.max(np.abs(f(points) - reference[i]))) for i, f in enumerate(interpolants))
        tried.append(f"{nodes}^{len(problem.box)} x {count} t: {err:.1e} ({seconds:.2f} s)")
        if err <= TOLERANCE:
            met = seconds
            break
        nodes, count = 2 * nodes - 1, 2 * count - 1
    if met is None:
        return (name, len(problem.box), build_text, f"not met after {swept:.0f} s; " + "; ".join(tried),
                f"> {swept / build:.2g}")
    return name, len(problem.box), build_text, "; ".join(tried), f"{met / build:.2g}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"problems (default: {', '.join(PROBLEMS)})")
    parser.add_argument("--budget", type=float, default=120.0, help="seconds of sweeping per problem (default 120)")
    args = parser.parse_args()
    names = args.names or list(PROBLEMS)
    unknown = sorted(set(names) - set(PROBLEMS))
    if unknown:
        parser.error(f"unknown problem(s) {', '.join(unknown)}; expected some of {', '.join(PROBLEMS)}")
    pgdcli.solve(parse_spec(_spec("warm", "imports", 1, {"k": (1, 2)}, {"u": "1"}, ["der(u) = -k*u"]),
                            source="warm.yaml"))  # imports and first-call costs, untimed
    with published(__file__, "Builds of problems written as a user would beside a vectorized sweep"):
        rows = [row(name, args.budget) for name in names]
        print(markdown_table(rows, ("problem", "parameters", f"pgdcli build (gate included), error at "
                                    f"{CHECK_POINTS} points (tolerance {TOLERANCE:g})",
                                    "vectorized DOP853 over a uniform grid + cubic interpolation: grids tried, "
                                    "error at the same points (seconds)", "sweep / build")))


if __name__ == "__main__":
    main()

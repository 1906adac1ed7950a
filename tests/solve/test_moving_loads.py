"""The shipped linear problems the enrichment cannot finish, solved from their specs and checked against
references written here (scipy solve_ivp at tight tolerance; a Chebyshev method of lines), at random points
of the parameter box plus its corners and the midpoints of its faces."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import BarycentricInterpolator
from threadpoolctl import threadpool_limits

import pgdcli
from conftest import PROBLEMS


def box_points(domains: dict[str, tuple[float, float]], random: int, seed: int) -> list[dict[str, float]]:
    """``random`` uniform points of the box, its corners and the midpoints of its faces."""
    rng = np.random.default_rng(seed)
    names = list(domains)
    lows = np.array([domains[n][0] for n in names])
    highs = np.array([domains[n][1] for n in names])
    points = list(rng.uniform(lows, highs, size=(random, len(names))))
    points += [np.array(c) for c in itertools.product(*[domains[n] for n in names])]
    mids = 0.5 * (lows + highs)
    for k, side in itertools.product(range(len(names)), (0, 1)):
        face = mids.copy()
        face[k] = (lows, highs)[side][k]
        points.append(face)
    return [dict(zip(names, map(float, p))) for p in points]


def solved(name: str):
    result = pgdcli.solve(pgdcli.load_spec(PROBLEMS / f"{name}.yaml"))
    assert result.converged and result.accurate, result.message
    return result


# ----------------------------------------------------------------------------------------------
# the quarter car: a driven two-mass system, against solve_ivp (DOP853, rtol 1e-12)
# ----------------------------------------------------------------------------------------------
def suspension_reference(w: float, c: float, times: np.ndarray) -> np.ndarray:
    ks, kt, mu, amplitude = 20.0, 120.0, 0.1, 0.02

    def rhs(t, y):
        zs, zu, vs, vu = y
        spring = ks * (zs - zu) + c * (vs - vu)
        return [vs, vu, -spring, (spring - kt * (zu - amplitude * np.sin(w * t))) / mu]

    sol = solve_ivp(rhs, (0.0, 3.0), [0.0, 0.0, 0.0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14, t_eval=times)
    assert sol.success
    return sol.y[:2]


@pytest.mark.slow
def test_suspension_falls_back_to_the_tensor_train_solver_and_meets_its_tolerance():
    result = solved("suspension")
    report = result.codebook.report
    # auto: the enrichment first; it stalls (or would need more than max_modes), the tensor-train solver runs
    assert report["method"] == "amen"
    assert "the enrichment stopped" in report["method_reason"] and "tensor-train solver ran instead" in \
        report["method_reason"]
    assert any("tensor-train solver ran instead" in w for w in result.warnings)
    cb = result.codebook
    times = np.sort(np.concatenate([[0.0, 3.0], np.random.default_rng(2).uniform(0.0, 3.0, 40)]))
    worst = 0.0
    for p in box_points({"w": (2.0, 12.0), "c": (0.5, 2.0)}, random=12, seed=3):
        ref = suspension_reference(p["w"], p["c"], times)
        values = cb(t=times, **p)
        worst = max(worst, float(np.max(np.abs(values["zs"] - ref[0]))), float(np.max(np.abs(values["zu"] - ref[1]))))
    assert worst <= 1e-6, worst


# ----------------------------------------------------------------------------------------------
# the moving heat source, against a Chebyshev method of lines (BDF, rtol 1e-11)
# ----------------------------------------------------------------------------------------------
def chebyshev(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Chebyshev-Gauss-Lobatto points on [-1, 1] (descending) and the differentiation matrix (Trefethen)."""
    x = np.cos(np.pi * np.arange(n + 1) / n)
    c = np.hstack([2.0, np.ones(n - 1), 2.0]) * (-1.0) ** np.arange(n + 1)
    dx = x[:, None] - x[None, :]
    d = np.outer(c, 1.0 / c) / (dx + np.eye(n + 1))
    return x, d - np.diag(d.sum(axis=1))


def moving_source_reference(v: float, kappa: float, xs: np.ndarray, times: np.ndarray, n: int = 120) -> np.ndarray:
    """u(t, x) of u_t = kappa u_xx + exp(-(x - 0.5 - v t)^2 / 0.01), u = 0 at x = 0, 2, u(0) = 0: (T, X)."""
    s, d = chebyshev(n)
    x = 1.0 + s  # [0, 2]: d/dx = d/ds
    lap = kappa * (d @ d)[1:-1, 1:-1]
    inner = x[1:-1]

    def rhs(t, u):
        return lap @ u + np.exp(-(inner - 0.5 - v * t) ** 2 / 0.01)

    with threadpool_limits(1):
        sol = solve_ivp(rhs, (0.0, 1.0), np.zeros(n - 1), method="BDF", jac=lap, rtol=1e-11, atol=1e-13,
                        t_eval=times)
    assert sol.success
    values = np.vstack([np.zeros((1, times.size)), sol.y, np.zeros((1, times.size))])  # (x nodes, T)
    return BarycentricInterpolator(x, values, axis=0)(xs).T


def test_moving_source_reference_is_converged():
    xs = np.linspace(0.0, 2.0, 41)
    times = np.array([0.3, 1.0])
    a = moving_source_reference(1.0, 0.01, xs, times)
    b = moving_source_reference(1.0, 0.01, xs, times, n=80)
    assert np.max(np.abs(a - b)) < 1e-9


@pytest.mark.slow
def test_moving_source_meets_its_tolerance_against_a_method_of_lines():
    result = solved("moving_source")
    assert result.codebook.report["method"] == "amen"
    cb = result.codebook
    rng = np.random.default_rng(4)
    times = np.sort(np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 12)]))
    xs = np.concatenate([[0.0, 2.0], rng.uniform(0.0, 2.0, 30)])
    worst = 0.0
    for p in box_points({"v": (0.2, 1.0), "kappa": (0.01, 0.1)}, random=8, seed=5):
        ref = moving_source_reference(p["v"], p["kappa"], xs, times)
        t, x = np.meshgrid(times, xs, indexing="ij")
        values = cb(t=t, x=x, **p)["u"]
        worst = max(worst, float(np.max(np.abs(values - ref))))
    assert worst <= 1e-6, worst


# ----------------------------------------------------------------------------------------------
# a heater moving across a plate, against a 2-D Chebyshev method of lines (BDF, rtol 1e-10; 28 x 28 nodes,
# within 1e-9 of 44 x 44)
# ----------------------------------------------------------------------------------------------
def moving_heater_reference(v: float, kappa: float, xs: np.ndarray, ys: np.ndarray, times: np.ndarray,
                            n: int = 28) -> np.ndarray:
    """u(t, x, y) of the plate: u = 0 at x = 0, 1 and u_y = 0 at y = 0, 1 eliminated; shape (T, X, Y)."""
    s, d = chebyshev(n)
    x = y = (1.0 + s) / 2.0
    d = 2.0 * d
    d2 = d @ d
    ends, inner = [0, n], slice(1, n)
    # Neumann ends: u_ends = -D[ends, ends]^-1 D[ends, inner] u_inner
    to_ends = -np.linalg.solve(d[np.ix_(ends, ends)], d[ends, inner])
    extend = np.vstack([to_ends[:1], np.eye(n - 1), to_ends[1:]])  # y values at all nodes from the inner ones
    lap_y = d2[inner, :] @ extend
    lap = kappa * (np.kron(d2[inner, inner], np.eye(n - 1)) + np.kron(np.eye(n - 1), lap_y))
    gx, gy = np.meshgrid(x[inner], y[inner], indexing="ij")

    def rhs(t, u):
        source = np.sin(np.pi * gx) * np.exp(-((gx - 0.3 - v * t) ** 2 + (gy - 0.5) ** 2) / 0.04)
        return lap @ u + source.reshape(-1)

    with threadpool_limits(1):  # small dense LUs: many BLAS threads on a busy machine only wait for each other
        sol = solve_ivp(rhs, (0.0, 1.0), np.zeros((n - 1) ** 2), method="BDF", jac=lap, rtol=1e-10, atol=1e-12,
                        t_eval=times)
    assert sol.success
    inner_values = sol.y.T.reshape(times.size, n - 1, n - 1)
    full = np.zeros((times.size, n + 1, n + 1))
    full[:, inner, :] = inner_values @ extend.T
    along_x = BarycentricInterpolator(x, full, axis=1)(xs)  # (T, X, n + 1)
    return BarycentricInterpolator(y, along_x, axis=2)(ys)


def test_moving_heater_reference_is_converged():
    xs, ys = np.linspace(0.0, 1.0, 9), np.linspace(0.0, 1.0, 7)
    times = np.array([0.2, 1.0])
    a = moving_heater_reference(0.4, 0.05, xs, ys, times)
    b = moving_heater_reference(0.4, 0.05, xs, ys, times, n=24)
    assert np.max(np.abs(a - b)) < 1e-8


@pytest.mark.slow
def test_moving_heater_meets_its_tolerance_against_a_method_of_lines():
    result = solved("moving_heater")
    cb = result.codebook
    rng = np.random.default_rng(6)
    times = np.sort(np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 6)]))
    xs = np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 8)])
    ys = np.concatenate([[0.0, 1.0], rng.uniform(0.0, 1.0, 6)])
    t, x, y = np.meshgrid(times, xs, ys, indexing="ij")
    worst = 0.0
    for p in box_points({"v": (0.0, 0.4), "kappa": (0.05, 0.2)}, random=3, seed=7):
        ref = moving_heater_reference(p["v"], p["kappa"], xs, ys, times)
        worst = max(worst, float(np.max(np.abs(cb(t=t, x=x, y=y, **p)["u"] - ref))))
    assert worst <= 1e-5, worst

"""Sums of Hadamard products by the one-site cross (pgdcli.tensors.cross_products).

Checked against the full tensors formed with numpy (never with the cross itself), on smooth
low-rank factors the march meets (cosines of the coordinates) and on a fresh rigid-body-like
march against scipy's solve_ivp at random grid points.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from threadpoolctl import threadpool_limits

from pgdcli.tensors.cross_products import ProductCross, round_products_by_cross
from pgdcli.tensors.tt import TT, tt_ones


def _smooth_train(shape, rank, rng, decay=0.3):
    """``sum_j decay^j prod_k cos(w_jk x_k + phi_jk)`` on uniform grids of [0, 1], as cores (rank ``rank``)."""
    cores = []
    for k, n in enumerate(shape):
        x = np.linspace(0.0, 1.0, n)
        w = rng.uniform(0.5, 2.0, size=rank) * np.arange(1, rank + 1)
        phi = rng.uniform(size=rank)
        values = np.cos(np.outer(w, x) + phi[:, None])  # (rank, n)
        if k == 0:
            core = (values * decay ** np.arange(rank)[:, None]).T[None]  # (1, n, rank)
        elif k == len(shape) - 1:
            core = values[:, :, None]  # (rank, n, 1)
        else:
            core = np.zeros((rank, n, rank))
            core[np.arange(rank), :, np.arange(rank)] = values
        cores.append(core)
    return TT(cores)


@pytest.mark.parametrize("rank, d", [(1, 4), (3, 5), (4, 6)])
def test_cross_of_products_matches_the_full_tensor_and_warm_starts(rank, d):
    rng = np.random.default_rng(100 + rank)
    shape = (7,) * d
    a, b, c, e = (_smooth_train(shape, rank, rng) for _ in range(4))
    terms = [(0.7, a, b), (-1.3, c, e), (0.5, a, tt_ones(shape))]
    full = 0.7 * a.full() * b.full() - 1.3 * c.full() * e.full() + 0.5 * a.full()
    rms_target = 1e-8
    delta = rms_target * np.sqrt(full.size)
    cross = ProductCross(shape, np.random.default_rng(3))
    sweeps = []
    for _ in range(3):  # the same function again: the index sets of the last call are reused
        x, info = round_products_by_cross(cross, terms, absolute=delta, max_rank=150)
        assert x is not None, info.message
        error = x.full() - full
        assert np.sqrt(np.mean(error ** 2)) <= rms_target
        assert np.linalg.norm(error) <= delta
        sweeps.append(info.sweeps)
    assert sweeps[1] <= 2 and sweeps[2] <= 2


def test_cross_of_products_reports_a_rank_cap_instead_of_a_wrong_train():
    rng = np.random.default_rng(7)
    shape = (8,) * 5
    a, b = _smooth_train(shape, 6, rng, decay=0.9), _smooth_train(shape, 6, rng, decay=0.9)
    cross = ProductCross(shape, np.random.default_rng(4), max_sweeps=4)
    x, info = round_products_by_cross(cross, [(1.0, a, b)], absolute=1e-12, max_rank=3)
    assert x is None and "above" in info.message


def _kirchhoff(y, c):
    """The rigid body's right-hand side (Kirchhoff, written by hand): y = (u1, u2, u3, w1, w2, w3) rows."""
    m, M, I, J = 1.0, (0.2, 0.5, 0.8), (1.0, 1.5, 2.0), (0.1, 0.2, 0.3)
    u1, u2, u3, w1, w2, w3 = y
    return np.array([
        ((m + M[1]) * u2 * w3 - (m + M[2]) * u3 * w2) / (m + M[0]),
        ((m + M[2]) * u3 * w1 - (m + M[0]) * u1 * w3) / (m + M[1]),
        ((m + M[0]) * u1 * w2 - (m + M[1]) * u2 * w1 + c) / (m + M[2]),
        (((J[1] + I[1]) - (J[2] + I[2])) * w2 * w3 + (M[1] - M[2]) * u2 * u3) / (J[0] + I[0]),
        (((J[2] + I[2]) - (J[0] + I[0])) * w3 * w1 + (M[2] - M[0]) * u3 * u1) / (J[1] + I[1]),
        (((J[0] + I[0]) - (J[1] + I[1])) * w1 * w2 + (M[0] - M[1]) * u1 * u2) / (J[2] + I[2]),
    ])


RIGID = """
name: rigid_cross
constants: {m: 1, M1: 0.2, M2: 0.5, M3: 0.8, I1: 1, I2: 1.5, I3: 2, J1: 0.1, J2: 0.2, J3: 0.3, fg3: -0.5}
coordinates:
  t:   {domain: [0, 0.6], nodes: 8}
  u10: {domain: [0.5, 1.5], nodes: 5}
  u20: {domain: [0.5, 1.5], nodes: 5}
  u30: {domain: [0.5, 1.5], nodes: 5}
  w10: {domain: [0.5, 1.5], nodes: 5}
  w20: {domain: [0.5, 1.5], nodes: 5}
  w30: {domain: [0.5, 1.5], nodes: 5}
unknowns:
  u1: {initial: u10}
  u2: {initial: u20}
  u3: {initial: u30}
  w1: {initial: w10}
  w2: {initial: w20}
  w3: {initial: w30}
equations:
  - "(m + M1)*der(u1) = (m + M2)*u2*w3 - (m + M3)*u3*w2"
  - "(m + M2)*der(u2) = (m + M3)*u3*w1 - (m + M1)*u1*w3"
  - "(m + M3)*der(u3) = (m + M1)*u1*w2 - (m + M2)*u2*w1 + fg3"
  - "(J1 + I1)*der(w1) = ((J2 + I2) - (J3 + I3))*w2*w3 + (M2 - M3)*u2*u3"
  - "(J2 + I2)*der(w2) = ((J3 + I3) - (J1 + I1))*w3*w1 + (M3 - M1)*u3*u1"
  - "(J3 + I3)*der(w3) = ((J1 + I1) - (J2 + I2))*w1*w2 + (M1 - M2)*u1*u2"
solver: {tolerance: 1e-6}
"""


def test_march_with_products_by_cross_matches_solve_ivp(monkeypatch):
    """Every right-hand side through the cross (exact path disabled), against solve_ivp at 300 grid points."""
    import pgdcli.algorithms.polynomial_rhs as rhs
    from pgdcli import parse_spec
    from pgdcli.algorithms.march import compile_system, march

    monkeypatch.setattr(rhs, "PRODUCTS", "cross")
    monkeypatch.setattr(rhs, "EXACT_RANK_LIMIT", 0)
    problem = parse_spec(RIGID, source="rigid_cross.yaml")
    with threadpool_limits(1):
        system = compile_system(problem, 1e-6)
        result = march(system, 1e-6, max_rank=200)
    stats = result.roundings
    assert stats["product_crosses"] > 0 and stats.get("product_cross_fallbacks", 0) <= stats["product_crosses"] // 10
    rng = np.random.default_rng(5)
    idx = rng.integers(0, 5, size=(300, 6))
    nodes = system.bases["u10"].nodes
    y0 = nodes[idx].T  # (6, 300)
    t_end = float(result.times[-1])
    ref = solve_ivp(lambda t, y: _kirchhoff(y.reshape(6, -1), -0.5).ravel(), (0.0, t_end), y0.ravel(),
                    method="DOP853", rtol=1e-12, atol=1e-12).y[:, -1].reshape(6, -1)
    from pgdcli.tensors.cross import tt_values_at
    got = np.array([tt_values_at(u, idx) for u in result.states[-1]])
    assert np.max(np.abs(got - ref)) <= 2e-5  # the march's RMS target 1e-6; the worst point 5-20x (module docs)
    assert np.sqrt(np.mean((got - ref) ** 2)) <= 2e-6

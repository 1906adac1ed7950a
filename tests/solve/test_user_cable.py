"""A user's 4-coordinate heat problem with an x-dependent conductivity: it needs more modes than the
default max_modes, and meets its tolerance when given them.

The reference is a Chebyshev collocation method of lines written here (Radau, rtol 1e-12), sharing
nothing with the package.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.interpolate import BarycentricInterpolator
from threadpoolctl import threadpool_limits

import pgdcli

SPEC = Path(__file__).resolve().parents[1] / "user_problems" / "cable.yaml"


def _chebyshev(n):
    """Nodes on [0, 1] and the differentiation matrix (Trefethen, Spectral Methods in MATLAB, cheb)."""
    x = np.cos(np.pi * np.arange(n + 1) / n)
    c = np.r_[2.0, np.ones(n - 1), 2.0] * (-1.0) ** np.arange(n + 1)
    dx = x[:, None] - x[None, :]
    d = np.outer(c, 1 / c) / (dx + np.eye(n + 1))
    d -= np.diag(d.sum(axis=1))
    return (1 - x) / 2, -2 * d


def _reference(a, b, times, xs, n=64):
    x, d = _chebyshev(n)
    op = (np.diag(1 + a * x) @ d @ d + a * d - b * np.eye(n + 1))[1:-1, 1:-1]  # u = 0 at both ends
    sol = solve_ivp(lambda t, u: op @ u, (0, max(times)), np.sin(np.pi * x[1:-1]) ** 3, method="Radau",
                    jac=op, rtol=1e-12, atol=1e-13, t_eval=times)
    return np.array([BarycentricInterpolator(x, np.r_[0.0, sol.y[:, j], 0.0])(xs) for j in range(len(times))])


@pytest.mark.slow
def test_cable_meets_its_tolerance_against_an_independent_method_of_lines():
    with threadpool_limits(1):
        result = pgdcli.solve(SPEC)
    assert result.accurate is True, result.message
    cb = result.codebook
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(16):  # 16 parameter points x 4 times x 5 positions = 320 points
        a, b = rng.uniform(0, 1), rng.uniform(0, 2)
        times = np.sort(rng.uniform(0, 0.5, 4) ** 2)  # early times, where the solution moves most
        xs = rng.uniform(0, 1, 5)
        ref = _reference(a, b, times, xs)
        for i, t in enumerate(times):
            for j, x in enumerate(xs):
                worst = max(worst, abs(float(cb(t=t, x=x, a=a, b=b)["u"]) - ref[i, j]))
    assert worst <= 1e-6

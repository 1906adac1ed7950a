"""A user's nonlinear reaction-diffusion front through `pgd solve`, checked against a Chebyshev method of
lines written here (Radau, rtol 1e-12, with its exact Jacobian), sharing nothing with the package."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.integrate import solve_ivp
from scipy.interpolate import BarycentricInterpolator

from pgdcli import Codebook
from pgdcli.cli.main import cli

SPEC = Path(__file__).resolve().parents[1] / "user_problems" / "front.yaml"


def _initial(x):
    return 0.5 * (1 - np.tanh(10 * (x - 0.3))) + 0.0024726232 * (1 - x) - 8.3152802e-07 * x


def _reference(diffusion, k, times, xs, n=128):
    """u at times x xs: Chebyshev collocation on [0, 1], u(0) = 1 and u(1) = 0 eliminated."""
    z = np.cos(np.pi * np.arange(n + 1) / n)
    c = np.r_[2.0, np.ones(n - 1), 2.0] * (-1.0) ** np.arange(n + 1)
    d = np.outer(c, 1 / c) / (z[:, None] - z[None, :] + np.eye(n + 1))
    d -= np.diag(d.sum(axis=1))
    x, d = (1 - z) / 2, -2 * d
    d2 = (d @ d)[1:-1]

    def rhs(t, u):
        return diffusion * (d2 @ np.r_[1.0, u, 0.0]) + k * u**2 * (1 - u)

    def jac(t, u):
        return diffusion * d2[:, 1:-1] + np.diag(k * (2 * u - 3 * u**2))

    sol = solve_ivp(rhs, (0, max(times)), _initial(x[1:-1]), method="Radau", jac=jac, rtol=1e-12, atol=1e-13,
                    t_eval=times)
    return np.array([BarycentricInterpolator(x, np.r_[1.0, sol.y[:, j], 0.0])(xs) for j in range(len(times))])


@pytest.mark.slow
def test_front_meets_its_tolerance_and_reports_its_march(tmp_path):
    out = tmp_path / "front.h5"
    res = CliRunner().invoke(cli, ["solve", str(SPEC), "-o", str(out), "--format", "json", "-q"])
    assert res.exit_code == 0, res.output
    summary = json.loads(res.stdout)
    assert summary["method"] == "pde march" and summary["residual"] is None and summary["steps"] > 0
    cb = Codebook.load(out)
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(20):  # 20 parameter points x 4 times x 4 positions = 320 points
        diffusion, k = rng.uniform(0.01, 0.05), rng.uniform(2, 6)
        times, xs = np.sort(rng.uniform(0, 1, 4)), rng.uniform(0, 1, 4)
        ref = _reference(diffusion, k, times, xs)
        got = cb(t=times[:, None], x=xs[None, :], D=diffusion, k=k)["u"]
        worst = max(worst, float(np.max(np.abs(got - ref))))
    assert worst <= 1e-6

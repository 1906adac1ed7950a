"""problems/hotplate.yaml (2-D heat, a Gaussian heater of amplitude A at (a, b), edges held at 0) solved
from its spec and checked against its exact solution, a double sine series written here:

    u = A sum_{m,n} F_m(a) F_n(b) (1 - exp(-lambda_mn t)) / lambda_mn sin(m pi x) sin(n pi y),
    lambda_mn = kappa pi^2 (m^2 + n^2),   F_m(a) = 2 int_0^1 exp(-(x - a)^2 / w) sin(m pi x) dx,

the source's sine coefficients integrated by Gauss-Legendre quadrature (exact to rounding for this
smooth integrand), the series cut where its tail is below 1e-8."""

from __future__ import annotations

import functools
import itertools

import numpy as np
import pytest
from scipy.special import roots_legendre

import pgdcli
from conftest import PROBLEMS

KAPPA, WIDTH = 0.1, 0.01
DOMAINS = {"x": (0.0, 1.0), "y": (0.0, 1.0), "t": (0.0, 1.0), "A": (0.0, 1.0), "a": (0.3, 0.7), "b": (0.3, 0.7)}


@functools.cache
def gauss_legendre(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Nodes and weights of the n-point Gauss-Legendre rule on [0, 1]."""
    s, weights = roots_legendre(n)
    return (s + 1.0) / 2.0, weights / 2.0


def sine_coefficients(centres: np.ndarray, modes: int, quadrature: int = 800) -> np.ndarray:
    """F_m(c) = 2 int_0^1 exp(-(x - c)^2 / w) sin(m pi x) dx for m = 1..modes: shape (len(centres), modes)."""
    x, weights = gauss_legendre(quadrature)
    gauss = np.exp(-(x[None, :] - centres[:, None]) ** 2 / WIDTH) * weights
    return 2.0 * gauss @ np.sin(np.pi * np.outer(x, np.arange(1, modes + 1)))


def exact(points: dict[str, np.ndarray], modes: int = 120) -> np.ndarray:
    """The series at each point (every coordinate an array of shape (P,))."""
    m = np.arange(1, modes + 1)
    rate = KAPPA * np.pi ** 2 * (m[:, None] ** 2 + m[None, :] ** 2)  # (M, M)
    growth = -np.expm1(-rate[None] * points["t"][:, None, None]) / rate[None]  # (P, M, M)
    fx = sine_coefficients(points["a"], modes) * np.sin(np.pi * np.outer(points["x"], m))
    fy = sine_coefficients(points["b"], modes) * np.sin(np.pi * np.outer(points["y"], m))
    return points["A"] * np.einsum("pm,pmn,pn->p", fx, growth, fy)


def check_points(random: int, per_face: int, seed: int) -> dict[str, np.ndarray]:
    """``random`` uniform points of the 6-D box, ``per_face`` random points on each of its 12 faces, its 64 corners."""
    rng = np.random.default_rng(seed)
    names = list(DOMAINS)
    lows, highs = (np.array([DOMAINS[n][k] for n in names]) for k in (0, 1))
    blocks = [rng.uniform(lows, highs, size=(random, len(names)))]
    for k, side in itertools.product(range(len(names)), (lows, highs)):
        face = rng.uniform(lows, highs, size=(per_face, len(names)))
        face[:, k] = side[k]
        blocks.append(face)
    blocks.append(np.array(list(itertools.product(*DOMAINS.values()))))
    return dict(zip(names, np.vstack(blocks).T))


def test_the_series_is_converged_and_meets_the_equation():
    p = check_points(random=40, per_face=0, seed=1)
    values = exact(p)
    assert np.max(np.abs(values - exact(p, modes=200))) < 1e-9
    # u_t - kappa lap(u) = source, by finite differences of the series in t, x, y (inside the box)
    p = {k: v[:40] for k, v in check_points(random=40, per_face=0, seed=2).items()}
    p["x"], p["y"], p["t"] = 0.1 + 0.8 * p["x"], 0.1 + 0.8 * p["y"], 0.05 + 0.9 * p["t"]
    h = 1e-3

    def shifted(name, step):
        return exact({**p, name: p[name] + step})

    u = exact(p)
    u_t = (shifted("t", h) - shifted("t", -h)) / (2 * h)
    lap = sum(shifted(c, h) - 2 * u + shifted(c, -h) for c in ("x", "y")) / h ** 2
    source = p["A"] * np.exp(-((p["x"] - p["a"]) ** 2 + (p["y"] - p["b"]) ** 2) / WIDTH)
    assert np.max(np.abs(u_t - KAPPA * lap - source)) < 1e-4 * max(1.0, np.max(np.abs(source)))


@pytest.mark.slow
def test_hotplate_meets_its_tolerance_against_the_exact_series():
    result = pgdcli.solve(pgdcli.load_spec(PROBLEMS / "hotplate.yaml"))
    assert result.converged and result.accurate, result.message
    p = check_points(random=300, per_face=10, seed=7)
    error = np.abs(result.codebook.evaluate(p)["u"] - exact(p))
    assert error.max() <= 1e-5, (error.max(), {k: v[error.argmax()] for k, v in p.items()})

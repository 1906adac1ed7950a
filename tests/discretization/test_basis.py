"""1D bases (pgdcli.discretization.basis) against closed forms, numpy.polynomial and scipy.

Every reference here is independent of pgdcli: closed-form integrals and
derivatives, numpy's Chebyshev series, np.interp, scipy's trapezoid, and the
closed-form trapezoidal (Crank-Nicolson) recurrence.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from numpy.polynomial import Chebyshev
from scipy.integrate import trapezoid

from pgdcli.discretization.basis import KINDS, ChebyshevBasis, LinearBasis, barycentric_columns, make_basis

EPS = np.finfo(float).eps

DOMAINS = [(0.0, 10.0), (1.0, 10.0), (0.1, 0.7), (-3.3, 1e-3), (0.5, 5.0), (-1.0, 1.0), (1e-8, 3e-8), (-7.0, -2.5)]


# ----------------------------------------------------------------------------------------------
# nodes
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("n", [2, 3, 8, 33, 56])
def test_nodes_hit_domain_ends_exactly_and_increase(kind, domain, n):
    b = make_basis(kind, domain, n)
    assert b.kind == kind
    assert b.nodes.shape == (n,) and b.weights.shape == (n,)
    assert b.nodes[0] == domain[0]
    assert b.nodes[-1] == domain[1]
    assert np.all(np.diff(b.nodes) > 0)


@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("n", [2, 5, 16, 33])
def test_chebyshev_nodes_are_gauss_lobatto_points(domain, n):
    lo, hi = domain
    j = np.arange(n)
    ref = lo + (hi - lo) * (1.0 - np.cos(np.pi * j / (n - 1))) / 2.0
    np.testing.assert_allclose(ChebyshevBasis(domain, n).nodes, ref, rtol=0, atol=4 * EPS * max(abs(lo), abs(hi)))


@pytest.mark.parametrize("domain", DOMAINS)
def test_linear_nodes_are_uniform(domain):
    b = LinearBasis(domain, 11)
    np.testing.assert_allclose(b.nodes, np.linspace(*domain, 11), rtol=0, atol=4 * EPS * max(map(abs, domain)))


def test_make_basis_rejects_bad_input():
    with pytest.raises(ValueError, match="unknown discretization"):
        make_basis("spline", (0, 1), 4)
    for kind in KINDS:
        with pytest.raises(ValueError, match="at least 2 nodes"):
            make_basis(kind, (0, 1), 1)


# ----------------------------------------------------------------------------------------------
# Clenshaw-Curtis quadrature
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3, 4, 5, 8, 9, 16, 17, 32, 33])
@pytest.mark.parametrize("domain", [(-0.5, 2.0), (0.0, 10.0), (1.0, 10.0)])
def test_clenshaw_curtis_exact_for_degree_below_n(n, domain):
    a, b = domain
    c, h = (a + b) / 2.0, (b - a) / 2.0
    basis = ChebyshevBasis(domain, n)
    for p in range(n):
        f = (basis.nodes - c) ** p
        exact = h ** (p + 1) * (1.0 - (-1.0) ** (p + 1)) / (p + 1)  # int_a^b (x - c)^p dx
        scale = (b - a) * h**p  # integral of |f| is at most this
        assert abs(basis.weights @ f - exact) <= 20 * n * EPS * scale, (n, p)


@pytest.mark.parametrize("n", [2, 3, 8, 17, 40])
def test_clenshaw_curtis_weights_positive_and_sum_to_length(n):
    b = ChebyshevBasis((0.5, 5.0), n)
    assert np.all(b.weights > 0)
    assert b.weights.sum() == pytest.approx(4.5, rel=4 * n * EPS)


def test_clenshaw_curtis_spectral_on_smooth_functions():
    # entire function: machine precision with few nodes
    b = ChebyshevBasis((0.0, 2.0), 16)
    exact = math.e**2 - 1.0
    assert abs(b.weights @ np.exp(b.nodes) - exact) <= 1e-14 * exact
    # Runge function: geometric convergence to machine precision
    exact = math.atan(4.0) / 2.0  # int_{-1}^{1} 1 / (1 + 16 x^2) dx
    errors = []
    for n in (9, 17, 33, 65, 129):
        b = ChebyshevBasis((-1.0, 1.0), n)
        errors.append(abs(b.weights @ (1.0 / (1.0 + 16.0 * b.nodes**2)) - exact))
    assert all(e2 < e1 / 10 for e1, e2 in zip(errors[:3], errors[1:4])), errors
    assert errors[-1] <= 1e-14


# ----------------------------------------------------------------------------------------------
# differentiation matrix
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [2, 3, 5, 8, 16, 33])
@pytest.mark.parametrize("domain", [(-1.0, 1.0), (0.0, 10.0), (0.5, 5.0)])
def test_differentiation_matrix_exact_on_polynomials(n, domain):
    rng = np.random.default_rng(n)
    basis = ChebyshevBasis(domain, n)
    assert basis.derivative.shape == (n, n)
    for _ in range(3):
        p = Chebyshev(rng.standard_normal(n), domain=list(domain))  # degree n - 1
        dp = p.deriv()(basis.nodes)
        # ||D|| ~ n^2 / half-width; |p| <= sum |Chebyshev coefficients|
        scale = np.sum(np.abs(p.coef)) * n * n / ((domain[1] - domain[0]) / 2.0)
        np.testing.assert_allclose(basis.derivative @ p(basis.nodes), dp, rtol=0, atol=100 * EPS * scale)


def test_differentiation_matrix_annihilates_constants():
    for n in (2, 9, 32, 64):
        d = ChebyshevBasis((0.0, 4.0), n).derivative
        assert np.max(np.abs(d @ np.ones(n))) <= 10 * EPS * np.max(np.abs(d))


def test_differentiation_matrix_spectral_on_smooth_function():
    b = ChebyshevBasis((0.0, 3.0), 40)
    x = b.nodes
    np.testing.assert_allclose(b.derivative @ np.exp(np.sin(x)), np.cos(x) * np.exp(np.sin(x)), rtol=0, atol=1e-11)


# ----------------------------------------------------------------------------------------------
# interpolation
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("domain", DOMAINS)
@pytest.mark.parametrize("n", [2, 3, 7, 32, 56])
def test_interpolation_at_nodes_is_exact_unit_rows(kind, domain, n):
    b = make_basis(kind, domain, n)
    m = b.interpolation_matrix(b.nodes)
    assert np.array_equal(m, np.eye(n))  # bitwise
    rng = np.random.default_rng(n)
    values = rng.standard_normal((n, 3))
    assert np.array_equal(b.interpolate(values, b.nodes[::-1]), values[::-1])


@pytest.mark.parametrize("n", [2, 4, 9, 24, 40])
def test_barycentric_interpolation_exact_for_polynomials(n):
    domain = (0.5, 5.0)
    rng = np.random.default_rng(100 + n)
    b = ChebyshevBasis(domain, n)
    p = Chebyshev(rng.standard_normal(n), domain=list(domain))
    x = rng.uniform(*domain, 500)
    # rounding bound: values (Lebesgue constant ~ log n) plus the conditioning of p at a rounded x
    bound = 10 * EPS * (np.sum(np.abs(p.coef)) * (1 + np.log(n)) + np.abs(p.deriv()(x) * x))
    assert np.all(np.abs(b.interpolate(p(b.nodes), x) - p(x)) <= bound)


def test_barycentric_interpolation_spectral_between_nodes():
    f = lambda x: np.exp(np.sin(x))
    rng = np.random.default_rng(7)
    x = rng.uniform(0.0, 4.0, 2000)
    errors = []
    for n in (8, 16, 24, 32, 40):
        b = ChebyshevBasis((0.0, 4.0), n)
        errors.append(np.max(np.abs(b.interpolate(f(b.nodes), x) - f(x))))
    assert all(e2 < e1 / 300 for e1, e2 in zip(errors[:4], errors[1:4])), errors
    assert errors[-1] <= 1e-14, errors


def test_interpolation_next_to_a_node_is_finite_and_accurate():
    b = ChebyshevBasis((1.0, 10.0), 33)
    f = lambda x: 1.0 / x
    x = np.concatenate([np.nextafter(b.nodes[1:], -np.inf), np.nextafter(b.nodes[:-1], np.inf)])
    y = b.interpolate(f(b.nodes), x)
    assert np.all(np.isfinite(y))
    np.testing.assert_allclose(y, f(x), rtol=1e-10)


@pytest.mark.parametrize("kind", KINDS)
def test_interpolate_keeps_trailing_value_shape(kind):
    b = make_basis(kind, (0.0, 1.0), 6)
    values = np.arange(6 * 2 * 3, dtype=float).reshape(6, 2, 3)
    assert b.interpolate(values, np.linspace(0, 1, 5)).shape == (5, 2, 3)
    assert b.interpolate(values, 0.3).shape == (1, 2, 3)


@pytest.mark.parametrize("kind", KINDS)
def test_interpolation_rows_partition_unity(kind):
    b = make_basis(kind, (-2.0, 3.0), 17)
    x = np.random.default_rng(1).uniform(-2, 3, 300)
    np.testing.assert_allclose(b.interpolation_matrix(x).sum(axis=1), 1.0, rtol=0, atol=1e-14)


@pytest.mark.parametrize("n", [2, 5, 20])
def test_barycentric_columns_interpolate_polynomials_exactly(n):
    """Points last, as the batch path stores them: exact for polynomials of degree < n (against
    numpy's Chebyshev series), unit columns on the nodes, and the interpolation rows transposed."""
    b = ChebyshevBasis((-1.0, 3.0), n)
    rng = np.random.default_rng(n)
    x = rng.uniform(-1.0, 3.0, 400)
    x[::7] = b.nodes[rng.integers(0, n, x[::7].size)]
    out, work = np.empty((n, x.size)), np.empty((n, x.size))
    cols = barycentric_columns(x, b.nodes, b.bary, out, work)
    assert cols is out
    series = Chebyshev(rng.standard_normal(n), domain=[-1.0, 3.0])
    np.testing.assert_allclose(series(b.nodes) @ cols, series(x), rtol=0, atol=1e-12)
    on_node = np.isin(x, b.nodes)
    assert np.array_equal(cols[:, on_node], (x[on_node] == b.nodes[:, None]).astype(float))
    np.testing.assert_allclose(cols.T, b.interpolation_matrix(x), rtol=0, atol=1e-15)


# ----------------------------------------------------------------------------------------------
# linear (hat) basis
# ----------------------------------------------------------------------------------------------
def test_linear_interpolation_is_hat_interpolation():
    domain = (-1.5, 2.5)
    b = LinearBasis(domain, 9)
    rng = np.random.default_rng(3)
    x = np.concatenate([rng.uniform(*domain, 500), b.nodes, list(domain)])
    values = rng.standard_normal(9)
    np.testing.assert_allclose(b.interpolate(values, x), np.interp(x, b.nodes, values), rtol=0, atol=1e-15)
    m = b.interpolation_matrix(x)
    assert np.all(m >= 0) and np.all((m != 0).sum(axis=1) <= 2)
    # exact for linear functions
    np.testing.assert_allclose(b.interpolate(3.0 * b.nodes - 1.0, x), 3.0 * x - 1.0, rtol=0, atol=1e-14)


@pytest.mark.parametrize("n", [2, 3, 10, 41])
def test_linear_weights_are_trapezoid_rule(n):
    domain = (0.2, 3.7)
    b = LinearBasis(domain, n)
    h = (domain[1] - domain[0]) / (n - 1)
    ref = np.full(n, h)
    ref[[0, -1]] = h / 2
    np.testing.assert_allclose(b.weights, ref, rtol=1e-14)
    f = np.cos(b.nodes)
    assert b.weights @ f == pytest.approx(trapezoid(f, b.nodes), rel=1e-14, abs=1e-15)


# ----------------------------------------------------------------------------------------------
# time operators: solve u' = -u + g(t), u(0) = 1 via the free-node system
# ----------------------------------------------------------------------------------------------
def _solve_ivp_discrete(basis, source=None, u0=1.0):
    """u' + u = source(t), u(t0) = u0 with the basis's time operators; nodal values (n,)."""
    n = basis.nodes.size
    a = basis.time_stiffness(np.ones(n)) + basis.time_mass(np.ones(n))
    f = np.zeros(n) if source is None else source(basis.nodes)
    rhs = basis.time_load(f) - a[:, 0] * u0
    return np.concatenate([[u0], np.linalg.solve(a[:, 1:], rhs)])


@pytest.mark.parametrize("kind", KINDS)
def test_time_operator_shapes(kind):
    n = 9
    b = make_basis(kind, (0.0, 1.0), n)
    c = np.linspace(1.0, 2.0, n)
    assert b.time_stiffness(c).shape == (n - 1, n)
    assert b.time_mass(c).shape == (n - 1, n)
    assert b.time_load(c).shape == (n - 1,)
    assert b.time_weights().shape == (n - 1,)
    # the derivative of a constant vanishes
    np.testing.assert_allclose(b.time_stiffness(c) @ np.ones(n), 0.0, rtol=0, atol=1e-12)


def test_cg1_is_the_trapezoidal_recurrence():
    # cG(1) with piecewise-constant tests on u' = -u is Crank-Nicolson: u_{j+1} = u_j (1 - h/2) / (1 + h/2)
    b = LinearBasis((0.0, 2.0), 21)
    h = 0.1
    u = _solve_ivp_discrete(b)
    ref = ((1 - h / 2) / (1 + h / 2)) ** np.arange(21)
    np.testing.assert_allclose(u, ref, rtol=1e-13)


def test_cg1_converges_at_second_order():
    exact = lambda t: t - 1.0 + 2.0 * np.exp(-t)  # u' = -u + t, u(0) = 1
    errors = []
    for n in (21, 41, 81, 161):
        b = LinearBasis((0.0, 2.0), n)
        errors.append(np.max(np.abs(_solve_ivp_discrete(b, source=lambda t: t) - exact(b.nodes))))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 3.8) & (ratios < 4.2)), (errors, ratios)


def test_chebyshev_time_system_converges_exponentially():
    exact = lambda t: t - 1.0 + 2.0 * np.exp(-t)
    errors = []
    for n in (6, 8, 10, 12, 14):
        b = ChebyshevBasis((0.0, 2.0), n)
        errors.append(np.max(np.abs(_solve_ivp_discrete(b, source=lambda t: t) - exact(b.nodes))))
    assert all(e2 < e1 / 50 for e1, e2 in zip(errors[:-1], errors[1:])), errors
    b = ChebyshevBasis((0.0, 2.0), 18)
    assert np.max(np.abs(_solve_ivp_discrete(b, source=lambda t: t) - exact(b.nodes))) <= 1e-13


def test_chebyshev_time_system_with_time_dependent_coefficients():
    # (1 + t) u' + 2 u = 0, u(0) = 1  ->  u = (1 + t)^-2, through c(t) in both operators
    b = ChebyshevBasis((0.0, 3.0), 30)
    t = b.nodes
    a = b.time_stiffness(1.0 + t) + b.time_mass(np.full(t.size, 2.0))
    u = np.concatenate([[1.0], np.linalg.solve(a[:, 1:], -a[:, 0])])
    np.testing.assert_allclose(u, (1.0 + t) ** -2, rtol=0, atol=1e-12)


def test_cg1_time_dependent_coefficients_second_order():
    # (1 + t) u' + 2 u = 0, u(0) = 1
    errors = []
    for n in (21, 41, 81):
        b = LinearBasis((0.0, 3.0), n)
        t = b.nodes
        a = b.time_stiffness(1.0 + t) + b.time_mass(np.full(t.size, 2.0))
        u = np.concatenate([[1.0], np.linalg.solve(a[:, 1:], -a[:, 0])])
        errors.append(np.max(np.abs(u - (1.0 + t) ** -2)))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all((ratios > 3.6) & (ratios < 4.4)), (errors, ratios)

"""Means, variances and Sobol indices of codebooks (pgdcli.codebook.sensitivity), against independent values.

- closed forms: a solved problem whose solution is a polynomial in every coordinate (the codebook
  is exact, so are its indices: 1e-10), and ``u' = -k u`` (a product of one-coordinate functions,
  its closed form to the codebook's tolerance);
- brute force: the unknowns on the full tensor grid of the quadrature points (``evaluate_grid``)
  and the conditional variances taken there by plain numpy sums, for CP and tensor trains in any
  core order and every basis (Chebyshev, slabs, linear elements), under uniform and truncated
  normal densities;
- densities: a truncated normal's closed-form mean and variance.
The comparison with sampling estimates (scipy.stats.sobol_indices on solve_ivp) is in
test_sensitivity_sampling.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from pgdcli.codebook.codebook import Codebook, CoordinateInfo, CPTensor, TT
from pgdcli.codebook.densities import TruncatedNormal, parse_density, quadrature
from pgdcli.errors import QueryError

LINEAR_GROWTH = """
name: linear_growth
description: "u' = k c, u(0) = u0: u = u0 + k c t"
coordinates:
  t: {domain: [0, 2], nodes: 4}
  k: {domain: [0.5, 1.5], nodes: 3}
  c: {domain: [-1, 2], nodes: 3}
  u0: {domain: [0, 1], nodes: 2, discretization: linear}
unknowns:
  u: {initial: u0}
equations:
  - "der(u) = k*c"
solver:
  tolerance: 1e-12
"""

DECAY = """
name: decay
coordinates:
  t: {domain: [0, 2], nodes: 24}
  k: {domain: [0.5, 2], nodes: 24}
  u0: {domain: [1, 3], nodes: 2, discretization: linear}
unknowns:
  u: {initial: u0}
equations:
  - "der(u) = -k*u"
solver:
  tolerance: 1e-10
"""


def _uniform_moments(low, high):
    return (low + high) / 2.0, (high - low) ** 2 / 12.0


def _solve(text, tmp_path):
    import pgdcli

    path = tmp_path / "spec.yaml"
    path.write_text(text)
    result = pgdcli.solve(pgdcli.load_spec(path))
    assert result.converged
    return result.codebook


# ----------------------------------------------------------------------------------------------
# closed forms
# ----------------------------------------------------------------------------------------------
def test_closed_form_indices_of_a_solved_polynomial_problem(tmp_path):
    """u = u0 + t k c with independent uniform k, c, u0: V_k = t^2 E[c]^2 Var k, V_kc = t^2 Var k Var c, ..."""
    cb = _solve(LINEAR_GROWTH, tmp_path)
    times = np.array([0.0, 0.3, 1.0, 1.7, 2.0])
    s = cb.sensitivity(times=times, second_order=True)
    assert s.inputs == ["k", "c", "u0"] and s.time == "t"
    mk, vk = _uniform_moments(0.5, 1.5)
    mc, vc = _uniform_moments(-1.0, 2.0)
    m0, v0 = _uniform_moments(0.0, 1.0)
    vk_, vc_, vkc = times**2 * mc**2 * vk, times**2 * mk**2 * vc, times**2 * vk * vc
    variance = v0 + vk_ + vc_ + vkc
    np.testing.assert_allclose(s.mean["u"], m0 + times * mk * mc, rtol=0, atol=1e-10)
    np.testing.assert_allclose(s.variance["u"], variance, rtol=1e-10, atol=0)
    first = np.stack([vk_, vc_, np.full_like(times, v0)], axis=-1) / variance[:, None]
    total = np.stack([vk_ + vkc, vc_ + vkc, np.full_like(times, v0)], axis=-1) / variance[:, None]
    np.testing.assert_allclose(s.first["u"], first, rtol=0, atol=1e-10)
    np.testing.assert_allclose(s.total["u"], total, rtol=0, atol=1e-10)
    np.testing.assert_allclose(s.second["u"][:, 0, 1], vkc / variance, rtol=0, atol=1e-10)
    np.testing.assert_allclose(s.second["u"][:, 0, 2], 0.0, atol=1e-10)
    # the ANOVA terms of three inputs, none of order three here, add up to the variance
    upper = np.triu(s.second["u"], 1).sum(axis=(1, 2))
    np.testing.assert_allclose(s.first["u"].sum(axis=1) + upper, 1.0, rtol=0, atol=1e-10)


def test_closed_form_indices_of_exponential_decay(tmp_path):
    """u = u0 exp(-k t): a product g(u0) h(k), V_u0 = Var g E[h]^2, V_k = E[g]^2 Var h, V = E[g^2] E[h^2] - E^2."""
    cb = _solve(DECAY, tmp_path)
    times = np.array([0.25, 1.0, 2.0])
    s = cb.sensitivity(times=times)
    a, b = 0.5, 2.0
    eh = (np.exp(-a * times) - np.exp(-b * times)) / ((b - a) * times)
    eh2 = (np.exp(-2 * a * times) - np.exp(-2 * b * times)) / (2 * (b - a) * times)
    eg, vg = _uniform_moments(1.0, 3.0)
    eg2 = vg + eg**2
    variance = eg2 * eh2 - (eg * eh) ** 2
    first_k = eg**2 * (eh2 - eh**2) / variance
    first_u0 = vg * eh**2 / variance
    total_k, total_u0 = 1 - first_u0, 1 - first_k
    # the codebook holds exp(-k t) to its tolerance, 1e-10: its indices agree to about that over the variance
    np.testing.assert_allclose(s.mean["u"], eg * eh, rtol=0, atol=1e-9)
    np.testing.assert_allclose(s.variance["u"], variance, rtol=1e-8, atol=0)
    np.testing.assert_allclose(s.first["u"], np.stack([first_k, first_u0], -1), rtol=0, atol=1e-8)
    np.testing.assert_allclose(s.total["u"], np.stack([total_k, total_u0], -1), rtol=0, atol=1e-8)


# ----------------------------------------------------------------------------------------------
# brute force on the tensor grid of the quadrature points
# ----------------------------------------------------------------------------------------------
def _synthetic(seed=1):
    """CP and tensor-train unknowns over Chebyshev slabs (time), Chebyshev, linear, Chebyshev elements, space."""
    rng = np.random.default_rng(seed)
    coords = [CoordinateInfo("t", (0.0, 2.0), 13, "chebyshev", "time", tuple(np.linspace(0, 2, 4))),
              CoordinateInfo("a", (-1.0, 1.0), 7, "chebyshev", "parameter"),
              CoordinateInfo("b", (0.0, 3.0), 9, "linear", "parameter"),
              CoordinateInfo("c", (1.0, 2.0), 9, "chebyshev", "parameter", (1.0, 1.4, 2.0)),
              CoordinateInfo("x", (0.0, 1.0), 6, "chebyshev", "space")]
    fields = {"p": CPTensor(rng.standard_normal(4), tuple(rng.standard_normal((c.nodes, 4)) + 2 for c in coords))}
    ranks = [1, 3, 4, 5, 2, 1]
    for name, order in (("q", (2, 0, 4, 1, 3)), ("r", (0, 1, 2, 3, 4)), ("s", (4, 3, 2, 1, 0))):
        cores = tuple(rng.standard_normal((ranks[k], coords[j].nodes, ranks[k + 1])) for k, j in enumerate(order))
        fields[name] = TT(cores, order)
    return Codebook(coords, fields, name="synthetic", report={})


def _brute(cb, u, times, fixed, densities):
    """Mean, variance, first, total and second-order indices from the values on the full quadrature grid."""
    tname = "t"
    inputs = [c for c in cb.coordinates if c.name != tname and c.name not in fixed]
    axes, weights = {}, []
    for c in cb.coordinates:
        if c.name == tname:
            axes[c.name] = times
        elif c.name in fixed:
            axes[c.name] = [fixed[c.name]]
        else:
            x, w = quadrature(c.name, c.basis(), densities.get(c.name))
            axes[c.name], _ = x, weights.append(w)
    grid = cb.evaluate_grid(axes, fields=[u])[u]
    names = cb.coordinate_names
    order = [names.index(tname)] + [names.index(c.name) for c in inputs] + [names.index(n) for n in fixed]
    g = np.transpose(grid, order).reshape(grid.shape[names.index(tname)], *[w.size for w in weights])
    d = len(inputs)

    def conditional_variance(keep):
        f = g
        for k in sorted(set(range(d)) - set(keep), reverse=True):
            f = np.tensordot(f, weights[k], axes=([1 + k], [0]))
        w = np.ones(())
        for k in sorted(keep):
            w = np.multiply.outer(w, weights[k])
        m = np.tensordot(f, w, axes=len(keep))
        return np.tensordot((f - m.reshape((-1,) + (1,) * len(keep))) ** 2, w, axes=len(keep))

    variance = conditional_variance(range(d))
    first = np.stack([conditional_variance([i]) for i in range(d)], -1) / variance[:, None]
    total = np.stack([variance - conditional_variance([j for j in range(d) if j != i]) for i in range(d)], -1)
    second = np.zeros((len(times), d, d))
    for i in range(d):
        for j in range(i + 1, d):
            second[:, i, j] = (conditional_variance([i, j]) - conditional_variance([i]) - conditional_variance([j]))
    w = np.ones(())
    for wk in weights:
        w = np.multiply.outer(w, wk)
    mean = np.tensordot(g, w, axes=d)
    return mean, variance, first, total / variance[:, None], second / variance[:, None, None]


@pytest.mark.parametrize("densities", [{}, {"a": "normal:0.2,0.7", "c": "uniform:1.1,1.7", "b": "normal:2.5,2"}])
@pytest.mark.parametrize("u", ["p", "q", "r", "s"])
def test_every_representation_and_basis_against_the_quadrature_grid(u, densities):
    cb = _synthetic()
    times = np.array([0.0, 0.3, 0.5, 1.1, 2.0])
    s = cb.sensitivity(times=times, at={"x": 0.37}, densities=densities, second_order=True, fields=[u])
    assert s.inputs == ["a", "b", "c"] and s.unknowns == [u]
    parsed = {k: parse_density(v) for k, v in densities.items()}
    mean, variance, first, total, second = _brute(cb, u, times, {"x": 0.37}, parsed)
    np.testing.assert_allclose(s.mean[u], mean, rtol=1e-12, atol=1e-12 * np.abs(mean).max())
    np.testing.assert_allclose(s.variance[u], variance, rtol=1e-11)
    np.testing.assert_allclose(s.first[u], first, rtol=0, atol=1e-11)
    np.testing.assert_allclose(s.total[u], total, rtol=0, atol=1e-11)
    np.testing.assert_allclose(np.triu(s.second[u], 1), second, rtol=0, atol=1e-11)
    np.testing.assert_array_equal(s.second[u], np.swapaxes(s.second[u], 1, 2))


def test_a_fixed_parameter_is_no_input_and_a_steady_codebook_has_no_times():
    cb = _synthetic()
    s = cb.sensitivity(times=[1.0], at={"x": 0.5, "b": 1.2}, fields=["q"])
    assert s.inputs == ["a", "c"] and s.at == {"x": 0.5, "b": 1.2}
    mean, variance, first, total, _ = _brute(cb, "q", np.array([1.0]), {"x": 0.5, "b": 1.2}, {})
    np.testing.assert_allclose(s.first["q"], first, atol=1e-11)
    steady = Codebook([c for c in cb.coordinates if c.name != "t"],
                      {"m": CPTensor(np.array([1.0, 2.0]), tuple(np.random.default_rng(3).standard_normal((c.nodes, 2))
                                                                    for c in cb.coordinates if c.name != "t"))},
                      name="steady", report={})
    r = steady.sensitivity(at={"x": 0.2})
    assert r.time is None and r.times.shape == (1,) and r.first["m"].shape == (1, 3)
    with pytest.raises(QueryError, match="no time coordinate"):
        steady.sensitivity(times=[0.5], at={"x": 0.2})


def test_indices_are_nan_where_nothing_varies(tmp_path):
    """At t = 0 the solution is the initial value, the same for every k: no variance, no indices."""
    spec = DECAY.replace("  u0: {domain: [1, 3], nodes: 2, discretization: linear}\n", "").replace("initial: u0",
                                                                                                   "initial: 1")
    cb = _solve(spec, tmp_path)
    s = cb.sensitivity(times=[0.0, 1.0])
    assert s.inputs == ["k"]
    assert s.variance["u"][0] <= 1e-24 and np.isnan(s.first["u"][0]).all() and np.isnan(s.total["u"][0]).all()
    assert s.first["u"][1, 0] == pytest.approx(1.0, abs=1e-12)  # one input explains all the variance
    assert s.to_dict()["unknowns"]["u"]["first"]["k"][0] is None  # JSON: null


# ----------------------------------------------------------------------------------------------
# densities and quadrature
# ----------------------------------------------------------------------------------------------
def test_truncated_normal_mean_and_variance_are_the_closed_form():
    coordinate = CoordinateInfo("k", (0.5, 3.0), 9, "chebyshev", "parameter")
    basis = coordinate.basis()
    mu, sd = 1.2, 0.4
    x, w = quadrature("k", basis, TruncatedNormal(mu, sd))
    alpha, beta = (0.5 - mu) / sd, (3.0 - mu) / sd
    phi = lambda z: math.exp(-z * z / 2) / math.sqrt(2 * math.pi)  # noqa: E731
    big = 0.5 * (math.erf(beta / math.sqrt(2)) - math.erf(alpha / math.sqrt(2)))
    mean = mu + sd * (phi(alpha) - phi(beta)) / big
    variance = sd**2 * (1 + (alpha * phi(alpha) - beta * phi(beta)) / big - ((phi(alpha) - phi(beta)) / big) ** 2)
    assert w.sum() == pytest.approx(1.0, abs=1e-15)
    assert w @ x == pytest.approx(mean, rel=1e-13)
    assert w @ (x - mean) ** 2 == pytest.approx(variance, rel=1e-12)


@pytest.mark.parametrize("c", [CoordinateInfo("a", (0.0, 2.0), 9, "chebyshev"),
                               CoordinateInfo("b", (-1.0, 1.0), 7, "linear"),
                               CoordinateInfo("c", (0.0, 3.0), 13, "chebyshev", "parameter", (0.0, 0.5, 2.0, 3.0))])
def test_uniform_quadrature_is_exact_for_products_of_basis_functions(c):
    """The mass matrix of the cardinal functions, against 40 Gauss points on each piece where they are polynomials."""
    basis = c.basis()
    x, w = quadrature(c.name, basis, None)
    b = basis.interpolation_matrix(x)
    pieces = basis.nodes if c.discretization == "linear" else np.array(basis.breakpoints if c.breakpoints else c.domain)
    unit_x, unit_w = np.polynomial.legendre.leggauss(40)
    h = np.diff(pieces)[:, None]
    ref_x = (pieces[:-1, None] + h * (unit_x + 1) / 2).reshape(-1)
    ref_w = (h * unit_w / 2).reshape(-1) / (c.domain[1] - c.domain[0])
    rb = basis.interpolation_matrix(ref_x)
    mass = rb.T @ (ref_w[:, None] * rb)
    np.testing.assert_allclose(b.T @ (w[:, None] * b), mass, rtol=0, atol=1e-13 * np.abs(mass).max())  # rounding
    assert x.size == (pieces.size - 1) * (2 if c.discretization == "linear" else (c.nodes - 1) // (pieces.size - 1) + 1)


@pytest.mark.parametrize("text, message", [
    ("normal:1", "expected uniform, uniform:LOW,HIGH or normal:MEAN,SD"),
    ("normal:1,-2", "standard deviation of normal:MEAN,SD must be positive"),
    ("uniform:2,1", "needs LOW < HIGH"),
    ("gamma:1,2", "expected uniform"),
    ("normal:a,b", "must be numbers"),
    ("uniform:nan,1", "finite"),
])
def test_bad_density_texts(text, message):
    with pytest.raises(QueryError, match=message):
        parse_density(text)


@pytest.mark.parametrize("kwargs, message", [
    ({"at": {"x": 2.0}}, r"--at x=2: outside the domain \[0, 1\]"),
    ({"at": {"t": 0.5, "x": 0.5}}, "'t' is the time coordinate; give its values with --times"),
    ({}, "give a value for the space coordinate x"),
    ({"at": {"x": 0.5}, "times": [3.0]}, r"--times: 3.0 is outside the domain \[0, 2\]"),
    ({"at": {"x": 0.5, "z": 1}}, "unknown coordinate 'z'"),
    ({"at": {"x": 0.5}, "densities": {"x": "uniform"}}, "'x' is not a random input"),
    ({"at": {"x": 0.5}, "densities": {"a": "uniform:-2,0"}}, r"--density a=uniform:-2.0,0.0: \[-2, 0\] is not an interval"),
    ({"at": {"x": 0.5}, "densities": {"a": "normal:50,0.1"}}, "no probability inside the domain"),
    ({"at": {"x": 0.5}, "densities": {"a": "normal:0,1e-9"}}, "too small"),
    ({"at": {"x": 0.5}, "fields": ["zz"]}, "unknown 'zz'"),
])
def test_bad_requests_name_what_is_wrong(kwargs, message):
    with pytest.raises(QueryError, match=message):
        _synthetic().sensitivity(**kwargs)


def test_rows_and_json_layout():
    s = _synthetic().sensitivity(times=[0.5, 1.0], at={"x": 0.5}, second_order=True, fields=["p", "q"])
    rows = s.rows()
    assert len(rows) == 4 and list(rows[0])[:4] == ["unknown", "t", "mean", "variance"]
    assert "first_a" in rows[0] and "total_c" in rows[0] and "second_a_c" in rows[0]
    assert rows[1]["first_b"] == s.first["p"][1, 1]
    d = s.to_dict()
    assert d["inputs"] == ["a", "b", "c"] and d["times"] == [0.5, 1.0] and d["densities"]["a"] == "uniform"
    assert d["unknowns"]["q"]["second"]["a,b"] == list(s.second["q"][:, 0, 1])

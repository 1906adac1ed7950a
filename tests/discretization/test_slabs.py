"""Time slabs: piecewise Chebyshev bases, solver.time_slabs for both solvers, codebook round trip."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import assert_solved

import pgdcli
from pgdcli.discretization.basis import PiecewiseChebyshevBasis, make_basis
from pgdcli.codebook.codebook import Codebook
from pgdcli.errors import SpecError


def test_piecewise_basis_nodes_weights_interpolation_and_time_system():
    b = make_basis("chebyshev", (0.0, 2.0), 3 * 8 + 1, breakpoints=(0.0, 0.5, 1.2, 2.0))
    assert isinstance(b, PiecewiseChebyshevBasis)
    assert b.nodes[0] == 0.0 and b.nodes[-1] == 2.0 and np.all(np.diff(b.nodes) > 0)
    assert {0.5, 1.2} <= set(b.nodes.tolist())  # slabs share their ends
    np.testing.assert_array_equal(b.interpolation_matrix(b.nodes), np.eye(b.nodes.size))
    # degree 7 on every slab: polynomials of degree <= 7 are reproduced and integrated exactly
    p = np.polynomial.Polynomial([0.3, -1.0, 0.5, 2.0, -0.7, 0.1, 0.05, -0.02])
    x = np.random.default_rng(0).uniform(0, 2, 500)
    np.testing.assert_allclose(b.interpolate(p(b.nodes), x), p(x), rtol=0, atol=1e-12)
    integral = p.integ()(2.0) - p.integ()(0.0)
    assert abs(b.weights @ p(b.nodes) - integral) <= 1e-12 * abs(integral)
    # u' = -u, u(0) = 1, collocated slab by slab: spectral accuracy at every node
    n = b.nodes.size
    a = b.time_stiffness(np.ones(n))[:, 1:] + b.time_mass(np.ones(n))[:, 1:]
    v = np.linalg.solve(a, -b.time_mass(np.ones(n)) @ np.ones(n))
    np.testing.assert_allclose(1.0 + v, np.exp(-b.nodes[1:]), rtol=0, atol=1e-9)


def test_series_rows_are_the_interpolation_matrix_on_each_slab_s_nodes():
    """A series along a march's time basis reads each time's slab only: the same rows as the dense matrix,
    without its (times x nodes) zeros (a stiff march's 8449 nodes at 17k check times: 1.1 GB)."""
    breakpoints = tuple(np.linspace(0.0, 2.0, 41))  # many slabs (few: the dense rows, below)
    b = make_basis("chebyshev", (0.0, 2.0), 40 * 8 + 1, breakpoints=breakpoints)
    x = np.concatenate([np.random.default_rng(1).uniform(0, 2, 300), b.nodes, breakpoints])
    rows = b.series_rows(x)
    assert rows.shape == (x.size, b.nodes.size) and rows.index.shape == (x.size, 9)
    np.testing.assert_array_equal(rows.toarray(), b.interpolation_matrix(x))
    values = np.random.default_rng(2).normal(size=(b.nodes.size, 3))
    np.testing.assert_allclose(rows.apply(values), b.interpolation_matrix(x) @ values, rtol=0, atol=1e-14)
    np.testing.assert_allclose(b.interpolate(values, x), rows.apply(values), rtol=0, atol=1e-14)
    for dense in (make_basis("chebyshev", (0.0, 2.0), 9), make_basis("chebyshev", (0.0, 2.0), 3 * 8 + 1,
                                                                     breakpoints=(0.0, 0.5, 1.2, 2.0))):
        np.testing.assert_array_equal(dense.series_rows(x), dense.interpolation_matrix(x))


def test_piecewise_derivative_is_each_slab_s_built_on_first_use():
    """A march's time basis has a slab per step (a stiff problem: ~1e5 nodes); its n x n derivative
    is built only when an operator asks for it, and is then each slab's Chebyshev derivative."""
    big = make_basis("chebyshev", (0.0, 40.0), 4 * 40000 + 1, breakpoints=tuple(np.linspace(0.0, 40.0, 40001)))
    assert "derivative" not in vars(big)  # 160001^2 values would be 205 GB
    b = make_basis("chebyshev", (0.0, 2.0), 3 * 5 + 1, breakpoints=(0.0, 0.5, 1.2, 2.0))  # 6 nodes a slab
    d = b.derivative
    assert d is b.derivative and d.shape == (16, 16)
    p = np.polynomial.Polynomial([0.3, -1.0, 0.5, 2.0, -0.7, 0.1])  # degree 5: exact on 6-node slabs
    np.testing.assert_allclose(d @ p(b.nodes), p.deriv()(b.nodes), rtol=0, atol=1e-11)
    assert np.all(d[5, 6:] == 0) and np.all(d[5, :5] != 0)  # a shared node takes its left slab's row
    # interpolation slab by slab, without the (points, n) matrix: the matrix's values, the nodal values at nodes
    rng = np.random.default_rng(2)
    values, x = rng.standard_normal((16, 3)), rng.uniform(0.0, 2.0, 50)
    np.testing.assert_allclose(b.interpolate(values, x), b.interpolation_matrix(x) @ values, rtol=0, atol=1e-14)
    assert np.array_equal(b.interpolate(values, b.nodes), values)
    t = rng.uniform(0.0, 40.0, 1000)
    np.testing.assert_allclose(big.interpolate(np.sin(big.nodes), t), np.sin(t), rtol=0, atol=1e-6)


def test_piecewise_basis_rejects_uneven_slabs():
    with pytest.raises(ValueError, match="equal node counts"):
        make_basis("chebyshev", (0.0, 1.0), 10, breakpoints=(0.0, 0.5, 1.0))


SPRING_2_SLABS = open("problems/spring.yaml").read().replace("tolerance: 1e-10", "tolerance: 1e-10\n  time_slabs: 2")


def test_pgd_with_two_equal_time_slabs_matches_the_exact_spring():
    problem = pgdcli.parse_spec(SPRING_2_SLABS, source="spring2")
    assert problem.solver.time_slabs == 2
    result = pgdcli.solve(problem)
    assert_solved(result)
    t = result.codebook.coordinate("t")
    per_slab = problem.coordinate("t").nodes
    assert t.nodes == 2 * (per_slab - 1) + 1 and t.breakpoints == (0.0, 2.0, 4.0)
    rng = np.random.default_rng(3)
    tt, k, c = rng.uniform(0, 4, 500), rng.uniform(1, 4, 500), rng.uniform(0.1, 0.5, 500)
    wd = np.sqrt(k - c**2 / 4)
    exact = np.exp(-c * tt / 2) * (np.cos(wd * tt) + c / (2 * wd) * np.sin(wd * tt))
    assert np.max(np.abs(result.codebook(t=tt, k=k, c=c)["x"] - exact)) <= 1e-8


def test_slab_breakpoints_survive_save_and_load(tmp_path):
    result = pgdcli.solve(pgdcli.load_spec("problems/logistic.yaml"))
    path = result.codebook.save(tmp_path / "l.h5")
    loaded = Codebook.load(path)
    assert loaded.coordinate("t").breakpoints == result.codebook.coordinate("t").breakpoints
    assert len(loaded.coordinate("t").breakpoints) > 2
    x = {"t": 0.77, "r": 1.3, "u0": 0.4}
    assert float(loaded(**x)["u"]) == float(result.codebook(**x)["u"])
    e = np.exp(1.3 * 0.77)
    assert abs(float(loaded(**x)["u"]) - 0.4 * e / (0.6 + 0.4 * e)) <= 1e-9


@pytest.mark.parametrize("value, message", [("often", "expected 'auto' or an integer >= 1"),
                                            ("0", "expected 'auto' or an integer >= 1")])
def test_time_slabs_validation(value, message):
    text = open("problems/logistic.yaml").read().replace("tolerance: 1e-10", f"tolerance: 1e-10\n  time_slabs: {value}")
    with pytest.raises(SpecError, match=message):
        pgdcli.parse_spec(text, source="x.yaml")


def test_single_points_on_a_sliced_time_axis_agree_with_the_batch_path():
    cb = pgdcli.solve(pgdcli.load_spec("problems/logistic.yaml")).codebook
    t = cb.coordinate("t")
    rng = np.random.default_rng(9)
    times = np.concatenate([rng.uniform(*t.domain, 40), np.array(t.breakpoints), t.basis().nodes[:5]])
    r, u0 = 1.1, 0.35
    batch = cb(t=times, r=r, u0=u0)["u"]
    single = np.array([float(cb(t=float(x), r=r, u0=u0)["u"]) for x in times])
    np.testing.assert_allclose(single, batch, rtol=0, atol=1e-14)
    e = np.exp(r * times)
    np.testing.assert_allclose(single, u0 * e / (1 - u0 + u0 * e), rtol=0, atol=1e-10)

"""Codebook.gradient and pgdcli.codebook.gradient: exact derivatives of the interpolants."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import codebook_points, exact_relaxation

from pgdcli.discretization.basis import make_basis
from pgdcli.errors import QueryError
from pgdcli.codebook.gradient import derivative_matrix


# ----------------------------------------------------------------------------------------------
# 1-D: the derivative rows differentiate what the bases represent exactly
# ----------------------------------------------------------------------------------------------
def test_chebyshev_rows_differentiate_polynomials_exactly():
    basis = make_basis("chebyshev", (-0.5, 2.0), 9)
    coef = np.random.default_rng(1).normal(size=9)  # degree 8: represented exactly by 9 nodes
    f, df = np.polynomial.Polynomial(coef), np.polynomial.Polynomial(coef).deriv()
    x = np.concatenate([np.random.default_rng(2).uniform(-0.5, 2.0, 50), basis.nodes])
    got = derivative_matrix(basis, x) @ f(basis.nodes)
    assert np.max(np.abs(got - df(x))) <= 1e-11 * np.max(np.abs(df(x)))


def test_slab_rows_differentiate_each_slab_and_take_the_right_slab_at_a_breakpoint():
    bp = (0.0, 0.3, 1.0)
    basis = make_basis("chebyshev", (0.0, 1.0), 2 * 4 + 1, bp)  # 2 slabs of 5 nodes: degree 4 per slab
    left = np.polynomial.Polynomial([1, -2, 3, 0.5])
    right = left + np.polynomial.Polynomial([-0.3, 1]) * np.polynomial.Polynomial([1, 2])  # continuous, kinked
    values = np.where(basis.nodes < 0.3, left(basis.nodes), right(basis.nodes))
    x = np.array([0.0, 0.1, 0.29, 0.3, 0.31, 0.8, 1.0])
    got = derivative_matrix(basis, x) @ values
    expected = np.where(x < 0.3, left.deriv()(x), right.deriv()(x))
    assert np.allclose(got[[1, 2, 4, 5, 6]], expected[[1, 2, 4, 5, 6]], rtol=0, atol=1e-11)
    assert abs(got[3] - right.deriv()(0.3)) < 1e-11


def test_linear_rows_are_the_slope_of_the_element_on_the_right():
    basis = make_basis("linear", (0.0, 2.0), 5)
    values = np.array([0.0, 1.0, 3.0, 2.0, 2.0])
    got = derivative_matrix(basis, np.array([0.0, 0.25, 0.5, 0.9, 1.0, 1.7, 2.0]))
    assert np.allclose(got @ values, [2.0, 2.0, 4.0, 4.0, -2.0, 0.0, 0.0], rtol=0, atol=1e-14)


# ----------------------------------------------------------------------------------------------
# codebooks: against exact derivatives and finite differences
# ----------------------------------------------------------------------------------------------
def _complex_step(func, p, name, h=1e-30):
    q = {k: np.asarray(v, dtype=complex) for k, v in p.items()}
    q[name] = q[name] + 1j * h
    return {u: v.imag / h for u, v in func(q).items()}


def test_relaxation_gradient_matches_the_exact_solution(solved):
    """du/d(t, k, a, u0) of the CP codebook against the closed form's complex-step derivatives."""
    cb = solved("relaxation").codebook
    p = codebook_points(cb, 300, seed=3)
    grad = cb.gradient(p)
    scale = np.max(np.abs(exact_relaxation(p)["u"]))
    for name in cb.coordinate_names:
        exact = _complex_step(exact_relaxation, p, name)["u"]
        err = np.max(np.abs(grad["u"][name] - exact))
        assert err <= 1e-6 * max(scale, np.max(np.abs(exact))), (name, err)
    # the time derivative is the equation's right-hand side: u' = -k u + a sin(2t)
    rhs = -p["k"] * cb(**p)["u"] + p["a"] * np.sin(2 * p["t"])
    assert np.max(np.abs(grad["u"]["t"] - rhs)) <= 1e-6


def test_spring_gradient_matches_finite_differences(solved):
    cb = solved("spring").codebook
    p = codebook_points(cb, 100, seed=4, corners=False)
    grad = cb.gradient(p, wrt=["k", "c"], fields=["x"])
    assert set(grad) == {"x"} and set(grad["x"]) == {"k", "c"}
    for name, h in (("k", 1e-5), ("c", 1e-6)):
        up, down = dict(p), dict(p)
        up[name], down[name] = p[name] + h, p[name] - h
        fd = (cb(**up)["x"] - cb(**down)["x"]) / (2 * h)
        assert np.max(np.abs(grad["x"][name] - fd)) <= 1e-7


def test_coupled_tensor_train_time_derivative_is_the_right_hand_side(solved):
    """u1' = 1 - u2 u3, ... at random points: the TT codebook's d/dt against its own equations."""
    cb = solved("coupled").codebook
    p = codebook_points(cb, 200, seed=5)
    grad = cb.gradient(p, wrt=["t"])
    u = cb(**p)
    rhs = {"u1": 1 - u["u2"] * u["u3"], "u2": 2 - u["u1"] * u["u3"], "u3": 3 - u["u1"] * u["u2"]}
    for name in rhs:
        assert np.max(np.abs(grad[name]["t"] - rhs[name])) <= 1e-6, name


def test_gradient_in_blocks_of_points_equals_one_block(solved, monkeypatch):
    """A march's time basis can have ~1e5 nodes: the (points, nodes) rows are built block by block."""
    import pgdcli.codebook.gradient as gradient

    cb = solved("coupled").codebook
    p = codebook_points(cb, 300, seed=8)
    whole = cb.gradient(p)
    monkeypatch.setattr(gradient, "CHUNK_VALUES", 7 * max(c.nodes for c in cb.coordinates))  # blocks of 7 points
    blocks = cb.gradient(p)
    for u in whole:
        for name in whole[u]:
            # the same products on fewer rows: BLAS may sum in another order, and the derivative rows'
            # entries (~2 n^2 / length: ~1e3 here) cancel to O(1): rounding of ~1e3 eps
            scale = np.max(np.abs(whole[u][name]))
            np.testing.assert_allclose(blocks[u][name], whole[u][name], rtol=0, atol=1e-11 * scale)


def test_coupled_parameter_derivatives_match_finite_differences(solved):
    cb = solved("coupled").codebook
    p = codebook_points(cb, 100, seed=6, corners=False)
    p = {k: np.clip(v, 1e-4, None) if k != "t" else v for k, v in p.items()}
    grad = cb.gradient(p, wrt=["a", "b", "c"])
    h = 1e-5
    for name in "abc":
        up, down = dict(p), dict(p)
        up[name], down[name] = np.minimum(p[name] + h, 1.0), p[name] - h
        values_up, values_down = cb(**up), cb(**down)
        for u in cb.unknown_names:
            fd = (values_up[u] - values_down[u]) / (up[name] - down[name])
            assert np.max(np.abs(grad[u][name] - fd)) <= 1e-7, (u, name)


@pytest.mark.parametrize("name", ["relaxation", "coupled"])
def test_grid_gradient_equals_the_point_gradient_on_the_meshgrid(solved, name):
    cb = solved(name).codebook
    rng = np.random.default_rng(7)
    axes = {c.name: np.sort(rng.uniform(*c.domain, 2 + i)) for i, c in enumerate(cb.coordinates)}
    grid = cb.gradient(axes, grid=True)
    mesh = dict(zip(axes, np.meshgrid(*axes.values(), indexing="ij")))
    points = cb.gradient(mesh)
    for u in cb.unknown_names:
        for c in cb.coordinate_names:
            assert grid[u][c].shape == mesh[c].shape
            assert np.allclose(grid[u][c], points[u][c], rtol=1e-12, atol=1e-12)


def test_gradient_errors_are_query_errors(solved):
    cb = solved("relaxation").codebook
    p = {"t": 1.0, "k": 1.0, "a": 0.0, "u0": 0.5}
    with pytest.raises(QueryError, match="unknown coordinate 'q' in wrt"):
        cb.gradient(p, wrt=["q"])
    with pytest.raises(QueryError, match="outside the domain"):
        cb.gradient(dict(p, k=99.0))
    with pytest.raises(QueryError, match="missing coordinate 'u0'"):
        cb.gradient({"t": 1.0, "k": 1.0, "a": 0.0})


@pytest.mark.parametrize("name, axis", [("relaxation", "t"), ("relaxation", "a"), ("coupled", "t"), ("coupled", "b"),
                                        ("coupled", "c")])
def test_trajectory_model_equals_evaluate_and_gradient(solved, name, axis):
    """Along one coordinate (first, middle or last core of the train) at a point of the others."""
    from pgdcli.codebook.gradient import TrajectoryModel

    cb = solved(name).codebook
    rng = np.random.default_rng(8)
    values = rng.uniform(*cb.coordinate(axis).domain, 17)
    model = TrajectoryModel(cb, axis, values, cb.unknown_names)
    point = [rng.uniform(*c.domain) for c in cb.coordinates]
    others = [j for j, c in enumerate(cb.coordinates) if c.name != axis]
    got = model.evaluate(point, others)
    coords = {c.name: (values if c.name == axis else point[j]) for j, c in enumerate(cb.coordinates)}
    expected_values = cb(**coords)
    expected = cb.gradient(coords, wrt=[cb.coordinate_names[j] for j in others])
    for i, u in enumerate(cb.unknown_names):
        assert np.allclose(got[i, :, 0], expected_values[u], rtol=1e-12, atol=1e-12)
        for s, j in enumerate(others):
            assert np.allclose(got[i, :, 1 + s], expected[u][cb.coordinate_names[j]], rtol=1e-11, atol=1e-11)
    with pytest.raises(ValueError):
        model.evaluate(point, [cb.coordinate_names.index(axis)])

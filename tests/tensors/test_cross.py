"""TT-cross (pgdcli.cross) against dense tensors: exact low-rank functions, smooth functions, rank caps."""

import numpy as np
import pytest

from pgdcli.tensors.cross import maxvol, tt_cross, tt_from_full, tt_values_at
from pgdcli.tensors.tt import TT


def grid_function(shape, f):
    """f of the grid points x_k in [0, 1] (uniform), as an index function and the dense tensor."""
    axes = [np.linspace(0.0, 1.0, n) for n in shape]

    def function(idx):
        return f(*[axes[k][idx[:, k]] for k in range(len(shape))])

    dense = f(*np.meshgrid(*axes, indexing="ij"))
    return function, dense


def rms(a, b):
    return float(np.sqrt(np.mean((a - b) ** 2)))


def test_maxvol_bounds_the_coefficients():
    rng = np.random.default_rng(1)
    a = rng.standard_normal((200, 7))
    rows = maxvol(a)
    assert len(set(rows)) == 7
    assert np.max(np.abs(a @ np.linalg.inv(a[rows]))) <= 1.05 + 1e-12


@pytest.mark.parametrize("table_limit", [0, 2 ** 16])  # contracted at every call, and tabulated once
@pytest.mark.parametrize("ranks", [(3, 2), (1, 1)])  # the rank-one path of coefficients and initial values too
def test_values_at_match_the_full_tensor(ranks, table_limit, monkeypatch):
    from pgdcli.tensors import cross

    monkeypatch.setattr(cross, "TABLE_LIMIT", table_limit)
    rng = np.random.default_rng(2)
    train = TT([rng.standard_normal((1, 4, ranks[0])), rng.standard_normal((ranks[0], 5, ranks[1])),
                rng.standard_normal((ranks[1], 6, 1))])
    idx = np.stack([rng.integers(0, n, 50) for n in (4, 5, 6)], axis=1)
    full = train.full()
    cores = [c.copy() for c in train.cores]
    np.testing.assert_allclose(tt_values_at(train, idx), full[idx[:, 0], idx[:, 1], idx[:, 2]], rtol=1e-13, atol=1e-13)
    assert all(np.array_equal(a, b) for a, b in zip(cores, train.cores))  # the cores untouched
    # a mode whose slices are equal at every node is folded in (a coefficient free of that coordinate)
    flat = TT([train.cores[0], np.repeat(train.cores[1][:, :1, :], 5, axis=1), train.cores[2]])
    np.testing.assert_allclose(tt_values_at(flat, idx), flat.full()[idx[:, 0], idx[:, 1], idx[:, 2]], rtol=1e-13,
                               atol=1e-13)
    constant = TT([np.repeat(c[:, :1, :], c.shape[1], axis=1) for c in train.cores])
    np.testing.assert_allclose(tt_values_at(constant, idx), constant.full()[0, 0, 0], rtol=1e-13, atol=1e-13)


def test_tt_from_full_meets_its_bound():
    f, dense = grid_function((9, 10, 11), lambda x, y, z: np.exp(-x * y * z))
    train = tt_from_full(dense, 1e-6)
    assert np.linalg.norm(train.full() - dense) <= 1e-6


@pytest.mark.parametrize("shape", [(12, 13, 14, 15), (8,) * 6])
def test_exact_low_rank_function_recovered_to_machine_precision(shape):
    # sum of two products: TT rank 2 exactly
    f, dense = grid_function(shape, lambda *x: np.prod([np.sin(1 + xi) for xi in x], axis=0)
                             + np.prod([np.cos(2 * xi) for xi in x], axis=0))
    result = tt_cross(f, shape, 1e-10, dense_limit=0, rng=np.random.default_rng(3))
    assert result.converged, result.message
    assert max(result.train.ranks) == 2
    assert np.max(np.abs(result.train.full() - dense)) <= 1e-12 * np.max(np.abs(dense))
    assert result.evaluations < dense.size


@pytest.mark.parametrize("tolerance", [1e-4, 1e-8, 1e-11])
def test_smooth_function_to_the_requested_accuracy(tolerance):
    shape = (16,) * 5
    f, dense = grid_function(shape, lambda a, b, c, d, e: np.sin(1 + a + 0.5 * b * c) / (1.5 + d * e + a))
    result = tt_cross(f, shape, tolerance, dense_limit=0, rng=np.random.default_rng(4))
    assert result.converged, result.message
    assert rms(result.train.full(), dense) <= tolerance
    assert result.evaluations < 0.5 * dense.size


def test_rank_above_the_cap_reports_failure():
    shape = (30, 30, 30)
    # a (nearly) full-rank function: rank 30 across every bond
    f, dense = grid_function(shape, lambda x, y, z: 1.0 / (1e-3 + np.abs(x - y) + np.abs(y - z)))
    result = tt_cross(f, shape, 1e-10, max_rank=5, dense_limit=0, rng=np.random.default_rng(5))
    assert not result.converged
    assert "cap 5" in result.message


def test_dense_path_rank_cap_and_non_finite_values():
    f, dense = grid_function((20, 20), lambda x, y: 1.0 / (1e-3 + np.abs(x - y)))
    result = tt_cross(f, (20, 20), 1e-12, max_rank=3)
    assert not result.converged and "cap 3" in result.message
    g, _ = grid_function((5, 6, 7), lambda x, y, z: np.log(np.abs(x - 0.5) + 0 * y * z) * (x != 0.5) + np.where(x < 0.3, np.nan, 0.0))
    bad = tt_cross(g, (5, 6, 7), 1e-8)
    assert not bad.converged and "not finite" in bad.message
    bad = tt_cross(g, (5, 6, 7), 1e-8, dense_limit=0)
    assert not bad.converged and "not finite" in bad.message


def test_warm_start_reuses_index_sets():
    shape = (16,) * 5
    f, dense = grid_function(shape, lambda a, b, c, d, e: np.exp(-(a + b * c + d * e)))
    first = tt_cross(f, shape, 1e-9, dense_limit=0, rng=np.random.default_rng(6))
    g, dense2 = grid_function(shape, lambda a, b, c, d, e: np.exp(-1.01 * (a + b * c + d * e)))
    second = tt_cross(g, shape, 1e-9, dense_limit=0, right_sets=first.right_sets)
    assert second.converged and rms(second.train.full(), dense2) <= 1e-9

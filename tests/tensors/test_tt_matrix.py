"""TT-matrices (pgdcli.tensors.tt_matrix) against the dense matrices they stand for."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.tensors.tt import TT
from pgdcli.tensors.tt_matrix import TTMatrix, tt_matrix_from_terms
from pgdcli.tensors.tt_svd import tt_from_cp


def kron_all(mats) -> np.ndarray:
    out = np.ones((1, 1))
    for m in mats:
        out = np.kron(out, m)
    return out


def random_terms(shapes, count: int, diagonal: set, seed: int):
    """``count`` Kronecker terms over modes of ``shapes``; the modes in ``diagonal`` diagonal in every term."""
    rng = np.random.default_rng(seed)
    terms = []
    for _ in range(count):
        term = []
        for k, (m, n) in enumerate(shapes):
            term.append(np.diag(rng.standard_normal(m)) if k in diagonal else rng.standard_normal((m, n)))
        terms.append(term)
    return terms


def random_train(shape, rank: int, seed: int) -> TT:
    rng = np.random.default_rng(seed)
    ranks = [1] + [rank] * (len(shape) - 1) + [1]
    return TT([rng.standard_normal((ranks[k], n, ranks[k + 1])) for k, n in enumerate(shape)])


@pytest.mark.parametrize("diagonal", [set(), {1}, {0, 2}])
def test_from_terms_is_the_sum_of_kronecker_products(diagonal):
    shapes = [(4, 4), (5, 5), (3, 3)]
    terms = random_terms(shapes, 7, diagonal, seed=len(diagonal))
    dense = sum(kron_all(t) for t in terms)
    matrix = tt_matrix_from_terms(terms)
    assert [matrix.diagonal(k) for k in range(3)] == [k in diagonal for k in range(3)]
    np.testing.assert_allclose(matrix.full(), dense, atol=1e-12 * np.abs(dense).max())


def test_linearly_dependent_terms_are_merged():
    # a Laplacian-like sum: A (x) I (x) I + I (x) A (x) I + I (x) I (x) A has ranks 2, not 3
    a = np.random.default_rng(3).standard_normal((4, 4))
    eye = np.eye(4)
    terms = [[a, eye, eye], [eye, a, eye], [eye, eye, a], [2 * a, eye, eye]]
    matrix = tt_matrix_from_terms(terms)
    assert matrix.ranks == (2, 2)
    np.testing.assert_allclose(matrix.full(), sum(kron_all(t) for t in terms), atol=1e-12)


def test_rectangular_modes():
    shapes = [(3, 5), (4, 2)]
    terms = random_terms(shapes, 3, set(), seed=4)
    matrix = tt_matrix_from_terms(terms)
    assert matrix.row_shape == (3, 4) and matrix.column_shape == (5, 2)
    np.testing.assert_allclose(matrix.full(), sum(kron_all(t) for t in terms), atol=1e-12)


@pytest.mark.parametrize("diagonal", [set(), {0}, {1, 2}])
def test_matvec_transpose_and_gram_match_dense(diagonal):
    shapes = [(4, 4), (6, 6), (3, 3)]
    matrix = tt_matrix_from_terms(random_terms(shapes, 5, diagonal, seed=7))
    dense = matrix.full()
    x = random_train([4, 6, 3], 3, seed=8)
    np.testing.assert_allclose(matrix.matvec(x).full().reshape(-1), dense @ x.full().reshape(-1),
                               atol=1e-11 * np.abs(dense).max() * np.abs(x.full()).max() * dense.shape[1])
    np.testing.assert_allclose(matrix.transpose().full(), dense.T, atol=1e-12)
    np.testing.assert_allclose(matrix.gram().full(), dense.T @ dense, rtol=1e-10, atol=1e-10 * np.abs(dense).max() ** 2)
    assert all(matrix.gram().diagonal(k) == (k in diagonal) for k in range(3))


def test_rounded_keeps_the_operator_and_lowers_redundant_ranks():
    shapes = [(3, 3), (4, 4), (3, 3)]
    matrix = tt_matrix_from_terms(random_terms(shapes, 4, {1}, seed=9))
    gram = matrix.gram()
    rounded = gram.rounded()
    assert all(r <= g for r, g in zip(rounded.ranks, gram.ranks)) and rounded.ranks != gram.ranks
    np.testing.assert_allclose(rounded.full(), gram.full(), atol=1e-11 * np.abs(gram.full()).max())


def test_scaled_columns_is_a_right_diagonal_product():
    shapes = [(3, 3), (4, 4)]
    matrix = tt_matrix_from_terms(random_terms(shapes, 3, {0}, seed=10))
    rng = np.random.default_rng(11)
    scales = [rng.uniform(0.5, 2.0, 3), rng.uniform(0.5, 2.0, 4)]
    np.testing.assert_allclose(matrix.scaled_columns(scales).full(), matrix.full() @ np.diag(kron_all(
        [s[None, :] for s in scales]).ravel()), atol=1e-12)


def test_invalid_cores_are_refused_with_the_index():
    with pytest.raises(ValueError, match="core 1 has left rank 2"):
        TTMatrix([np.ones((1, 2, 2, 3)), np.ones((2, 2, 2, 1))])
    with pytest.raises(ValueError, match="core 0 must be"):
        TTMatrix([np.ones((1, 2))])
    with pytest.raises(ValueError, match="left rank and the last core's right rank must be 1"):
        TTMatrix([np.ones((2, 2, 1))])


@pytest.mark.parametrize("relative", [0.0, 1e-6, 1e-2])
def test_tt_from_cp_meets_its_bound(relative):
    # many terms of a smooth function of four variables: far fewer ranks than terms
    rng = np.random.default_rng(12)
    grids = [np.linspace(0.0, 1.0, n) for n in (7, 6, 5, 8)]
    centres = rng.uniform(0.0, 1.0, (60, 4))
    factors = [np.exp(-((g[:, None] - centres[None, :, k]) ** 2) / 0.3) for k, g in enumerate(grids)]
    weights = rng.standard_normal(60)
    full = np.einsum("c,ic,jc,kc,lc->ijkl", weights, *factors)
    absolute = relative * np.linalg.norm(full)
    train = tt_from_cp(weights, factors, absolute)
    assert np.linalg.norm(train.full() - full) <= max(absolute, 1e-12 * np.linalg.norm(full))
    if relative > 0:
        assert max(train.ranks) < 30


def test_tt_from_cp_of_cancelling_terms_is_resolved_to_rounding():
    # two nearly equal terms of opposite sign: their difference, 1e-10 of each, is kept to rounding of the
    # terms (through a Gram matrix it would be lost: errors near sqrt(eps) times the terms)
    x = np.linspace(0.0, 1.0, 9)
    f, g = np.exp(x), np.exp(x) * (1 + 1e-10 * x)
    full = np.einsum("i,j->ij", f, g) - np.einsum("i,j->ij", f, f)
    train = tt_from_cp(np.array([1.0, -1.0]), [np.column_stack([f, f]), np.column_stack([g, f])], 0.0)
    np.testing.assert_allclose(train.full(), full, rtol=0, atol=1e-13)
    assert np.abs(full).max() > 1e-10

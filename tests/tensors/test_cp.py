"""Separated tensors and operators (pgdcli.tensors.cp) against dense numpy."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pgdcli.tensors.cp import CPTensor, SeparatedOperator

EPS = np.finfo(float).eps


def _random_cp(rng, shape, rank):
    return CPTensor(rng.standard_normal(rank), [rng.standard_normal((n, rank)) for n in shape])


def _dense(weights, factors):
    """Independent full tensor: sum_r w_r outer(f_1[:, r], ..., f_d[:, r]) via einsum."""
    letters = "abcdefgh"[: len(factors)]
    return np.einsum(",".join(f"{l}r" for l in letters) + ",r->" + letters, *factors, weights)


# ----------------------------------------------------------------------------------------------
# CPTensor
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("shape,rank", [((4,), 3), ((3, 5), 1), ((3, 4, 5), 4), ((2, 3, 2, 4), 6), ((7, 1, 3), 2)])
def test_cptensor_full_and_norm_match_numpy(shape, rank):
    rng = np.random.default_rng(rank + len(shape))
    x = _random_cp(rng, shape, rank)
    assert x.shape == shape and x.rank == rank and x.order == len(shape)
    full = x.full()
    np.testing.assert_allclose(full, _dense(x.weights, x.factors), rtol=1e-13, atol=1e-14)
    assert x.norm() == pytest.approx(np.linalg.norm(full.ravel()), rel=1e-13)


@settings(max_examples=60, deadline=None)
@given(shape=st.lists(st.integers(1, 5), min_size=1, max_size=4), rank=st.integers(1, 5), seed=st.integers(0, 2**31))
def test_cptensor_norm_matches_dense_property(shape, rank, seed):
    x = _random_cp(np.random.default_rng(seed), tuple(shape), rank)
    assert x.norm() == pytest.approx(np.linalg.norm(_dense(x.weights, x.factors).ravel()), rel=1e-12, abs=1e-300)


def test_cptensor_add_and_scale():
    rng = np.random.default_rng(11)
    x, y = _random_cp(rng, (3, 4, 2), 2), _random_cp(rng, (3, 4, 2), 3)
    s = x + y
    assert s.rank == 5
    np.testing.assert_allclose(s.full(), x.full() + y.full(), rtol=1e-13, atol=1e-14)
    np.testing.assert_allclose(x.scaled(-2.5).full(), -2.5 * x.full(), rtol=1e-14, atol=1e-15)


def test_cptensor_size_counts_the_stored_floats():
    x = CPTensor(np.ones(3), (np.ones((4, 3)), np.ones((5, 3))))
    assert x.size == 3 + 4 * 3 + 5 * 3


def test_cptensor_rank_zero_norm_is_zero():
    x = CPTensor(np.zeros(0), [np.zeros((3, 0)), np.zeros((4, 0))])
    assert x.norm() == 0.0
    assert np.array_equal(x.full(), np.zeros((3, 4)))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_norm_resolves_residual_far_below_gram_limit(seed):
    """||X - (X + E)|| with ||E|| = 1e-13 ||X||: the sweep sees E, the Gram formula cannot."""
    rng = np.random.default_rng(seed)
    shape, rank = (6, 7, 5), 3
    w = rng.standard_normal(rank)
    fs = [rng.standard_normal((n, rank)) for n in shape]
    x_norm = np.linalg.norm(_dense(w, fs))
    e = [rng.standard_normal(n) for n in shape]
    e = [v / np.linalg.norm(v) for v in e]
    eps = 1e-13 * x_norm  # E = eps * e1 (x) e2 (x) e3, so ||E|| = eps exactly (closed form)
    diff = CPTensor(
        np.concatenate([w, -w, [-eps]]),
        [np.column_stack([f, f, v]) for f, v in zip(fs, e)],
    )
    assert diff.norm() == pytest.approx(eps, rel=1e-2)
    # the construction really is beyond the Gram formula's reach (a meaningful test)
    gram = np.ones((2 * rank + 1,) * 2)
    for f in diff.factors:
        gram *= f.T @ f
    squared = diff.weights @ gram @ diff.weights
    gram_norm = np.sqrt(squared) if squared > 0 else 0.0
    assert not (gram_norm == pytest.approx(eps, rel=0.5, abs=0.0))  # approx defaults to abs=1e-12 > eps


def test_norm_of_exact_cancellation_is_rounding_level():
    rng = np.random.default_rng(9)
    x = _random_cp(rng, (5, 6, 4), 3)
    assert (x + x.scaled(-1.0)).norm() <= 1e-15 * x.norm()


# ----------------------------------------------------------------------------------------------
# SeparatedOperator
# ----------------------------------------------------------------------------------------------
def _kron_all(mats):
    out = np.array([[1.0]])
    for m in mats:
        out = np.kron(out, m)
    return out


@pytest.mark.parametrize("sizes", [[(3, 3)], [(4, 4), (3, 3)], [(3, 4), (5, 2), (2, 3)], [(2, 2), (3, 3), (2, 2), (3, 3)]])
def test_separated_operator_apply_matches_dense_kron(sizes):
    rng = np.random.default_rng(len(sizes))
    K = 3
    terms = tuple(tuple(rng.standard_normal(s) for s in sizes) for _ in range(K))
    op = SeparatedOperator(terms)
    assert op.order == len(sizes) and op.n_terms == K
    dense = sum(_kron_all(t) for t in terms)
    np.testing.assert_allclose(op.full(), dense, rtol=1e-13, atol=1e-14)
    x = _random_cp(rng, tuple(n for _, n in sizes), 2)
    y = op.apply(x)
    assert y.rank == K * x.rank
    assert y.shape == tuple(m for m, _ in sizes)
    ref = dense @ _dense(x.weights, x.factors).ravel()
    np.testing.assert_allclose(y.full().ravel(), ref, rtol=1e-12, atol=1e-13 * np.abs(ref).max())
    np.testing.assert_array_equal(op.mode_stack(0), np.stack([t[0] for t in terms]))


# ----------------------------------------------------------------------------------------------
# validation messages name the culprit
# ----------------------------------------------------------------------------------------------
def test_cptensor_validation_names_bad_factor():
    with pytest.raises(ValueError, match=r"factor 1 has 3 columns, expected rank 2"):
        CPTensor(np.ones(2), [np.ones((3, 2)), np.ones((4, 3))])
    with pytest.raises(ValueError, match=r"factor 2 must be a 2D array"):
        CPTensor(np.ones(2), [np.ones((3, 2)), np.ones((4, 2)), np.ones(5)])
    with pytest.raises(ValueError, match="at least one factor"):
        CPTensor(np.ones(2), [])


def test_separated_operator_validation_names_bad_term_and_mode():
    a, b = np.eye(3), np.eye(2)
    with pytest.raises(ValueError, match=r"operator term 1, mode 1: shape \(3, 3\) differs"):
        SeparatedOperator(((a, b), (a, a)))
    with pytest.raises(ValueError, match=r"operator term 1 has 1 modes, expected 2"):
        SeparatedOperator(((a, b), (a,)))
    with pytest.raises(ValueError, match=r"operator term 0, mode 1: expected a matrix"):
        SeparatedOperator(((a, np.ones(3)),))
    with pytest.raises(ValueError, match="at least one term"):
        SeparatedOperator(())

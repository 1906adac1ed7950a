"""Orthogonal sweeps and norms of separated tensors (pgdcli.tensors.cp_sweep) against dense numpy."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.tensors.cp_sweep import _norm_split, khatri_rao_rows, orthogonal_sweep, separated_norm


def _dense(weights, factors):
    """Independent full tensor: sum_r w_r outer(f_1[:, r], ..., f_d[:, r]) via einsum."""
    letters = "abcdefgh"[: len(factors)]
    return np.einsum(",".join(f"{l}r" for l in letters) + ",r->" + letters, *factors, weights)


def test_orthogonal_sweep_preserves_inner_products():
    rng = np.random.default_rng(5)
    factors = [rng.standard_normal((n, 6)) for n in (9, 3, 5)]
    z = orthogonal_sweep(factors)
    assert z.shape[1] == 6 and z.shape[0] <= 6
    # Gram matrix of the rank-one terms, from dense vectors
    terms = np.stack([_dense(np.eye(6)[c], factors).ravel() for c in range(6)], axis=1)
    np.testing.assert_allclose(z.T @ z, terms.T @ terms, rtol=1e-12, atol=1e-12 * np.abs(terms.T @ terms).max())


@pytest.mark.parametrize("seed", [0, 1])
def test_norm_by_two_sweeps_resolves_a_tiny_residual(seed):
    """The norm splits the modes into two swept groups (here sizes (9, 6, 2) and (8, 7): the
    cheaper pair); it must still see a term of 1e-13 relative size."""
    rng = np.random.default_rng(seed)
    shape, rank = (9, 8, 7, 6, 2), 12
    assert all(_norm_split(shape, 2 * rank + 1))  # really split in two
    w = rng.standard_normal(rank)
    fs = [rng.standard_normal((n, rank)) for n in shape]
    x_norm = np.linalg.norm(_dense(w, fs))
    e = [rng.standard_normal(n) for n in shape]
    e = [v / np.linalg.norm(v) for v in e]
    eps = 1e-13 * x_norm
    weights = np.concatenate([w, -w, [-eps]])
    factors = [np.column_stack([f, f, v]) for f, v in zip(fs, e)]
    assert separated_norm(weights, factors) == pytest.approx(eps, rel=1e-2)
    # and an ordinary tensor: the dense norm
    np.testing.assert_allclose(separated_norm(w, fs), x_norm, rtol=1e-13)


def test_khatri_rao_rows_matches_kron_per_column():
    rng = np.random.default_rng(2)
    z, x = rng.standard_normal((3, 4)), rng.standard_normal((5, 4))
    out = khatri_rao_rows(z, x)
    assert out.shape == (15, 4)
    for c in range(4):
        np.testing.assert_array_equal(out[:, c], np.kron(z[:, c], x[:, c]))

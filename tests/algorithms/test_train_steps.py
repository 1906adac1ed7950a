"""The arithmetic of tensor-train states (pgdcli.algorithms.train_steps): the error norms of the embedded estimates."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import DOP853

from pgdcli.algorithms.train_steps import frobenius_of_sums
from pgdcli.tensors.tt import TT


def random_train(shape, ranks, rng) -> TT:
    bonds = [1, *ranks, 1]
    return TT([rng.standard_normal((bonds[k], n, bonds[k + 1])) for k, n in enumerate(shape)])


@pytest.mark.parametrize("shape, ranks", [((6, 5, 4, 3), (3, 4, 2)), ((7,), ()), ((5, 6), (4,))])
def test_norms_of_combinations_equal_the_full_arrays(shape, ranks):
    rng = np.random.default_rng(4)
    terms = [random_train(shape, ranks, rng) for _ in range(DOP853.n_stages + 1)]
    # nearly equal terms, as the stages of a short step: the estimates cancel to ~1e-9 of the terms
    base = terms[0]
    terms = [TT([c * (1.0 + 1e-9 * j) if k == 0 else c for k, c in enumerate(base.cores)]) for j in range(len(terms))]
    full = np.stack([t.full() for t in terms])
    for weights in ([DOP853.E5, DOP853.E3], [np.ones(len(terms)), np.zeros(len(terms))]):
        got = frobenius_of_sums(terms, weights)
        expected = [np.linalg.norm(np.tensordot(w, full, axes=1)) for w in weights]
        np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-13 * np.linalg.norm(full))


def test_random_terms_and_all_zero_weights():
    rng = np.random.default_rng(5)
    terms = [random_train((4, 5, 6), (2, 3), rng) for _ in range(5)]
    full = np.stack([t.full() for t in terms])
    w = rng.standard_normal(5)
    got = frobenius_of_sums(terms, [w, np.zeros(5)])
    assert got[1] == 0.0
    assert got[0] == pytest.approx(np.linalg.norm(np.tensordot(w, full, axes=1)), rel=1e-12)

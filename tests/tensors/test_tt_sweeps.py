"""Sweeps over cores: orthogonality, the rounding's error bound, the batched rounding."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.tensors.tt import TT
from pgdcli.tensors.tt_sweeps import (orthogonalize_left, orthogonalize_right, pad_ranks, reduce_wide_ends,
                                      round_stacked, truncate_sweep)


def _cores(rng, shape=(4, 5, 3, 6), ranks=(1, 3, 7, 4, 1)):
    return [rng.standard_normal((ranks[k], n, ranks[k + 1])) for k, n in enumerate(shape)]


def _full(cores):
    return TT(cores).full()


def test_orthogonalization_keeps_the_tensor_and_makes_cores_orthonormal():
    rng = np.random.default_rng(0)
    cores = _cores(rng)
    want = _full(cores)
    left = orthogonalize_left([c.copy() for c in cores])
    right = orthogonalize_right([c.copy() for c in cores])
    np.testing.assert_allclose(_full(left), want, atol=1e-12 * np.abs(want).max())
    np.testing.assert_allclose(_full(right), want, atol=1e-12 * np.abs(want).max())
    for c in left[:-1]:
        m = c.reshape(-1, c.shape[2])
        np.testing.assert_allclose(m.T @ m, np.eye(m.shape[1]), atol=1e-12)
    for c in right[1:]:
        m = c.reshape(c.shape[0], -1)
        np.testing.assert_allclose(m @ m.T, np.eye(m.shape[0]), atol=1e-12)


@pytest.mark.parametrize("delta", [1e-8, 1e-2, 1.0])
def test_truncation_drops_at_most_delta_per_bond(delta):
    rng = np.random.default_rng(1)
    cores = _cores(rng)
    want = _full(cores)
    out = truncate_sweep(orthogonalize_right([c.copy() for c in cores]), delta, None)
    error = np.linalg.norm(_full(out) - want)
    assert error <= delta * np.sqrt(len(cores) - 1) * (1 + 1e-10)


def test_padding_and_reducing_wide_ends_keep_the_tensor():
    rng = np.random.default_rng(2)
    cores = _cores(rng, shape=(2, 5, 2), ranks=(1, 9, 9, 1))  # bonds wider than the outer modes allow
    want = _full(cores)
    padded = pad_ranks(cores, [1, 11, 10, 1])
    np.testing.assert_array_equal(_full(padded), want)
    stacked = [c[None] for c in padded]
    reduce_wide_ends(stacked)
    assert stacked[0].shape[3] <= 2 and stacked[-1].shape[1] <= 2
    np.testing.assert_allclose(_full([c[0] for c in stacked]), want, atol=1e-12 * np.abs(want).max())


def test_batched_rounding_keeps_every_train_within_its_bound():
    rng = np.random.default_rng(3)
    trains = [_cores(rng) for _ in range(3)]
    delta = 0.5
    ranks = [1] + [max(t[k].shape[2] for t in trains) for k in range(3)] + [1]
    stacked = [np.stack(cs) for cs in zip(*[pad_ranks(t, ranks) for t in trains])]
    out = round_stacked(stacked, delta, None)
    for i, t in enumerate(trains):
        error = np.linalg.norm(_full([c[i] for c in out]) - _full(t))
        assert error <= delta * np.sqrt(3) * (1 + 1e-10)

"""TT-SVD of full tensors (pgdcli.tensors.tt_svd): the sketched splits meet the same bound as the exact SVD."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.tensors import tt_svd
from pgdcli.tensors.tt_svd import tt_from_full, tt_from_full_sketched


def smooth_tensor(shape, noise: float, seed: int) -> np.ndarray:
    """A smooth function on a grid (ranks decay fast), plus white noise of the given size."""
    grids = np.meshgrid(*[np.linspace(0.0, 1.0, n) for n in shape], indexing="ij")
    s = sum((k + 1) * g for k, g in enumerate(grids))
    values = np.exp(-s) * np.sin(3.0 * s) + 1.0 / (1.0 + s * s)
    return values + noise * np.random.default_rng(seed).standard_normal(shape)


@pytest.mark.parametrize("shape", [(50, 40, 40, 40), (113, 20, 20, 20), (30, 12, 11, 10, 9)])
@pytest.mark.parametrize("relative", [1e-3, 1e-8, 1e-11])
def test_sketched_meets_the_bound_with_the_exact_ranks(shape, relative):
    values = smooth_tensor(shape, 0.0, 0)
    absolute = relative * np.linalg.norm(values)
    exact = tt_from_full(values, absolute)
    sketched = tt_from_full_sketched(values, absolute, np.random.default_rng(1))
    error = np.linalg.norm(sketched.full() - values)
    assert error <= absolute, (error, absolute)
    # the sketched range is measured, so it costs at most a rank or two over the exact SVD's truncation
    assert all(s <= e + 2 for s, e in zip(sketched.ranks, exact.ranks)), (sketched.ranks, exact.ranks)


def test_a_too_narrow_sketch_is_widened_and_noise_goes_to_the_exact_svd():
    values = smooth_tensor((40, 24, 24, 24), 1e-6, 2)  # full rank below 1e-6: no sketch can be narrow
    absolute = 1e-9 * np.linalg.norm(values)
    sketched = tt_from_full_sketched(values, absolute, np.random.default_rng(3), rank_guesses=(2, 2, 2))
    assert np.linalg.norm(sketched.full() - values) <= absolute
    exact = tt_from_full(values, absolute)
    assert sketched.ranks == exact.ranks


def test_small_unfoldings_take_the_exact_svd(monkeypatch):
    calls = []
    split = tt_svd._sketched_split

    def counted(*args):
        out = split(*args)
        calls.append(out is not None)
        return out

    monkeypatch.setattr(tt_svd, "_sketched_split", counted)
    values = smooth_tensor((10, 9, 8), 0.0, 4)
    train = tt_from_full_sketched(values, 1e-10, np.random.default_rng(5))
    assert calls == [False, False]
    assert np.linalg.norm(train.full() - values) <= 1e-10

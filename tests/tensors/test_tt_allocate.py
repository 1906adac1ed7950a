"""Rank allocation of tensor-train rounding (pgdcli.tensors.tt_allocate) against numpy on full tensors.

Spectra are checked against numpy's SVD of the full tensor's unfoldings, errors on the full
tensors (with the measurement's rounding allowance of test_tt, not a looser tolerance), and
the allocation against a brute-force search over all rank pairs of a three-core train.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pgdcli.tensors.tt import TT, tt_round, tt_round_shared
from pgdcli.tensors.tt_allocate import allocate_ranks, bond_spectra, rank_within, truncate_allocated

EPS = np.finfo(float).eps


def _slack(full: np.ndarray) -> float:
    return 100 * EPS * np.sqrt(full.size) * np.linalg.norm(full)


def _unfolding_spectra(full: np.ndarray) -> list[np.ndarray]:
    return [np.linalg.svd(full.reshape(int(np.prod(full.shape[:k])), -1), compute_uv=False)
            for k in range(1, full.ndim)]


def _smooth_tt(shape) -> tuple[TT, np.ndarray]:
    """1 / (1 + x_1 + 2 x_2 + ... ) on [0, 1] grids: fast-decaying spectra, ranks up to the mode sizes."""
    grids = np.meshgrid(*[np.linspace(0, 1, n) for n in shape], indexing="ij")
    full = 1.0 / (1.0 + sum((k + 1) * g for k, g in enumerate(grids)))
    cores, rest, left = [], full, 1
    for n in shape[:-1]:  # exact TT-SVD with numpy (no truncation)
        u, s, vt = np.linalg.svd(rest.reshape(left * n, -1), full_matrices=False)
        cores.append(u.reshape(left, n, s.size))
        rest, left = s[:, None] * vt, s.size
    cores.append(rest.reshape(left, shape[-1], 1))
    return TT(cores), full


def _right_orthogonal(cores: list[np.ndarray]) -> list[np.ndarray]:
    cores = [c.copy() for c in cores]
    for k in range(len(cores) - 1, 0, -1):
        r0, n, r1 = cores[k].shape
        q, r = np.linalg.qr(cores[k].reshape(r0, n * r1).T)
        cores[k] = q.T.reshape(-1, n, r1)
        cores[k - 1] = np.einsum("anb,cb->anc", cores[k - 1], r)
    return cores


def _values(ranks, sizes) -> int:
    r = [1, *ranks, 1]
    return sum(r[k] * n * r[k + 1] for k, n in enumerate(sizes))


def test_bond_spectra_are_those_of_the_unfoldings():
    train, full = _smooth_tt((5, 6, 7, 4))
    spectra, left = bond_spectra(_right_orthogonal(list(train.cores)))
    for got, expected in zip(spectra, _unfolding_spectra(full)):
        np.testing.assert_allclose(got, expected[:got.size], rtol=0, atol=1e-12 * expected[0])
        assert np.all(expected[got.size:] <= 1e-12 * expected[0])
    assert np.linalg.norm(TT(left).full() - full) <= _slack(full)
    for core in left[:-1]:  # left-orthogonal
        m = core.reshape(-1, core.shape[2])
        np.testing.assert_allclose(m.T @ m, np.eye(m.shape[1]), atol=1e-12)


def test_allocation_within_budget_and_no_more_values_than_equal_shares():
    rng = np.random.default_rng(3)
    sizes = [4, 9, 9, 9, 4]
    spectra = [np.sort(rng.uniform(0, 1, r) * np.logspace(0, -8, r))[::-1] for r in (4, 30, 40, 30)]
    for delta in (1e-6, 1e-4, 1e-2):
        ranks = allocate_ranks(spectra, sizes, delta)
        dropped = sum(np.sum(s[r:] ** 2) for s, r in zip(spectra, ranks))
        assert dropped <= delta ** 2
        share = delta / np.sqrt(len(spectra))
        equal = [max(1, int(np.sum(np.sqrt(np.cumsum((s * s)[::-1]))[::-1] > share))) for s in spectra]
        assert _values(ranks, sizes) <= _values(equal, sizes)


def test_allocation_matches_brute_force_on_three_cores():
    # the middle mode is large: a rank of the first bond costs 2 + 50 values, of the second 50 + 2
    sizes = [2, 50, 2]
    spectra = [np.array([1.0, 3e-4]), np.array([1.0, 2e-4])]
    for delta in (1e-4, 2.5e-4, 3.7e-4, 1e-3):
        ranks = allocate_ranks(spectra, sizes, delta)
        best = min(_values(r, sizes) for r in itertools.product(range(1, 3), repeat=2)
                   if sum(np.sum(s[k:] ** 2) for s, k in zip(spectra, r)) <= delta ** 2)
        assert _values(ranks, sizes) == best


@pytest.mark.parametrize("relative", [1e-3, 1e-6, 1e-9])
def test_truncate_allocated_within_delta_with_the_allocated_ranks(relative):
    train, full = _smooth_tt((6, 9, 9, 9, 6))
    delta = relative * np.linalg.norm(full)
    rounded = tt_round(train, absolute=delta, allocate=True)
    assert np.linalg.norm(rounded.full() - full) <= delta + _slack(full)
    expected = allocate_ranks(_unfolding_spectra(full), list(full.shape), delta)
    assert list(rounded.ranks) == expected
    plain = tt_round(train, absolute=delta)
    assert sum(c.size for c in rounded.cores) <= sum(c.size for c in plain.cores)


def test_truncate_allocated_keeps_an_exact_low_rank_train():
    rng = np.random.default_rng(5)
    cores = [rng.standard_normal((1, 4, 2)), rng.standard_normal((2, 5, 3)), rng.standard_normal((3, 4, 1))]
    full = TT(cores).full()
    out = truncate_allocated(_right_orthogonal(cores), 1e-12 * np.linalg.norm(full))
    assert [c.shape[2] for c in out[:-1]] == [2, 3]
    assert np.linalg.norm(TT(out).full() - full) <= _slack(full)


def test_round_shared_allocated_each_train_within_delta():
    rng = np.random.default_rng(8)
    train, _ = _smooth_tt((5, 8, 8, 6))
    shared = list(train.cores[1:])
    firsts = [train.cores[0] * rng.uniform(0.5, 2.0, (1, 1, train.cores[0].shape[2])) for _ in range(3)]
    delta = 1e-7
    allocated = tt_round_shared(firsts, shared, absolute=delta, allocate=True)
    plain = tt_round_shared(firsts, shared, absolute=delta)
    for first, got, equal in zip(firsts, allocated, plain):
        full = TT([first] + shared).full()
        assert np.linalg.norm(got.full() - full) <= delta + _slack(full)
        assert sum(c.size for c in got.cores) <= sum(c.size for c in equal.cores)


def test_round_refuses_allocate_with_max_rank():
    train, _ = _smooth_tt((3, 4, 3))
    with pytest.raises(ValueError, match="allocate"):
        tt_round(train, absolute=1e-6, allocate=True, max_rank=2)


def test_rank_within_is_the_smallest_rank_dropping_at_most_delta():
    """Against the definition, rank by rank: the norm of what is dropped beyond it."""
    rng = np.random.default_rng(4)
    for _ in range(50):
        s = np.sort(rng.random(rng.integers(1, 12)) ** 3)[::-1]
        delta = float(rng.uniform(0, 1.2 * np.linalg.norm(s)))
        fits = [r for r in range(1, s.size + 1) if np.linalg.norm(s[r:]) <= delta]
        assert rank_within(s, delta) == min(fits)
    assert rank_within(np.zeros(3), 0.0) == 1


def test_rank_within_drops_values_under_the_floor_even_when_delta_keeps_them():
    """Against the definition: the smallest rank within delta, capped by the count of values above the floor."""
    rng = np.random.default_rng(5)
    for _ in range(50):
        s = np.sort(10.0 ** rng.uniform(-18, 0, rng.integers(1, 12)))[::-1]
        delta = float(rng.choice([0.0, 1e-17, 1e-9]))
        floor = float(rng.choice([1e-14, 1e-6]))
        fits = min(r for r in range(1, s.size + 1) if np.linalg.norm(s[r:]) <= delta)
        above = int(np.sum(s > floor * s[0]))
        assert rank_within(s, delta, floor) == max(1, min(fits, above))
    assert rank_within(np.zeros(4), 0.0, 1e-14) == 1
    assert rank_within(np.zeros(0), 0.0, 1e-14) == 1

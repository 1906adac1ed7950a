"""The cross of a vector-valued function (pgdcli.tensors.fiber_cross), against the function itself at
multi-indices it never asked for, and against exact ranks."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.tensors import fiber_cross
from pgdcli.tensors.fiber_cross import vector_cross, tt_vectors_at
from pgdcli.tensors.tt import tt_round

NODES = 0.5 + 0.5 * (1.0 - np.cos(np.pi * np.arange(9) / 8))  # Chebyshev-Lobatto nodes on [0.5, 1.5]
TIMES = np.linspace(0.0, 1.0, 30)


def trajectories(indices: np.ndarray) -> np.ndarray:
    """A smooth family of curves of t (the vector) depending on five parameters, not separable."""
    x = NODES[indices]
    decay = np.exp(-np.outer(x.sum(axis=1), TIMES) / 5.0)
    wave = np.cos(np.outer(x[:, 0] * x[:, 1], TIMES) + x[:, 2:3])
    return decay * wave + np.outer(1.0 / (1.0 + x[:, 3] * x[:, 4]), TIMES ** 2)


def columns(indices: np.ndarray) -> np.ndarray:
    """The trajectories as vector_cross takes them: one column per multi-index."""
    return trajectories(indices).T


def held_out(seed: int, count: int = 4000) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, NODES.size, size=(count, 5))


@pytest.mark.parametrize("tolerance", [1e-5, 1e-8])
def test_cross_meets_its_tolerance_where_it_never_looked(tolerance):
    result = vector_cross(columns, TIMES.size, (NODES.size,) * 5, tolerance, largest=10 * tolerance,
                          rng=np.random.default_rng(0))
    assert result.converged, result.message
    assert result.train.shape == (TIMES.size,) + (NODES.size,) * 5
    points = held_out(1)
    difference = tt_vectors_at(result.train, points) - trajectories(points)
    # the check points are a sample: allow the held-out root mean square twice the sampled one
    assert np.sqrt(np.mean(difference ** 2)) <= 2 * tolerance
    assert np.max(np.abs(difference)) <= 20 * tolerance
    assert result.evaluations < NODES.size ** 5  # fewer trajectories than the grid has nodes


def test_exact_rank_three_is_found():
    rng = np.random.default_rng(3)
    vectors = rng.standard_normal((3, 12))
    factors = rng.uniform(0.5, 1.5, size=(3, 4, 7))  # term, mode, node

    def function(indices):
        terms = np.prod([factors[:, k, indices[:, k]] for k in range(4)], axis=0)  # (3, P)
        return vectors.T @ terms

    result = vector_cross(function, 12, (7,) * 4, 1e-10, rng=np.random.default_rng(0))
    assert result.converged, result.message
    rounded = tt_round(result.train, absolute=1e-9)
    assert max(rounded.ranks) <= 3
    grid = np.stack(np.meshgrid(*[np.arange(7)] * 4, indexing="ij"), axis=-1).reshape(-1, 4)
    np.testing.assert_allclose(tt_vectors_at(result.train, grid), function(grid).T, atol=1e-9)


def test_rank_cap_is_reported_not_hidden():
    table = np.random.default_rng(5).standard_normal((6,) * 4 + (3,))  # no low rank at all
    result = vector_cross(lambda idx: table[tuple(idx.T)].T, 3, (6,) * 4, 1e-8, rng=np.random.default_rng(0),
                          max_rank=5)
    assert not result.converged
    assert "max_rank=5" in result.message


def test_same_seed_same_train_and_bad_arguments():
    first = vector_cross(columns, TIMES.size, (NODES.size,) * 5, 1e-5, rng=np.random.default_rng(4))
    second = vector_cross(columns, TIMES.size, (NODES.size,) * 5, 1e-5, rng=np.random.default_rng(4))
    assert all(np.array_equal(a, b) for a, b in zip(first.train.cores, second.train.cores))
    with pytest.raises(ValueError, match="outputs >= 1"):
        vector_cross(columns, 0, (3, 3), 1e-5, rng=np.random.default_rng(0))


def test_evaluation_budget_stops_the_cross():
    result = vector_cross(columns, TIMES.size, (NODES.size,) * 5, 1e-10, rng=np.random.default_rng(0),
                          max_evaluations=5000)
    assert not result.converged
    assert "more than the budget of 5,000" in result.message
    assert result.evaluations > 5000


MEMO_FLOATS = fiber_cross.MEMO_FLOATS


class Counting:
    """``columns`` that records every multi-index it is asked for."""

    def __init__(self):
        self.asked: list[np.ndarray] = []

    def __call__(self, indices: np.ndarray) -> np.ndarray:
        self.asked.append(indices.copy())
        return columns(indices)

    @property
    def points(self) -> np.ndarray:
        return np.vstack(self.asked)


def crossed(monkeypatch, memo_floats: int):
    monkeypatch.setattr(fiber_cross, "MEMO_FLOATS", memo_floats)
    function = Counting()
    result = vector_cross(function, TIMES.size, (NODES.size,) * 5, 1e-8, rng=np.random.default_rng(2))
    assert result.converged, result.message
    return result, function


class Picks:
    """A map over batches that records the (multi-index, output) of every value picked."""

    def __init__(self):
        self.picked: list[tuple] = []

    def __call__(self, fn, items):
        for prefixes, tail, outputs, groups in items:
            value = fn((prefixes, tail, outputs, groups))
            points = fiber_cross.batch_points(prefixes, tail)
            if outputs is not None:
                width = len(tail)
                self.picked += [tuple(points[g * width + j]) + (o,) for g, o in zip(groups, outputs)
                                for j in range(width)]
                whole = columns(points.astype(int))  # the task's values are the function's, picked
                assert np.array_equal(value, whole[outputs[:, None], groups[:, None] * width + np.arange(width)])
            yield value


def picked(monkeypatch, memo_floats: int):
    monkeypatch.setattr(fiber_cross, "MEMO_FLOATS", memo_floats)
    picks = Picks()
    result = vector_cross(columns, TIMES.size, (NODES.size,) * 5, 1e-10, rng=np.random.default_rng(2), map=picks)
    assert result.converged, result.message
    return result, picks.picked


def test_the_memo_saves_evaluations_and_leaves_the_train_as_it_is(monkeypatch):
    without, plain = picked(monkeypatch, 0)
    result, values = picked(monkeypatch, MEMO_FLOATS)
    assert all(np.array_equal(a, b) for a, b in zip(result.train.cores, without.train.cores))
    # a core's next visit takes the values of its last one from the memo: fewer values and trajectories
    assert set(values) == set(plain) and len(values) < 0.85 * len(plain)
    assert result.evaluations < without.evaluations


def test_a_full_memo_starts_again_with_the_same_train(monkeypatch):
    without, _ = crossed(monkeypatch, 0)
    everything, _ = crossed(monkeypatch, MEMO_FLOATS)
    # room for 3000 values: less than the cross asks for, more than most requests
    result, counted = crossed(monkeypatch, 3000)
    assert everything.evaluations < result.evaluations < without.evaluations
    assert len(counted.points) == result.evaluations
    assert all(np.array_equal(a, b) for a, b in zip(result.train.cores, without.train.cores))


class Recorded:
    """A map over batches that records what each task sends back."""

    def __init__(self):
        self.floats = 0

    def __call__(self, fn, items):
        for item in items:
            value = fn(item)
            self.floats += value.size
            yield value


def test_an_interior_fibre_sends_back_only_the_values_it_uses(monkeypatch):
    monkeypatch.setattr(fiber_cross, "MEMO_FLOATS", 0)
    mapped = Recorded()
    function = Counting()
    result = vector_cross(function, TIMES.size, (NODES.size,) * 5, 1e-8, rng=np.random.default_rng(2),
                          map=mapped)
    plain, _ = crossed(monkeypatch, 0)
    assert all(np.array_equal(a, b) for a, b in zip(result.train.cores, plain.train.cores))
    # whole vectors of every point would be evaluations x M values; the picks are a few per point
    assert mapped.floats < 0.25 * result.evaluations * TIMES.size


def test_batches_smaller_than_one_prefix_fibres_still_meet_the_tolerance(monkeypatch):
    monkeypatch.setattr(fiber_cross, "BATCH_FLOATS", 7 * TIMES.size)  # 7 points a task: slices of a prefix
    picks = Picks()
    result = vector_cross(columns, TIMES.size, (NODES.size,) * 5, 1e-8, rng=np.random.default_rng(0), map=picks)
    assert result.converged, result.message
    points = held_out(1)
    difference = tt_vectors_at(result.train, points) - trajectories(points)
    assert np.sqrt(np.mean(difference ** 2)) <= 2e-8

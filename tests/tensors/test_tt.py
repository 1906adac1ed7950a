"""Tensor trains (pgdcli.tensors.tt) against numpy on the full tensors.

Every expectation is computed independently with numpy from the cores or the
full tensors (explicit index loops, einsum), never with pgdcli.tensors.tt itself.
Rounding bounds are checked on the full tensors with an allowance of a few
units of rounding of the measurement (``_SLACK``), not a looser tolerance.
"""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from pgdcli.discretization.basis import make_basis
from pgdcli.tensors.tt import TT, tt_constant, tt_hadamard, tt_rank_one, tt_round, tt_round_many, tt_round_shared, tt_sum

EPS = np.finfo(float).eps
SHAPES = {1: (5,), 2: (4, 6), 3: (3, 5, 4), 4: (3, 4, 2, 5)}
RANKS = {1: (), 2: (3,), 3: (2, 3), 4: (2, 3, 2)}


def _slack(x_full: np.ndarray) -> float:
    """Rounding allowance of measuring ||Y - X||_F on the full tensors (not a tolerance)."""
    return 100 * EPS * np.sqrt(x_full.size) * np.linalg.norm(x_full)


def random_tt(rng, shape, ranks) -> TT:
    r = (1,) + tuple(ranks) + (1,)
    return TT([rng.standard_normal((r[k], n, r[k + 1])) for k, n in enumerate(shape)])


def explicit_full(cores) -> np.ndarray:
    """X[i1..id] = G1[:, i1, :] @ ... @ Gd[:, id, :], one entry at a time."""
    shape = tuple(c.shape[1] for c in cores)
    out = np.empty(shape)
    for idx in itertools.product(*[range(n) for n in shape]):
        m = np.eye(1)
        for c, i in zip(cores, idx):
            m = m @ c[:, i, :]
        out[idx] = m[0, 0]
    return out


def decaying_tt(rng, shape, terms=8, ratio=0.1) -> TT:
    """Sum of rank-one trains with weights 1, ratio, ratio^2, ... (rounding has something to cut)."""
    parts = [tt_rank_one([rng.standard_normal(n) for n in shape]) for _ in range(terms)]
    return tt_sum(parts, [ratio ** k for k in range(terms)])


# ----------------------------------------------------------------------------------------------
# construction, full, properties
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_full_matches_explicit_product(d):
    rng = np.random.default_rng(d)
    x = random_tt(rng, SHAPES[d], RANKS[d])
    full = x.full()
    assert full.shape == SHAPES[d]
    np.testing.assert_allclose(full, explicit_full(x.cores), rtol=1e-13, atol=1e-13)
    assert x.order == d
    assert x.shape == SHAPES[d]
    assert x.ranks == RANKS[d]
    assert x.size == sum(c.size for c in x.cores)


def test_rank_one_and_constant():
    rng = np.random.default_rng(7)
    vs = [rng.standard_normal(n) for n in (3, 4, 5)]
    x = tt_rank_one(vs, 2.5)
    np.testing.assert_allclose(x.full(), 2.5 * np.einsum("i,j,k->ijk", *vs), rtol=1e-14, atol=1e-14)
    assert x.ranks == (1, 1)
    c = tt_constant(-1.5, (2, 3, 4))
    np.testing.assert_array_equal(c.full(), np.full((2, 3, 4), -1.5))


# ----------------------------------------------------------------------------------------------
# arithmetic
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_sum_weighted_and_unweighted(d):
    rng = np.random.default_rng(10 + d)
    xs = [random_tt(rng, SHAPES[d], r) for r in (RANKS[d], tuple(1 for _ in RANKS[d]), tuple(2 for _ in RANKS[d]))]
    fulls = [explicit_full(x.cores) for x in xs]
    w = [0.5, -2.0, 3.0]
    np.testing.assert_allclose(tt_sum(xs, w).full(), sum(a * f for a, f in zip(w, fulls)), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(tt_sum(xs).full(), sum(fulls), rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose((xs[0] + xs[1]).full(), fulls[0] + fulls[1], rtol=1e-12, atol=1e-12)
    # one term: scaled copy
    np.testing.assert_allclose(tt_sum([xs[0]], [4.0]).full(), 4.0 * fulls[0], rtol=1e-13, atol=1e-13)
    if d > 1:  # ranks add at every bond
        s = tt_sum(xs)
        assert s.ranks == tuple(sum(x.ranks[k] for x in xs) for k in range(d - 1))


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_hadamard(d):
    rng = np.random.default_rng(20 + d)
    x = random_tt(rng, SHAPES[d], RANKS[d])
    y = random_tt(rng, SHAPES[d], tuple(r + 1 for r in RANKS[d]))
    fx, fy = explicit_full(x.cores), explicit_full(y.cores)
    z = tt_hadamard(x, y)
    np.testing.assert_allclose(z.full(), fx * fy, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose((x * y).full(), fx * fy, rtol=1e-12, atol=1e-12)
    assert z.ranks == tuple(a * b for a, b in zip(x.ranks, y.ranks))


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_scaled_and_scalar_multiplication(d):
    rng = np.random.default_rng(30 + d)
    x = random_tt(rng, SHAPES[d], RANKS[d])
    fx = explicit_full(x.cores)
    np.testing.assert_allclose(x.scaled(-3.25).full(), -3.25 * fx, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose((2.0 * x).full(), 2.0 * fx, rtol=1e-13, atol=1e-13)
    np.testing.assert_allclose((x * 0.5).full(), 0.5 * fx, rtol=1e-13, atol=1e-13)
    # the original is untouched
    np.testing.assert_allclose(x.full(), fx, rtol=1e-13, atol=1e-13)


@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_norm_matches_numpy(d):
    rng = np.random.default_rng(40 + d)
    x = random_tt(rng, SHAPES[d], RANKS[d])
    assert x.norm() == pytest.approx(np.linalg.norm(explicit_full(x.cores)), rel=1e-13)
    # a sum with heavy cancellation: X + (1e-8 - 1) X has norm 1e-8 ||X||
    y = tt_sum([x, x], [1.0, 1e-8 - 1.0])
    assert y.norm() == pytest.approx(1e-8 * np.linalg.norm(x.full()), rel=1e-6)


# ----------------------------------------------------------------------------------------------
# evaluate
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("d", [1, 2, 3, 4])
def test_evaluate_with_interpolation_matrices(d):
    rng = np.random.default_rng(50 + d)
    shape = SHAPES[d]
    x = random_tt(rng, shape, RANKS[d])
    full = explicit_full(x.cores)
    p = 37
    kinds = ["chebyshev", "linear"]
    bases = [make_basis(kinds[k % 2], (-1.0, 2.0), n) for k, n in enumerate(shape)]
    mats = [b.interpolation_matrix(rng.uniform(-1.0, 2.0, p)) for b in bases]
    letters = "ijkl"[:d]
    expr = letters + "," + ",".join(f"p{l}" for l in letters) + "->p"
    ref = np.einsum(expr, full, *mats)
    np.testing.assert_allclose(x.evaluate(mats), ref, rtol=1e-12, atol=1e-12)
    # unit rows pick entries of the full tensor
    idx = [rng.integers(0, n, p) for n in shape]
    units = [np.eye(n)[i] for n, i in zip(shape, idx)]
    np.testing.assert_allclose(x.evaluate(units), full[tuple(idx)], rtol=1e-13, atol=1e-13)


# ----------------------------------------------------------------------------------------------
# rounding
# ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("d", [2, 3, 4])
@pytest.mark.parametrize("tol", [0.3, 1e-1, 1e-3, 1e-6, 1e-10])
def test_round_relative_bound(d, tol):
    rng = np.random.default_rng(60 + d)
    shape = tuple(n + 2 for n in SHAPES[d])
    x = decaying_tt(rng, shape, terms=8, ratio=0.1)
    full = x.full()
    y = tt_round(x, tol)
    err = np.linalg.norm(y.full() - full)
    assert err <= tol * np.linalg.norm(full) + _slack(full), (err, tol * np.linalg.norm(full))
    assert all(r <= rx for r, rx in zip(y.ranks, x.ranks))
    if tol >= 1e-1:  # not vacuous: something was cut
        assert sum(y.ranks) < sum(x.ranks)


@pytest.mark.parametrize("d", [2, 3, 4])
@pytest.mark.parametrize("absolute", [1.0, 1e-2, 1e-5, 1e-9])
def test_round_absolute_bound(d, absolute):
    rng = np.random.default_rng(70 + d)
    shape = tuple(n + 2 for n in SHAPES[d])
    x = tt_sum([decaying_tt(rng, shape, terms=6, ratio=0.05), random_tt(rng, shape, RANKS[d]).scaled(1e-4)])
    full = x.full()
    y = tt_round(x, absolute=absolute)
    err = np.linalg.norm(y.full() - full)
    assert err <= absolute + _slack(full), (err, absolute)
    if absolute >= 1e-2:
        assert sum(y.ranks) < sum(x.ranks)


def test_round_ranks_shrink_as_tolerance_loosens():
    rng = np.random.default_rng(80)
    x = decaying_tt(rng, (6, 7, 8, 5), terms=10, ratio=0.2)
    ranks = [tt_round(x, tol).ranks for tol in (1e-12, 1e-8, 1e-4, 1e-1)]
    for tighter, looser in zip(ranks, ranks[1:]):
        assert all(b <= a for a, b in zip(tighter, looser)), ranks


@pytest.mark.parametrize("true_ranks,shape", [((2, 3), (5, 6, 7)), ((2, 3, 2), (4, 5, 6, 4)), ((3,), (6, 5))])
def test_round_recovers_exact_low_rank(true_ranks, shape):
    rng = np.random.default_rng(90 + len(shape))
    x = random_tt(rng, shape, true_ranks)
    full = explicit_full(x.cores)
    padded = tt_sum([x, x], [0.25, 0.75])  # the same tensor with doubled ranks
    assert padded.ranks == tuple(2 * r for r in true_ranks)
    y = tt_round(padded, 1e-12)
    assert y.ranks == true_ranks
    np.testing.assert_allclose(y.full(), full, rtol=0, atol=1e-11 * np.abs(full).max())
    # absolute bound, and through tt_round_many too
    z = tt_round(padded, absolute=1e-12 * np.linalg.norm(full))
    assert z.ranks == true_ranks
    (w,) = tt_round_many([padded], absolute=1e-12 * np.linalg.norm(full))
    assert w.ranks == true_ranks


def test_round_max_rank_caps():
    rng = np.random.default_rng(100)
    x = random_tt(rng, (6, 6, 6, 6), (5, 6, 5))
    y = tt_round(x, 0.0, max_rank=2)
    assert max(y.ranks) <= 2
    assert y.shape == x.shape


def test_round_zero_and_order_one():
    z = tt_round(tt_constant(0.0, (3, 4, 5)), 1e-8)
    np.testing.assert_array_equal(z.full(), np.zeros((3, 4, 5)))
    rng = np.random.default_rng(101)
    x = random_tt(rng, (7,), ())
    np.testing.assert_array_equal(tt_round(x, 1e-3).full(), x.full())


def test_round_many_each_train_within_its_bound():
    rng = np.random.default_rng(110)
    shape = (6, 5, 7, 4)
    trains = [
        decaying_tt(rng, shape, terms=8, ratio=0.1),  # ranks (8, 8, 8)
        random_tt(rng, shape, (2, 3, 2)),  # exact, small ranks
        tt_rank_one([rng.standard_normal(n) for n in shape], 100.0),  # rank one, large norm
        tt_sum([random_tt(rng, shape, (3, 4, 3)), decaying_tt(rng, shape, terms=5, ratio=1e-3)]),
        tt_constant(0.0, shape),
    ]
    fulls = [t.full() for t in trains]
    for absolute in (1e-1, 1e-4, 1e-10):
        out = tt_round_many(trains, absolute=absolute)
        assert len(out) == len(trains)
        for i, (y, full) in enumerate(zip(out, fulls)):
            assert y.shape == shape
            err = np.linalg.norm(y.full() - full)
            assert err <= absolute + _slack(full), (i, absolute, err)


def test_round_many_order_one_and_two():
    rng = np.random.default_rng(111)
    for shape, ranks in (((9,), ()), ((6, 8), (4,))):
        trains = [random_tt(rng, shape, ranks), random_tt(rng, shape, tuple(1 for _ in ranks))]
        for y, x in zip(tt_round_many(trains, absolute=1e-3), trains):
            assert np.linalg.norm(y.full() - x.full()) <= 1e-3 + _slack(x.full())


# ----------------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------------
def test_constructor_rejects_empty():
    with pytest.raises(ValueError, match="at least one core"):
        TT([])


def test_constructor_names_a_core_that_is_not_3d():
    with pytest.raises(ValueError, match=r"core 1 must be 3D.*\(3, 4\)"):
        TT([np.ones((1, 3, 2)), np.ones((3, 4)), np.ones((2, 5, 1))])


def test_constructor_names_cores_with_mismatched_ranks():
    with pytest.raises(ValueError, match=r"core 2 has left rank 3, core 1 right rank 2"):
        TT([np.ones((1, 3, 2)), np.ones((2, 4, 2)), np.ones((3, 5, 1))])


def test_constructor_names_the_boundary_cores():
    with pytest.raises(ValueError, match="first core's left rank"):
        TT([np.ones((2, 3, 2)), np.ones((2, 4, 1))])
    with pytest.raises(ValueError, match="last core's right rank"):
        TT([np.ones((1, 3, 2)), np.ones((2, 4, 3))])


def test_constructor_names_a_mode_order_that_is_not_a_permutation():
    cores = [np.ones((1, 3, 2)), np.ones((2, 4, 1))]
    with pytest.raises(ValueError, match=r"mode order \[0, 0\] is not a permutation of the 2 cores' modes 0..1"):
        TT(cores, (0, 0))
    with pytest.raises(ValueError, match=r"mode order \[1, 2\]"):
        TT(cores, (1, 2))


# ----------------------------------------------------------------------------------------------
# mode order: core k holds mode mode_order[k]
# ----------------------------------------------------------------------------------------------
def test_mode_order_sets_shape_full_and_evaluate_in_mode_order():
    rng = np.random.default_rng(8)
    cores = [rng.standard_normal(s) for s in ((1, 3, 2), (2, 4, 3), (3, 5, 1))]
    x = TT(cores, (2, 0, 1))  # core 0 is mode 2, core 1 mode 0, core 2 mode 1
    assert x.shape == (4, 5, 3) and x.ranks == (2, 3) and x.rank == 3
    by_core = np.einsum("ia,ajb,bk->ijk", cores[0][0], cores[1], cores[2][:, :, 0])  # (3, 4, 5)
    np.testing.assert_allclose(x.full(), np.transpose(by_core, (1, 2, 0)), rtol=1e-14, atol=1e-14)
    rows = [rng.standard_normal((6, n)) for n in x.shape]
    expected = [sum(x.full()[i, j, k] * rows[0][p, i] * rows[1][p, j] * rows[2][p, k]
                    for i, j, k in itertools.product(*map(range, x.shape))) for p in range(6)]
    np.testing.assert_allclose(x.evaluate(rows), expected, rtol=1e-12, atol=1e-12)


def test_operations_keep_the_mode_order_and_refuse_to_mix_orders():
    rng = np.random.default_rng(9)
    cores = [rng.standard_normal(s) for s in ((1, 3, 2), (2, 4, 3), (3, 5, 1))]
    x, y = TT(cores, (2, 0, 1)), TT([2.0 * cores[0]] + cores[1:], (2, 0, 1))  # y = 2 x
    for result, full in ((x.scaled(3.0), 3 * x.full()), (tt_sum([x, y]), x.full() + y.full()),
                         (tt_hadamard(x, y), x.full() * y.full()), (tt_round(tt_sum([x, y]), 1e-12), 3 * x.full()),
                         (tt_round_many([x, y], absolute=1e-12)[1], y.full())):
        assert result.mode_order == (2, 0, 1)
        np.testing.assert_allclose(result.full(), full, rtol=1e-10, atol=1e-10)
    identity = TT(cores)
    assert identity.mode_order == (0, 1, 2)
    with pytest.raises(ValueError, match=r"train 1 has mode order \[0, 1, 2\], train 0 \[2, 0, 1\]"):
        tt_sum([x, identity])
    with pytest.raises(ValueError, match="train 1 has mode order"):
        tt_hadamard(x, identity)


# ---------------------------------------------------------------- sums of Hadamard products, centres
def _random_train(rng, shape, rank):
    ranks = [1] + [rank] * (len(shape) - 1) + [1]
    return TT([rng.standard_normal((ranks[k], n, ranks[k + 1])) for k, n in enumerate(shape)])


@pytest.mark.parametrize("hint", [2, 6, 40])
def test_round_sum_of_products_matches_the_explicit_sum(hint):
    from pgdcli.tensors.tt import tt_ones
    from pgdcli.tensors.tt_sketch import tt_round_sum_of_products

    rng = np.random.default_rng(11)
    shape = (6, 7, 5, 4)
    a, b, c, d = (_random_train(rng, shape, r) for r in (3, 4, 2, 5))
    exact = 0.7 * a.full() * b.full() - 1.3 * c.full() * d.full() + 0.5 * a.full()
    delta = 1e-9 * np.linalg.norm(exact)
    x = tt_round_sum_of_products([(0.7, a, b), (-1.3, c, d), (0.5, a, tt_ones(shape))], absolute=delta,
                                 rank_hint=hint, rng=rng)
    # the sketch (hint 2, 6) and the explicit sum (hint 40) both land on the true ranks
    assert np.linalg.norm(x.full() - exact) <= 10 * delta
    true_ranks = tt_round(TT(tt_sum([tt_hadamard(a, b), tt_hadamard(c, d), a], [0.7, -1.3, 0.5]).cores),
                          absolute=delta).ranks
    assert x.ranks == true_ranks


def test_round_sum_of_products_counts_its_roundings():
    """A sketch far below the true rank is a failed compression: counted, redone larger, and the
    result is as accurate as the explicit sum's rounding."""
    from pgdcli.tensors.tt import tt_ones
    from pgdcli.tensors.tt_sketch import tt_round_sum_of_products

    rng = np.random.default_rng(12)
    shape = (8, 9, 7, 6)
    a, b, c, d = (_random_train(rng, shape, r) for r in (4, 5, 4, 5))
    exact = a.full() * b.full() + c.full() * d.full()
    delta = 1e-9 * np.linalg.norm(exact)
    stats = {}
    x = tt_round_sum_of_products([(1.0, a, b), (1.0, c, d)], absolute=delta, rank_hint=1, oversample=2,
                                 rng=rng, stats=stats)
    assert np.linalg.norm(x.full() - exact) <= 10 * delta
    assert stats["sketched"] == 1 and stats["redone"] >= 2  # sketch 3 -> 6 -> 12 -> ... (true rank 40)
    small = {}
    tt_round_sum_of_products([(1.0, a, tt_ones(shape))], absolute=delta, rank_hint=8, stats=small)
    assert small == {"exact": 1}


def test_centre_cores_carry_the_whole_tensor():
    from pgdcli.tensors.tt import tt_centre_cores

    rng = np.random.default_rng(5)
    t = _random_train(rng, (5, 6, 4, 3), 3)
    full = t.full()
    for k, centre in enumerate(tt_centre_cores(t.cores)):
        unfolding = np.moveaxis(full, k, 0).reshape(full.shape[k], -1)
        c = np.transpose(centre, (1, 0, 2)).reshape(centre.shape[1], -1)
        np.testing.assert_allclose(np.linalg.svd(c, compute_uv=False)[: min(c.shape)],
                                   np.linalg.svd(unfolding, compute_uv=False)[: min(c.shape)], rtol=1e-10, atol=1e-12)


def test_round_many_of_sums_with_ranks_above_the_outer_modes():
    """Sums of many trains have bonds far above the outer mode sizes (the march's stage sums): the
    batched rounding cuts them first and still lands within the bound on the unbatched ranks."""
    from pgdcli.tensors.tt import tt_round_many

    rng = np.random.default_rng(21)
    shape = (6, 9, 5, 7)
    sums, fulls = [], []
    for _ in range(3):
        parts = [_random_train(rng, shape, 4) for _ in range(13)]
        weights = list(rng.standard_normal(13))
        sums.append(tt_sum(parts, weights))
        fulls.append(sum(w * t.full() for w, t in zip(weights, parts)))
    assert sums[0].ranks[0] == 52 > shape[0] and sums[0].ranks[-1] == 52 > shape[-1]
    delta = 1e-8 * max(np.linalg.norm(f) for f in fulls)
    rounded = tt_round_many(sums, absolute=delta)
    for x, s, f in zip(rounded, sums, fulls):
        assert np.linalg.norm(x.full() - f) <= delta
        single = tt_round(s, absolute=delta)
        assert x.ranks[0] <= shape[0] and x.ranks[-1] <= shape[-1]
        assert max(x.ranks) >= max(single.ranks)  # batched: the largest rank of the batch per bond


def test_round_shared_equals_rounding_each_train():
    rng = np.random.default_rng(12)
    # a rank-3 tensor behind rank-9 cores (redundant), and three first cores of different scales
    low = [rng.standard_normal((1, 5, 3)), rng.standard_normal((3, 6, 3)), rng.standard_normal((3, 4, 1))]
    shared = [np.concatenate([low[1]] * 3, axis=0).repeat(3, axis=2) / 3.0,
              np.concatenate([low[2]] * 3, axis=0)]
    firsts = [scale * np.concatenate([low[0]] * 3, axis=2) for scale in (1.0, 1e-3, 50.0)]
    delta = 1e-8
    rounded = tt_round_shared(firsts, shared, absolute=delta)
    for first, got in zip(firsts, rounded):
        expected = tt_round(TT([first] + shared), absolute=delta)
        assert got.ranks == expected.ranks
        assert max(got.ranks) <= 3
        full = TT([first] + shared).full()
        assert np.linalg.norm(got.full() - full) <= delta
        np.testing.assert_allclose(got.full(), expected.full(), atol=1e-10 * np.abs(full).max())

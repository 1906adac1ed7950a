"""Unit tests of the PGD enrichment's steps against dense linear algebra (numpy, independent of the steps).

The rank-one fixed point (pgdcli.algorithms.rank_one), the update's Kronecker PCG and batched solves
(pgdcli.algorithms.mode_update) on small random problems whose answers a dense solve gives.
"""

from __future__ import annotations

import numpy as np
import pytest
import threadpoolctl

from pgdcli.algorithms import mode_update
from pgdcli.algorithms.rank_one import enrich
from pgdcli.tensors.cp import SeparatedOperator


def _kron_all(factors):
    out = np.ones(1)
    for f in factors:
        out = np.kron(out, f)
    return out


def _dense(op: SeparatedOperator) -> np.ndarray:
    total = 0.0
    for term in op.terms:
        m = np.ones((1, 1))
        for a in term:
            m = np.kron(m, a)
        total = total + m
    return total


def _spd(rng, n):
    q = rng.standard_normal((n, n))
    return q @ q.T / n + np.eye(n)


@pytest.mark.parametrize("formulation", ["minres", "galerkin"])
def test_rank_one_fixed_point_recovers_a_rank_one_solution(formulation):
    # A = A_1 (x) A_2 (x) A_3 (one Kronecker term, SPD factors) and r = A (a (x) b (x) c): the exact
    # solution a (x) b (x) c is rank one, and both fixed points must reach it
    rng = np.random.default_rng(0)
    sizes = (5, 4, 6)
    op = SeparatedOperator(((tuple(_spd(rng, n) for n in sizes)),))
    exact = [rng.standard_normal(n) for n in sizes]
    res_f = [(a @ x)[:, None] for a, x in zip(op.terms[0], exact)]
    with threadpoolctl.threadpool_limits(1):
        factors, iterations = enrich(op, np.ones(1), res_f, formulation=formulation, tolerance=1e-14,
                                     max_iterations=200)
    assert iterations < 200
    np.testing.assert_allclose(_kron_all(factors), _kron_all(exact), rtol=1e-9, atol=1e-10)


def test_rank_one_minres_is_stationary_and_beats_its_start():
    # two Kronecker terms, a rank-two residual: no exact rank-one solution. The minres fixed point
    # must lower ||A R - r|| below that of its start, and be stationary: re-solving any one factor
    # by dense least squares (others frozen) gives the same rank-one tensor
    rng = np.random.default_rng(1)
    sizes = (4, 5, 3)
    op = SeparatedOperator(tuple(tuple(_spd(rng, n) * s for n in sizes) for s in (1.0, 0.3)))
    A = _dense(op)
    res_w = np.array([1.0, 0.7])
    res_f = [rng.standard_normal((n, 2)) for n in sizes]
    r = sum(w * _kron_all([f[:, c] for f in res_f]) for c, w in enumerate(res_w))
    start = [np.ones(n) for n in sizes]
    with threadpoolctl.threadpool_limits(1):
        factors, _ = enrich(op, res_w, res_f, tolerance=1e-15, max_iterations=2000, start=start)
    R = _kron_all(factors)
    best_start = np.linalg.lstsq((A @ _kron_all(start))[:, None], r, rcond=None)[0][0]
    assert np.linalg.norm(A @ R - r) < np.linalg.norm(A @ _kron_all(start) * best_start - r)
    for j in range(3):
        # R as a linear function of factor j: columns kron(f_1, .., e_i, .., f_d)
        basis = np.column_stack([_kron_all([factors[m] if m != j else np.eye(sizes[j])[i] for m in range(3)])
                                 for i in range(sizes[j])])
        x = np.linalg.lstsq(A @ basis, r, rcond=None)[0]
        np.testing.assert_allclose(basis @ x, R, rtol=1e-6, atol=1e-8 * np.linalg.norm(R))


def test_kronecker_pcg_converges_to_the_dense_solution():
    # sum_kl T_kl X G_kl^T = B with T, G from normal equations (SPD as a whole): enough PCG steps
    # give numpy's dense solve of the (n m) x (n m) system
    rng = np.random.default_rng(2)
    K, n, m = 2, 3, 5
    P = rng.standard_normal((K, 4, n))  # T_kl = P_k^T P_l
    Q = rng.standard_normal((K, 7, m))  # G_kl = Q_k^T Q_l
    T = np.einsum("kai,lap->kilp", P, P)
    G = np.einsum("kab,lac->klbc", Q, Q)
    dense = sum(np.kron(T[k, :, l, :], G[k, l]) for k in range(K) for l in range(K))
    B = rng.standard_normal((n, m))
    exact = np.linalg.solve(dense, B.reshape(-1)).reshape(n, m)
    with threadpoolctl.threadpool_limits(1):
        X = mode_update._kronecker_pcg(T, G, B, np.zeros((n, m)), iterations=200, rtol=0.0)
    np.testing.assert_allclose(X, exact, rtol=1e-8, atol=1e-10 * np.abs(exact).max())


def test_batched_solve_and_its_singular_fallback():
    rng = np.random.default_rng(3)
    N = np.stack([_spd(rng, 4) for _ in range(6)])
    rhs = rng.standard_normal((6, 4))
    np.testing.assert_allclose(mode_update._solve_batched(N, rhs),
                               np.stack([np.linalg.solve(a, b) for a, b in zip(N, rhs)]), rtol=1e-12)
    N[2] = np.outer(N[2][0], N[2][0])  # singular: least squares for all, the minimum-norm answer there
    x = mode_update._solve_batched(N, rhs)
    np.testing.assert_allclose(x[2], np.linalg.lstsq(N[2], rhs[2], rcond=None)[0], rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(x[0], np.linalg.solve(N[0], rhs[0]), rtol=1e-12)

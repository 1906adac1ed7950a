"""AMEn (pgdcli.tensors.amen) and its local systems (pgdcli.tensors.amen_local) against dense linear algebra."""

from __future__ import annotations

import numpy as np
import pytest

from pgdcli.tensors import amen_local
from pgdcli.tensors.amen import amen_solve
from pgdcli.tensors.amen_local import local_apply, local_matrix, solve_local
from pgdcli.tensors.tt import TT, tt_rank_one, tt_sum
from pgdcli.tensors.tt_matrix import tt_matrix_from_terms


def laplacian(n: int) -> np.ndarray:
    return 2.0 * np.eye(n) - np.eye(n, k=1) - np.eye(n, k=-1)


def smooth_rhs(shape, seed: int) -> TT:
    """A sum of a few rank-one trains of smooth vectors (ranks 3)."""
    rng = np.random.default_rng(seed)
    terms = []
    for _ in range(3):
        vectors = [np.sin(rng.uniform(0.5, 3.0) * np.linspace(0, 1, n) + rng.uniform(0, 3)) for n in shape]
        terms.append(tt_rank_one(vectors))
    return tt_sum(terms)


def spd_system(shape, seed: int):
    """``B = sum_k I (x) .. (x) (L_k + c_k D_k) (x) .. (x) I`` (SPD, a diffusion with a reaction)."""
    rng = np.random.default_rng(seed)
    terms = []
    for k, n in enumerate(shape):
        term = [np.eye(m) for m in shape]
        term[k] = laplacian(n) * (n + 1) ** 2 / 50.0 + np.diag(rng.uniform(0.5, 1.5, n))
        terms.append(term)
    return tt_matrix_from_terms(terms)


@pytest.mark.parametrize("shape", [(8, 9, 7), (6, 5, 7, 4)])
def test_spd_solution_matches_the_dense_solve(shape):
    matrix = spd_system(shape, seed=len(shape))
    rhs = smooth_rhs(shape, seed=1)
    out = amen_solve(matrix, rhs, 1e-10, max_sweeps=30)
    assert out.converged, out.message
    exact = np.linalg.solve(matrix.full(), rhs.full().reshape(-1))
    error = np.linalg.norm(out.solution.full().reshape(-1) - exact) / np.linalg.norm(exact)
    assert error < 1e-8, error
    # the measured residual is the true one
    true = np.linalg.norm(matrix.full() @ out.solution.full().reshape(-1) - rhs.full().reshape(-1))
    assert true / rhs.norm() == pytest.approx(out.residuals[-1], rel=1e-3, abs=1e-14)


def test_nonsymmetric_system_through_its_normal_equations():
    # a convection-diffusion operator (nonsymmetric), solved as A^T A x = A^T f
    shape = (7, 8, 6)
    rng = np.random.default_rng(5)
    terms = []
    for k, n in enumerate(shape):
        term = [np.eye(m) for m in shape]
        term[k] = laplacian(n) + 0.8 * (np.eye(n, k=1) - np.eye(n, k=-1)) + np.diag(rng.uniform(0.2, 1.0, n))
        terms.append(term)
    a = tt_matrix_from_terms(terms)
    f = smooth_rhs(shape, seed=6)
    normal = a.gram().rounded()
    rhs = a.transpose().matvec(f)
    out = amen_solve(normal, rhs, 1e-11, max_sweeps=40,
                     residual=lambda x: tt_sum([a.matvec(x), f], [1.0, -1.0]).norm() / f.norm(),
                     energy=1e-12 * f.norm())
    assert out.converged, out.message
    exact = np.linalg.solve(a.full(), f.full().reshape(-1))
    error = np.linalg.norm(out.solution.full().reshape(-1) - exact) / np.linalg.norm(exact)
    assert error < 1e-8, error


def test_ranks_grow_from_a_rank_two_start_to_what_the_solution_needs():
    # the solution of a 5-D anisotropic diffusion is not low-rank; from rank 2 only the
    # residual's enrichment can raise the ranks
    shape = (5, 5, 5, 5, 5)
    matrix = spd_system(shape, seed=8)
    rhs = tt_rank_one([np.ones(n) for n in shape])
    out = amen_solve(matrix, rhs, 1e-9, max_sweeps=40, kickrank=4)
    assert out.converged, out.message
    assert max(out.ranks[-1]) > 2 + 4
    exact = np.linalg.solve(matrix.full(), rhs.full().reshape(-1))
    assert np.linalg.norm(out.solution.full().reshape(-1) - exact) < 1e-7 * np.linalg.norm(exact)


def test_a_start_at_the_solution_converges_in_one_sweep():
    shape = (6, 7, 5)
    matrix = spd_system(shape, seed=9)
    rhs = smooth_rhs(shape, seed=2)
    first = amen_solve(matrix, rhs, 1e-10)
    again = amen_solve(matrix, rhs, 1e-10, x0=first.solution)
    assert again.converged and len(again.residuals) == 1


def test_rank_cap_ends_the_solve_with_its_status():
    shape = (5, 5, 5, 5, 5)
    matrix = spd_system(shape, seed=8)
    rhs = tt_rank_one([np.ones(n) for n in shape])
    out = amen_solve(matrix, rhs, 1e-12, max_rank=3)
    assert out.status == "rank cap" and "max_rank = 3" in out.message
    assert out.residual > 1e-12


def test_callback_can_stop_the_solve():
    shape = (6, 7, 5)
    seen = []

    def stop(info):
        seen.append(info["sweep"])
        return "enough" if info["sweep"] == 2 else None

    out = amen_solve(spd_system(shape, seed=1), smooth_rhs(shape, seed=3), 1e-30, callback=stop)
    assert out.status == "stopped" and out.message == "enough" and seen == [1, 2]


def test_zero_rhs_and_mismatched_shapes():
    shape = (4, 5)
    matrix = spd_system(shape, seed=2)
    zero = amen_solve(matrix, tt_rank_one([np.zeros(4), np.zeros(5)]), 1e-8)
    assert zero.converged and zero.solution.norm() == 0.0
    with pytest.raises(ValueError, match="do not match"):
        amen_solve(matrix, tt_rank_one([np.ones(4), np.ones(6)]), 1e-8)


# -- local systems ----------------------------------------------------------------------------------

def _local_pieces(diagonal: bool, seed: int, a: int = 3, n: int = 5, c: int = 4, p: int = 2, q: int = 3):
    """Random SPD interfaces and an operator core whose local matrix is SPD."""
    rng = np.random.default_rng(seed)

    def spd_stack(size, count):
        out = []
        for _ in range(count):
            m = rng.standard_normal((size, size))
            out.append(m @ m.T + size * np.eye(size))
        return np.stack(out, axis=1)  # (size, count, size)

    left, right = spd_stack(a, p), spd_stack(c, q)
    if diagonal:
        core = rng.uniform(0.5, 1.5, (p, n, q))
    else:
        core = np.stack([np.stack([(lambda m: m @ m.T + n * np.eye(n))(rng.standard_normal((n, n)))
                                   for _ in range(q)], axis=-1) for _ in range(p)])
    return left, core, right


@pytest.mark.parametrize("diagonal", [False, True])
def test_local_apply_is_the_local_matrix(diagonal):
    left, core, right = _local_pieces(diagonal, seed=1)
    y = np.random.default_rng(2).standard_normal((left.shape[0], core.shape[1], right.shape[0]))
    np.testing.assert_allclose(local_apply(left, core, right, y).reshape(-1),
                               local_matrix(left, core, right) @ y.reshape(-1), rtol=1e-12, atol=1e-10)


@pytest.mark.parametrize("diagonal", [False, True])
def test_conjugate_gradients_meet_the_dense_solution(diagonal, monkeypatch):
    left, core, right = _local_pieces(diagonal, seed=3, a=4, n=8, c=5)
    rhs = np.random.default_rng(4).standard_normal((4, 8, 5))
    dense, how = solve_local(left, core, right, rhs, 1e-12)
    assert how.dense and how.relative_residual < 1e-12
    monkeypatch.setattr(amen_local, "DENSE_LOCAL", 10)
    iterative, how = solve_local(left, core, right, rhs, 1e-10, max_iterations=500)
    assert not how.dense and how.iterations > 0
    # what is left is measured in energy: sqrt(d^T B d) within the bound asked
    d = (iterative - dense).reshape(-1)
    assert np.sqrt(d @ local_matrix(left, core, right) @ d) < 1e-9

"""The tensor-train solver of linear problems (pgdcli.algorithms.amen_solve) against the dense discretized system."""

from __future__ import annotations

from functools import reduce

import numpy as np

import pgdcli
from conftest import PROBLEMS
from pgdcli.algorithms.amen_solve import interpolated_start, nodal_system, solve_amen, train_modes
from pgdcli.discretization.linear import discretize


def small_heat1d():
    text = (PROBLEMS / "heat1d.yaml").read_text()
    for old, new in {"nodes: 20": "nodes: 10", "nodes: 24": "nodes: 12", "nodes: 16": "nodes: 6"}.items():
        text = text.replace(old, new)
    return pgdcli.parse_spec(text, source="small-heat1d.yaml")


def kron(vectors_or_matrices):
    return reduce(np.kron, vectors_or_matrices)


def dense_nodal_residual(disc, modes, v: np.ndarray) -> float:
    """``||W^-1/2 (A v - F)||`` of the discretized system, assembled densely from its Kronecker terms."""
    a = sum(kron([term[j] for j in modes]) for term in disc.operator.terms)
    f = sum(w * kron([disc.source.factors[j][:, c] for j in modes]) for c, w in enumerate(disc.source.weights))
    weights = kron([disc.row_weights[j] for j in modes])
    return float(np.linalg.norm((a @ v - f) / np.sqrt(weights)))


def test_reported_residual_is_the_dense_systems():
    problem = small_heat1d()
    result = solve_amen(problem, 1e-6, max_rank=50)
    assert result.converged, result.message
    disc = discretize(problem)
    modes = train_modes(disc)
    v = result.solution.train.full().reshape(-1)
    dense = dense_nodal_residual(disc, modes, v)
    assert dense <= 1e-6
    assert abs(dense - result.residual) <= 1e-6 * result.residual + 1e-13


def test_nodal_system_is_the_dense_operator_without_its_row_weights():
    problem = small_heat1d()
    disc = discretize(problem)
    modes = train_modes(disc)
    operator, source, scales = nodal_system(disc, 1e-12, modes)
    weights = kron([disc.row_weights[j] for j in modes])
    a = sum(kron([term[j] for j in modes]) for term in disc.operator.terms) / np.sqrt(weights)[:, None]
    np.testing.assert_allclose(operator.full() * kron(scales)[None, :], a, atol=1e-12 * np.abs(a).max())
    f = sum(w * kron([disc.source.factors[j][:, c] for j in modes]) for c, w in enumerate(disc.source.weights))
    np.testing.assert_allclose(source.full().reshape(-1), f / np.sqrt(weights), atol=1e-11 * np.abs(f).max())


def test_a_start_on_the_same_nodes_is_the_same_train():
    problem = small_heat1d()
    result = solve_amen(problem, 1e-8, max_rank=50)
    disc = discretize(problem)
    names = [disc.names[j] for j in train_modes(disc)]
    again = interpolated_start(result.solution, disc, names)
    np.testing.assert_allclose(again.full(), result.solution.train.full(), atol=1e-14)
    # and a solve started from it is done in one sweep
    restarted = solve_amen(problem, 1e-8, max_rank=50, start=result.solution)
    assert restarted.converged and len(restarted.residuals) == 1

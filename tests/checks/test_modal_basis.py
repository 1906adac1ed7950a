"""The eigenbasis of the modal reference: a 2-D Kronecker sum split into its directions, else decomposed whole."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from conftest import spec_text

import pgdcli
from pgdcli.checks.collocation import PdeModel
from pgdcli.checks.collocation_system import PdeSystem
from pgdcli.checks.modal_basis import KroneckerModes, Modes, decompose, decompose_samples

PLATE = spec_text(
    coordinates={'x': '{domain: [0, 1]}', 'y': '{domain: [0, 2]}', 't': '{domain: [0, 1]}', 'k': '{domain: [1, 2]}'},
    unknowns={'u': '\n    initial: "sin(pi*x)*cos(pi*y/2)"\n    boundary:\n      x: {low: 0, high: 0}\n'
                   '      y: {low: {gradient: 0}, high: {gradient: 0}}'},
    equations=['"der(u) = k*(der(u, x, 2) + 0.5*der(u, y, 2) + der(u, y))"'],
)


def _operator(spec: str, nodes: dict) -> tuple[PdeModel, np.ndarray]:
    problem = pgdcli.parse_spec(spec)
    model = PdeModel(problem, nodes)
    system = PdeSystem(model, {"k": np.array([1.5])}, 1, 0)
    return model, system.A[None].toarray()


@pytest.mark.parametrize("spec, kind", [
    (PLATE, KroneckerModes),  # a sum of an x operator and a y operator (an advection in y too)
    (spec_text(PLATE, equations=['"der(u) = k*((1 + x*y)*der(u, x, 2) + der(u, y, 2))"']), Modes),  # couples them
])
def test_the_basis_diagonalizes_the_operator(spec, kind):
    model, B = _operator(spec, {"x": 14, "y": 11})
    modes = decompose(model, B)
    assert type(modes) is kind
    y = np.random.default_rng(1).standard_normal((3, model.m))
    np.testing.assert_allclose(modes.from_modes(modes.lam * modes.to_modes(y)).real, y @ B.T,
                               atol=1e-11 * np.abs(B).max())
    np.testing.assert_allclose(modes.from_modes(modes.to_modes(y)).real, y, atol=1e-12)


def test_the_split_has_the_eigenvalues_of_the_whole():
    model, B = _operator(PLATE, {"x": 12, "y": 10})
    split = np.sort_complex(decompose(model, B).lam)
    whole = np.sort_complex(np.linalg.eigvals(B))
    assert np.abs(split - whole).max() <= 1e-9 * np.abs(whole).max()


@pytest.mark.parametrize("spec, kind", [
    (PLATE, KroneckerModes),
    (spec_text(PLATE, equations=['"der(u) = k*((1 + x*y)*der(u, x, 2) + der(u, y, 2))"']), Modes),
])
def test_sparse_samples_are_split_as_the_dense_operator_is(spec, kind):
    model, B = _operator(spec, {"x": 12, "y": 10})
    blocks = [sp.csr_matrix(c * B) for c in (1.0, 0.5, 2.0)]  # three samples: multiples of one operator
    modes, lam = decompose_samples(model, blocks)
    assert type(modes) is kind and type(decompose(model, B)) is kind
    whole = np.sort_complex(np.linalg.eigvals(B))
    for c, row in zip((1.0, 0.5, 2.0), lam):
        assert np.abs(np.sort_complex(row) - c * whole).max() <= 1e-9 * c * np.abs(whole).max()


# two parameters scaling the two directions and a rate: no one factor of one matrix, one basis per direction
ANISOTROPIC = spec_text(
    coordinates={'x': '{domain: [0, 1]}', 'y': '{domain: [0, 1]}', 't': '{domain: [0, 0.3]}',
                 'kx': '{domain: [0.5, 2]}', 'ky': '{domain: [0.1, 1]}', 'r': '{domain: [0, 3]}'},
    unknowns={'u': '\n    initial: "sin(pi*x)*(1 + y**2)"\n    boundary:\n      x: {low: 0, high: 0}\n'
                   '      y: {low: {gradient: 0}, high: 1}'},
    equations=['"der(u) = kx*der(u, x, 2) + ky*der(u, y, 2) - r*u + exp(-x)"'],
)
STEADY = spec_text(
    coordinates={'x': '{domain: [0, 1]}', 'y': '{domain: [0, 2]}', 'a': '{domain: [0.5, 2]}',
                 'g': '{domain: [-1, 1]}'},
    unknowns={'u': '\n    boundary:\n      x: {low: 0, high: 0}\n      y: {low: 0, high: g*sin(pi*x)}'},
    equations=['"der(u, x, 2) + a*der(u, y, 2) + sin(pi*x)*y = 0"'],
)


def _samples(problem, S, seed):
    rng = np.random.default_rng(seed)
    return {c.name: rng.uniform(*c.domain, S) for c in problem.coordinates if c.role == "parameter"}


def test_a_diffusivity_per_direction_is_solved_in_one_basis_as_radau_integrates_it():
    from pgdcli.checks.reference import solve_reference_pde
    from pgdcli.checks.reference_pde_modal import METHOD_NAME

    problem = pgdcli.parse_spec(ANISOTROPIC)
    P, times = _samples(problem, 5, 2), np.array([0.0, 0.01, 0.1, 0.3])
    exact = solve_reference_pde(problem, P, None, times, space_nodes={"x": 14, "y": 12})
    radau = solve_reference_pde(problem, P, None, times, space_nodes={"x": 14, "y": 12}, method="Radau",
                                rtol=1e-12, atol=1e-13)
    assert exact.method == METHOD_NAME and exact.success.all()
    assert np.max(np.abs(exact.values["u"] - radau.values["u"])) <= 1e-10 * np.abs(radau.values["u"]).max()


def test_a_steady_problem_is_solved_in_one_basis_as_the_sparse_lu_solves_it(monkeypatch):
    from pgdcli.checks import reference_pde
    from pgdcli.checks.reference import solve_reference_pde
    from pgdcli.checks.reference_pde_modal import steady_modal_states

    problem = pgdcli.parse_spec(STEADY)
    P = _samples(problem, 6, 3)
    model = PdeModel(problem, {"x": 16, "y": 20})
    split = steady_modal_states(model, P, 6, np.zeros(1))
    assert split is not None and type(decompose(model, _operator_of(model, P)[0])) is KroneckerModes
    monkeypatch.setattr(reference_pde, "modal_reference", lambda *a: None)  # the sparse LU path
    lu = solve_reference_pde(problem, P, None, None, space_nodes={"x": 16, "y": 20})
    got = split.reshape(6, 16, 20)  # (S, q = 1, T = 1, n): the grid of each sample
    assert np.max(np.abs(got - lu.values["u"])) <= 1e-11 * np.abs(lu.values["u"]).max()


def _operator_of(model, P):
    system = PdeSystem(model, P, len(next(iter(P.values()))), 0)
    m = model.m
    A = system.matrix(0.0).toarray()
    return [A[i * m:(i + 1) * m, i * m:(i + 1) * m] for i in range(A.shape[0] // m)]

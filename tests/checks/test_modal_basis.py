"""The eigenbasis of the modal reference: a 2-D Kronecker sum split into its directions, else decomposed whole."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import spec_text

import pgdcli
from pgdcli.checks.collocation import PdeModel
from pgdcli.checks.collocation_system import PdeSystem
from pgdcli.checks.modal_basis import KroneckerModes, Modes, decompose

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

"""problems/rigid_body10.yaml (the 10-D rigid body) states the Kirchhoff equations.

Its build is tested in tests/algorithms/test_cross_march.py; here the compiled right-hand side of
the march at t = 0, at random nodes of the 9-D parameter grid, is held to the equations
written out by hand with the spec's constants and the moments of inertia of the node.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

import pgdcli
from pgdcli.algorithms.march import compile_system, evaluate_rhs

SPEC = Path(__file__).resolve().parents[2] / "problems" / "rigid_body10.yaml"
M = np.array([0.2, 0.5, 0.8])
J = np.array([0.1, 0.2, 0.3])
MASS, FG3 = 1.0, -0.5


def kirchhoff(u: np.ndarray, w: np.ndarray, inertia: np.ndarray) -> np.ndarray:
    """(m E + M) u' = ((m E + M) u) x w + f_g;  (J + I) w' = ((J + I) w) x w + (M u) x u."""
    mu = MASS + M
    jj = J + inertia
    du = (np.cross(mu * u, w) + np.array([0.0, 0.0, FG3])) / mu
    dw = (np.cross(jj * w, w) + np.cross(M * u, u)) / jj
    return np.concatenate([du, dw])


def test_rigid_body10_right_hand_side_is_the_kirchhoff_equations():
    problem = pgdcli.load_spec(SPEC)
    assert [c.name for c in problem.coordinates] == ["t", "u10", "u20", "u30", "w10", "w20", "w30", "I1", "I2", "I3"]
    system = compile_system(problem)
    rhs = evaluate_rhs(system, 0.0, system.initial, 1e-14, 400)
    rng = np.random.default_rng(5)
    nodes = [system.bases[p].nodes for p in system.params]
    for _ in range(40):
        idx = [int(rng.integers(0, n.size)) for n in nodes]
        x = np.array([n[i] for n, i in zip(nodes, idx)])
        rows = [np.eye(n.size)[[i]] for n, i in zip(nodes, idx)]
        ours = np.array([float(f.evaluate(rows)[0]) for f in rhs])
        np.testing.assert_allclose(ours, kirchhoff(x[:3], x[3:6], x[6:9]), rtol=1e-12, atol=1e-12)

"""The PDE march building block (pgdcli.algorithms.pde_march) against the independent nonlinear
method-of-lines reference; not yet wired into pgd solve (fisher/burgers stay refused there)."""

import numpy as np
import pytest

from pgdcli.algorithms.pde_march import compile_pde_system, march_pde
from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_pde
from pgdcli.discretization.basis import make_basis
from pgdcli.errors import SolverError
from pgdcli.problem.spec import parse_spec

BURGERS_MILD = open("problems/burgers.yaml").read().replace("[0.01, 0.1]", "[0.05, 0.1]")


def _values(train, bases, x, nu):
    """The march's train (x, nu) at paired samples nu (S,) and points x (P,): (S, P)."""
    left = np.einsum("ij,ajb->ib", bases[0].interpolation_matrix(x), train.cores[0])
    right = np.einsum("sj,ajb->sa", bases[1].interpolation_matrix(nu), train.cores[1])
    return right @ left.T


@pytest.mark.slow
def test_burgers_march_against_reference():
    problem = parse_spec(BURGERS_MILD, source="burgers_mild.yaml")
    nodes = {"x": 49, "nu": 9}
    system = compile_pde_system(problem, nodes)
    times = np.array([0.1, 0.25, 0.5])
    result = march_pde(system, 1e-6, times)
    rng = np.random.default_rng(11)
    nu, x = rng.uniform(0.05, 0.1, 4), rng.uniform(0, 1, 30)  # 4 x 3 x 30 = 360 points
    ref = solve_reference_nonlinear_pde(problem, {"nu": nu}, times, x)
    bases = [make_basis("chebyshev", (0, 1), 49), make_basis("chebyshev", (0.05, 0.1), 9)]
    error = max(np.abs(_values(s, bases, x, nu) - ref.values["u"][:, k]).max() for k, s in enumerate(result.states))
    assert ref.error_estimate < 1e-9
    assert error < 1e-6  # the tolerance asked of the march (measured: 8e-8)


def test_refuses_two_unknowns():
    text = """
coordinates:
  t: {domain: [0, 1]}
  x: {domain: [0, 1]}
unknowns:
  u: {initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}
  v: {initial: "sin(pi*x)", boundary: {x: {low: 0, high: 0}}}
equations:
  - "der(u) = 0.1*der(u, x, 2) - u*v"
  - "der(v) = 0.1*der(v, x, 2) - u*v"
"""
    with pytest.raises(SolverError, match="PDE march takes one unknown"):
        compile_pde_system(parse_spec(text, source="two.yaml"), {"x": 17})

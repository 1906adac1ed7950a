"""The exponential PDE march (pgdcli.algorithms.pde_march, pde_phi, pde_system, pde_operators, pde_train)
against independent references: the phi-functions against expm of an augmented matrix and their series, the
march against the nonlinear method-of-lines reference (pgdcli.checks.reference_pde_nonlinear) and exact
solutions (manufactured ones for systems and two space coordinates: tests/manufactured_rd.py)."""

import math

import numpy as np
import pytest
from threadpoolctl import threadpool_limits

from pgdcli.algorithms.pde_march import compile_pde_system, march_pde
from pgdcli.algorithms.pde_phi import Eigen, phi_matrices, phi_scalars
from pgdcli.checks.reference_pde_nonlinear import solve_reference_nonlinear_pde
from pgdcli.discretization.basis import make_basis
from pgdcli.problem.spec import parse_spec

import manufactured_rd

BURGERS_MILD = open("problems/burgers.yaml").read().replace("[0.01, 0.1]", "[0.05, 0.1]")


def test_phi_scalars_against_their_series_and_closed_form():
    z = np.array([-1e-9, -0.3, 0.7, -0.999, -1.001, -5.0, -300.0])
    phi = phi_scalars(z, 3).real
    for zz, col in zip(z, phi.T):
        if abs(zz) < 1:  # the series sum_j z^j / (j + k)!
            exact = [sum(zz ** j / math.factorial(j + k) for j in range(40)) for k in range(4)]
        else:
            e = math.exp(zz)
            exact = [e, (e - 1) / zz, (e - 1 - zz) / zz ** 2, (e - 1 - zz - zz ** 2 / 2) / zz ** 3]
        assert np.allclose(col, exact, rtol=1e-13, atol=1e-300)


def test_phi_matrices_of_the_eliminated_laplacian_match_expm():
    problem = parse_spec(BURGERS_MILD, source="b.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 33), "nu": make_basis("chebyshev", (0.05, 0.1), 3)}
    system = compile_pde_system(problem, bases)
    A = system.species[0].eigen[0].A
    eigen = Eigen(A)
    scales = np.array([1e-4, 0.03])
    got = eigen.functions(scales, 3)
    for j, s in enumerate(scales):
        want = phi_matrices(s * A, 3)
        assert np.abs(got[:, j] - want).max() <= 1e-12 * max(1.0, np.abs(want).max())


def _values(train, bases, modes, x, samples):
    """The march's train at points x (P,) and paired parameter samples (S,): (S, P)."""
    left = np.einsum("pi,aib->pb", bases[modes[0]].interpolation_matrix(x), train.cores[0])
    right = None
    for m, core in zip(modes[1:], train.cores[1:]):
        piece = np.einsum("sj,ajb->sab", bases[m].interpolation_matrix(samples[m]), core)
        right = piece if right is None else np.einsum("sab,sbc->sac", right, piece)
    return np.einsum("pa,sab->sp", left, right)


@pytest.mark.parametrize("scheme, dense", [("etdrk4", True), ("etdrk4", False), ("lawson4", True)])
def test_burgers_march_against_reference(scheme, dense):
    """On the whole grid (an array) and as a tensor train."""
    problem = parse_spec(BURGERS_MILD, source="burgers_mild.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 33), "nu": make_basis("chebyshev", (0.05, 0.1), 9)}
    system = compile_pde_system(problem, bases)
    times = np.array([0.1, 0.25, 0.5])
    with threadpool_limits(1):
        result = march_pde(system, 1e-6, times, scheme=scheme, dense=dense)
    rng = np.random.default_rng(11)
    samples = {"nu": rng.uniform(0.05, 0.1, 4)}
    x = rng.uniform(0, 1, 30)  # 4 x 3 x 30 = 360 random points
    ref = solve_reference_nonlinear_pde(problem, samples, times, x)
    error = max(np.abs(_values(s[0], bases, system.modes, x, samples) - ref.values["u"][:, k]).max()
                for k, s in enumerate(result.states))
    assert ref.error_estimate < 1e-9
    assert error < 1e-6  # measured: ETDRK4 1.3e-8 in 37 steps, Lawson 8e-8 in 46 (x 49)


def test_etdrk4_is_fourth_order_on_the_logistic_reaction():
    """A uniform start with gradient conditions: u(t) is the logistic solution, whatever the diffusion.
    With fixed steps (no error control), halving them cuts the error about 32-fold: ETDRK4 is of order 4,
    and the accepted state is the step-doubling (Richardson) extrapolation, of order 5 (measured 40x)."""
    text = """
coordinates:
  t: {domain: [0, 2]}
  x: {domain: [0, 1]}
  r: {domain: [1, 3]}
unknowns:
  u: {initial: "0.2", boundary: {x: {low: {gradient: 0}, high: {gradient: 0}}}}
equations:
  - "der(u) = 0.1*der(u, x, 2) + r*u*(1 - u)"
"""
    problem = parse_spec(text, source="logistic.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 9), "r": make_basis("chebyshev", (1, 3), 5)}
    system = compile_pde_system(problem, bases)
    r = bases["r"].nodes
    exact = 0.2 * np.exp(2 * r) / (0.8 + 0.2 * np.exp(2 * r))
    errors = []
    for n in (8, 16):
        with threadpool_limits(1):
            out = march_pde(system, 1e-6, np.array([2.0]), fixed_step=2.0 / n)
        errors.append(np.abs(out.states[-1][0].full() - exact[None, :]).max())
    assert 24 < errors[0] / errors[1] < 56, errors


def test_an_under_resolved_front_stops_the_march():
    """Burgers at nu = 0.01 on 17 x nodes: the steepening front's Chebyshev tail passes 10x the tolerance
    and the march stops (pgdcli.adapt then adds x nodes) instead of shrinking its steps."""
    from pgdcli.algorithms.pde_march import UnderResolved

    problem = parse_spec(open("problems/burgers.yaml").read(), source="burgers.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 17), "nu": make_basis("chebyshev", (0.01, 0.1), 5)}
    system = compile_pde_system(problem, bases)
    with threadpool_limits(1), pytest.raises(UnderResolved) as caught:
        march_pde(system, 1e-6, np.array([0.5]), tail_limit=True)
    assert caught.value.coordinate == "x" and caught.value.tail > 1e-5 and caught.value.time < 0.5


def _at(train, bases, modes, points):
    """A state's train at scattered points (name -> (P,))."""
    return train.evaluate([bases[m].interpolation_matrix(points[m]) for m in modes])


@pytest.mark.parametrize("dense", [True, False])
def test_two_space_coordinates_against_an_exact_solution(dense):
    """Allen-Cahn with a source in (x, y): values depending on y at x = 1, gradients at y = 0 and 1, a
    source depending on time, the diffusion a parameter; the whole grid and tensor trains."""
    problem = parse_spec(manufactured_rd.PLANE, source="plane.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 17), "y": make_basis("chebyshev", (0, 1), 17),
             "c": make_basis("chebyshev", (0.05, 0.1), 3)}
    system = compile_pde_system(problem, bases)
    times = np.array([0.3, 1.0])
    with threadpool_limits(1):
        result = march_pde(system, 1e-6, times, dense=dense)
    rng = np.random.default_rng(2)
    points = {"x": rng.uniform(0, 1, 300), "y": rng.uniform(0, 1, 300), "c": rng.choice(bases["c"].nodes, 300)}
    for k, t in enumerate(times):
        exact = manufactured_rd.plane_exact(t, points["x"], points["y"])
        assert np.abs(_at(result.states[k][0], bases, system.modes, points) - exact).max() < 1e-8  # measured 1e-9


@pytest.mark.parametrize("dense", [True, False])
def test_two_species_against_an_exact_solution(dense):
    """A pair coupled by u*v, u*v/(1 + u) (by cross on trains) and v*der(u, x); gradient data for u, values
    a and a + 1 for v, v's diffusion 0.05*a."""
    problem = parse_spec(manufactured_rd.PAIR, source="pair.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 33), "a": make_basis("chebyshev", (0.5, 1.5), 3)}
    system = compile_pde_system(problem, bases)
    times = np.array([0.3, 1.0])
    with threadpool_limits(1):
        result = march_pde(system, 1e-7, times, dense=dense)
    rng = np.random.default_rng(3)
    points = {"x": rng.uniform(0, 1, 300), "a": rng.choice(bases["a"].nodes, 300)}
    for k, t in enumerate(times):
        exact = manufactured_rd.pair_exact(t, points["x"], points["a"])
        for s in range(2):  # measured 1.0e-8 (u), 1.1e-7 (v)
            assert np.abs(_at(result.states[k][s], bases, system.modes, points) - exact[s]).max() < 3e-7


def test_two_unequal_gradient_conditions_against_an_exact_solution():
    """u_x = 1 at x = 0 and 0 at x = 1: the lift is quadratic and its diffusion a source of the march."""
    text = """
coordinates:
  t: {domain: [0, 1]}
  x: {domain: [0, 1]}
  c: {domain: [0.1, 0.3]}
unknowns:
  u: {initial: "x - x**2/2 + cos(pi*x)", boundary: {x: {low: {gradient: 1}, high: {gradient: 0}}}}
equations:
  - "der(u) = c*der(u, x, 2) - u**3 - exp(-t)*cos(pi*x) + c*(1 + pi**2*exp(-t)*cos(pi*x))
     + (x - x**2/2 + exp(-t)*cos(pi*x))**3"
"""
    problem = parse_spec(text, source="fluxes.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 25), "c": make_basis("chebyshev", (0.1, 0.3), 3)}
    system = compile_pde_system(problem, bases)
    with threadpool_limits(1):
        result = march_pde(system, 1e-8, np.array([1.0]))
    x = np.linspace(0, 1, 101)
    for j, c in enumerate(bases["c"].nodes):
        got = _at(result.states[0][0], bases, system.modes, {"x": x, "c": np.full(x.size, c)})
        assert np.abs(got - (x - x ** 2 / 2 + np.exp(-1.0) * np.cos(np.pi * x))).max() < 1e-8


def test_an_error_estimate_that_does_not_fall_with_the_step_is_the_roundings_noise():
    from pgdcli.algorithms.pde_march import _noise_limited

    anchor, noise = _noise_limited(None, 1.0, 4.0)
    assert anchor == (1.0, 4.0) and not noise
    assert _noise_limited(anchor, 0.8, 4.0) == (anchor, False)  # not 30% shorter yet: no verdict
    # a truncation error: err/allowed falls like h^4, 0.5^4 = 1/16
    assert _noise_limited(anchor, 0.5, 4.0 / 16) == ((0.5, 0.25), False)
    # the same ratio at half the step: noise
    assert _noise_limited(anchor, 0.5, 3.0) == ((0.5, 3.0), True)
    # far below what is allowed: the step is accepted anyway, never called noise
    assert _noise_limited((1.0, 0.09), 0.5, 0.09)[1] is False
    assert _noise_limited(anchor, 2.0, 9.0) == ((2.0, 9.0), False)  # a longer step moves the anchor


def test_train_roundings_tighten_tenfold_at_most_three_times():
    from pgdcli.algorithms.pde_train import MAX_TIGHTENINGS, OPERATION_SHARE, TrainOperators

    problem = parse_spec(manufactured_rd.PLANE, source="plane.yaml")
    bases = {"x": make_basis("chebyshev", (0, 1), 9), "y": make_basis("chebyshev", (0, 1), 9),
             "c": make_basis("chebyshev", (0.05, 0.1), 3)}
    ops = TrainOperators(compile_pde_system(problem, bases))
    assert ops.share == OPERATION_SHARE
    assert [ops.tighten() for _ in range(MAX_TIGHTENINGS + 1)] == [True] * MAX_TIGHTENINGS + [False]
    assert ops.share == pytest.approx(OPERATION_SHARE * 0.1 ** MAX_TIGHTENINGS)

"""The linearly implicit stepper (pgdcli.algorithms.rosenbrock), its Jacobians (pgdcli.algorithms.jacobian,
pgdcli.problem.derivative) and the switch to it on stiff problems (pgdcli.algorithms.stiffness).

The stepper against exact solutions of a stiff linear system and scipy's Radau; the exact Jacobians
against finite differences of the right-hand side; the march's automatic switch and its report.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli
from pgdcli import parse_spec
from pgdcli.algorithms.grid_steps import ArraySpace, GridRhs, advance, initial_values
from pgdcli.algorithms.jacobian import jacobian_at
from pgdcli.algorithms.march import compile_system
from pgdcli.algorithms.rosenbrock import Rodas4

# u' = -a (u - cos t) - sin t, w' = -b (w - sin t) + cos t: u = cos t + (u0 - 1) e^(-a t),
# w = sin t + w0 e^(-b t); decay rates a, b up to 1e4 (stiff), time-dependent forcing (df/dt)
STIFF_LINEAR = """
name: stiff_linear
coordinates:
  t: {domain: [0, 5], nodes: 6}
  a: {domain: [100, 10000], nodes: 5}
  u0: {domain: [0, 2], nodes: 3}
unknowns:
  u: {initial: u0}
  w: {initial: 0.5}
equations:
  - "der(u) = -a*(u - cos(t)) - sin(t)"
  - "der(w) = -2000*(w - sin(t)) + cos(t)"
solver:
  method: march
  tolerance: 1e-7
"""


def _exact(t, a, u0):
    return np.cos(t) + (u0 - 1.0) * np.exp(-a * t), np.sin(t) + 0.5 * np.exp(-2000.0 * t)


def _stiff_system():
    problem = parse_spec(STIFF_LINEAR, source="stiff_linear.yaml", allow_nonlinear=True)
    system = compile_system(problem, 1e-7)
    assert system.params == ["a", "u0"]
    a, u0 = np.meshgrid(*[system.bases[p].nodes for p in system.params], indexing="ij")
    return system, a.reshape(-1), u0.reshape(-1)


def test_rodas4_march_meets_the_exact_solution_of_a_stiff_linear_system():
    """The adaptive march (per-step error control) to 1e-7 on decay rates up to 1e4, against the exact
    solution and scipy's Radau at rtol 1e-10, at every time node."""
    system, a, u0 = _stiff_system()
    states = []
    schedule = advance(system, GridRhs(system), initial_values(system), 1e-7, states.extend, stepper=Rodas4())
    times = np.array(schedule.times)
    values = np.array(states)  # (times, 2, P)
    u, w = _exact(times[:, None], a[None, :], u0[None, :])
    assert np.abs(values[:, 0] - u).max() <= 1e-7 and np.abs(values[:, 1] - w).max() <= 1e-7
    # DOP853's stability alone would need 5 * 1e4 / 6 steps (h a <= 6); RODAS4's forced stiff components
    # lose order (the order reduction of Rosenbrock methods), so its steps are set by accuracy well below that
    assert len(schedule.steps) < 0.5 * 5 * 1e4 / 6
    k = int(np.argmax(a))
    ref = solve_ivp(lambda t, y: [-a[k] * (y[0] - np.cos(t)) - np.sin(t), -2000 * (y[1] - np.sin(t)) + np.cos(t)],
                    (0, 5), [u0[k], 0.5], method="Radau", rtol=1e-10, atol=1e-12, t_eval=times)
    assert np.abs(ref.y[0] - u[:, k]).max() < 1e-8  # the reference agrees with the exact solution
    assert np.abs(values[:, 0, k] - ref.y[0]).max() <= 1e-7 and np.abs(values[:, 1, k] - ref.y[1]).max() <= 1e-7


def test_rodas4_step_is_of_order_four_and_its_dense_output_of_order_three():
    """Fixed steps resolving the slowest mode (a = 100, h a <= 0.125) over [0, 0.05]: halving the step divides
    the error at the end by about 16, and inside the steps (dense output) by at least 8."""
    system, a, u0 = _stiff_system()
    stepper = Rodas4()
    errors, dense_errors = [], []
    for n in (20, 40, 80):
        rhs, y = GridRhs(system), initial_values(system)
        space = ArraySpace(rhs, y, stepper.slots)
        y, t, h, worst = space.start(y), 0.0, 0.05 / n, 0.0
        f = rhs(t, y)
        for _ in range(n):
            trial = stepper.step(space, t, y, f, h)
            inside = stepper.dense_output(space, t, h, y, trial, [t + 0.37 * h, t + h], t + h)[0]
            u, w = _exact(t + 0.37 * h, a, u0)
            worst = max(worst, np.abs(inside[0] - u)[a == 100].max())
            y, f = space.accept(trial)
            t += h
        u, w = _exact(t, a, u0)
        errors.append(np.abs(y[0] - u)[a == 100].max())
        dense_errors.append(worst)
    assert all(12 < errors[i] / errors[i + 1] < 20 for i in range(2)), errors
    assert all(dense_errors[i] / dense_errors[i + 1] > 7 for i in range(2)), dense_errors


def test_rodas4_is_l_stable_one_long_step_damps_fast_modes():
    """One step of length 1 on u' = -a u, v' = -a (v - 1) with h a from 1e3 to 1e6: the fast modes are
    damped as R(z) = O(1/z) (z = -h a), as L-stability says, not left near 1 in size (the trapezoidal rule's
    R(-inf) = -1)."""
    text = """
coordinates:
  t: {domain: [0, 1], nodes: 4}
  a: {domain: [1000, 1000000], nodes: 6}
unknowns:
  u: {initial: 1}
  v: {initial: 0}
equations:
  - "der(u) = -a*u"
  - "der(v) = -a*(v - 1)"
"""
    system = compile_system(parse_spec(text, source="decay.yaml", allow_nonlinear=True), 1e-6)
    stepper = Rodas4()
    rhs, y = GridRhs(system), initial_values(system)
    space = ArraySpace(rhs, y, stepper.slots)
    y = space.start(y)
    trial = stepper.step(space, 0.0, y, rhs(0.0, y), 1.0)
    a = system.bases["a"].nodes
    assert np.all(np.abs(trial.y_new[0]) <= 10.0 / a) and np.all(np.abs(trial.y_new[1] - 1) <= 10.0 / a)


# polynomial terms, general terms (sin, sqrt, exp, abs, tanh, a power with a coordinate exponent) and a
# der() coefficient, so every rule of the symbolic differentiation is used
GENERAL = """
name: general_terms
coordinates:
  t: {domain: [0, 1], nodes: 4}
  a: {domain: [0.5, 1.5], nodes: 4}
  b: {domain: [1, 2], nodes: 3}
unknowns:
  x: {initial: a}
  y: {initial: b}
  z: {initial: 0.3}
equations:
  - "der(x) = -a*x*y + sin(x)*y**2 + t*z"
  - "b*der(y) = sqrt(1 + x**2)*y - exp(-y)/(1 + x**2) + abs(y)*y - tanh(z*x)"
  - "der(z) = (1 + x**2)**(a/2) - log(2 + y**2)*z**3 + cos(t)*x*z"
"""


@pytest.mark.parametrize("points", [False, True])
def test_jacobian_of_polynomial_and_general_terms_matches_finite_differences(points):
    problem = parse_spec(GENERAL, source="general.yaml", allow_nonlinear=True)
    system = compile_system(problem, 1e-8)
    rng = np.random.default_rng(3)
    P = int(np.prod(system.shape))
    indices = np.stack([rng.integers(0, n, 7) for n in system.shape], axis=1) if points else None
    rhs = GridRhs(system, indices)
    nodes = 7 if points else P
    Y = rng.uniform(-1.5, 1.5, (3, nodes))
    t = 0.37
    J = jacobian_at(rhs, t, Y)  # (nodes, 3, 3)
    for j in range(3):
        step = 1e-6 * np.maximum(1.0, np.abs(Y[j]))
        up, down = Y.copy(), Y.copy()
        up[j] += step
        down[j] -= step
        column = (rhs(t, up) - rhs(t, down)) / (2 * step)  # (3, nodes)
        np.testing.assert_allclose(J[:, :, j], column.T, rtol=1e-6, atol=1e-7)


# a nonlinear relaxation with rates up to 5000: stiff for DOP853 over t in [0, 5]
RELAXATION = """
name: stiff_relaxation
coordinates:
  t: {domain: [0, 5]}
  k: {domain: [1000, 5000]}
unknowns:
  u: {initial: 2}
equations:
  - "der(u) = -k*(u - cos(t)) - u**3 + cos(t)**3"
solver:
  tolerance: 1e-6
"""


def test_auto_integrator_switches_to_rodas4_on_a_stiff_problem_and_says_why():
    result = pgdcli.solve(parse_spec(RELAXATION, source="relaxation.yaml", allow_nonlinear=True))
    assert result.converged and result.accurate
    report = result.codebook.report
    assert report["integrator"] == "rodas4"
    assert report["integrator_reason"].startswith("solver.integrator: auto, stiff: from t = ")
    assert "held at its stability limit" in report["integrator_reason"]
    assert "marched again with RODAS4" in report["integrator_reason"]
    assert "with RODAS4 (stiff)" in result.message and "Radau" in report["check_method"]
    cb = result.codebook
    t, k = 3.3, 3210.0
    exact = solve_ivp(lambda s, u: -k * (u - np.cos(s)) - u ** 3 + np.cos(s) ** 3, (0, t), [2.0], method="Radau",
                      rtol=1e-11, atol=1e-13).y[0, -1]
    assert abs(float(cb(t=t, k=k)["u"]) - exact) <= 1e-6


def test_auto_switches_when_a_driven_stiff_mode_holds_the_steps_below_the_stability_limit():
    """Rates 100 to 1000 hold DOP853 near h x rate = 1, a sixth of its stability limit, by its error
    estimate (8700 steps to t = 10): the watch switches to RODAS4 all the same."""
    text = RELAXATION.replace("k: {domain: [1000, 5000]}", "k: {domain: [100, 1000]}").replace(
        "[0, 5]", "[0, 10]")
    result = pgdcli.solve(parse_spec(text, source="relaxation.yaml", allow_nonlinear=True))
    assert result.accurate and result.codebook.report["integrator"] == "rodas4"
    assert "the explicit DOP853 was held" in result.codebook.report["integrator_reason"]
    rng = np.random.default_rng(3)
    for t, k in zip(rng.uniform(0, 10, 6), rng.uniform(100, 1000, 6)):
        exact = solve_ivp(lambda s, u: -k * (u - np.cos(s)) - u ** 3 + np.cos(s) ** 3, (0, t), [2.0],
                          method="Radau", rtol=1e-11, atol=1e-13).y[0, -1]
        assert abs(float(result.codebook(t=t, k=k)["u"]) - exact) <= 1e-6


def test_explicit_integrator_stays_explicit_and_names_the_stiff_one():
    text = RELAXATION.replace("tolerance: 1e-6", "tolerance: 1e-6\n  integrator: dop853\n  max_steps: 300")
    result = pgdcli.solve(parse_spec(text, source="relaxation.yaml", allow_nonlinear=True))
    assert not result.converged
    assert "stability limit of the explicit DOP853" in result.message
    assert "solver.integrator: rodas4 or auto" in result.message


def test_a_non_stiff_problem_keeps_dop853_under_auto():
    text = RELAXATION.replace("k: {domain: [1000, 5000]}", "k: {domain: [0.5, 2]}")
    result = pgdcli.solve(parse_spec(text, source="relaxation.yaml", allow_nonlinear=True))
    assert result.converged
    assert result.codebook.report["integrator"] == "dop853"
    assert result.codebook.report["integrator_reason"] == "solver.integrator: auto, not stiff"

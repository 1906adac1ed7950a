"""The steppers of the time march (pgdcli.algorithms.runge_kutta, .dop853, .bogacki_shampine, .steppers).

Each registered tableau against its order conditions and against scipy's own solver step by step
(stages, new state, dense output, error estimate); the marches with ``solver.integrator: bs32``
against scipy's solve_ivp (DOP853, rtol = atol = 1e-12) at random points off the grid.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import DOP853, RK23, solve_ivp

import pgdcli
from pgdcli import parse_spec
from pgdcli.algorithms.grid_steps import ArraySpace, GridRhs, initial_values
from pgdcli.algorithms.march import compile_system
from pgdcli.algorithms.stepping import Stepper
from pgdcli.algorithms.runge_kutta import ExplicitRungeKutta
from pgdcli.algorithms.steppers import CHOICES, METHODS, stepper
from pgdcli.errors import SpecError
from pgdcli.problem.spec_options import INTEGRATORS

# predator-prey with a prey's rate a, a predator's death rate b and the initial prey x0 as coordinates
PREDATOR_PREY = """
name: predator_prey
coordinates:
  t: {domain: [0, 2]}
  a: {domain: [0.8, 1.2]}
  b: {domain: [0.6, 1.0]}
  x0: {domain: [0.5, 1.5]}
unknowns:
  x: {initial: x0}
  y: {initial: 0.5}
equations:
  - "der(x) = a*x - x*y"
  - "der(y) = x*y - b*y"
solver:
  tolerance: 1e-5
"""


def predator_prey(a, b):
    return lambda t, u: [a * u[0] - u[0] * u[1], u[0] * u[1] - b * u[1]]


def test_registry_names_are_the_spec_choices():
    assert CHOICES == INTEGRATORS
    for key, method in METHODS.items():
        assert method.name == key and issubclass(method, Stepper)
    assert stepper().name == "dop853" and not stepper().detect_stiffness
    assert stepper("auto").name == "dop853" and stepper("auto").detect_stiffness
    with pytest.raises(KeyError, match="expected one of auto, dop853, bs32, rodas4"):
        stepper("rk4")


@pytest.mark.parametrize("name", [n for n, m in METHODS.items() if issubclass(m, ExplicitRungeKutta)])
def test_tableau_meets_the_order_conditions_to_three(name):
    method = METHODS[name]()
    A, B, C = method.A, method.B, method.C
    np.testing.assert_allclose(A.sum(axis=1), C, atol=1e-14)
    assert np.allclose(np.triu(A), 0.0)  # explicit
    np.testing.assert_allclose([B.sum(), B @ C, B @ C ** 2, B @ A @ C], [1, 1 / 2, 1 / 3, 1 / 6], atol=1e-14)
    for weights in method.error_weights():  # a difference of two solutions: exact on constants
        assert weights.shape == (method.n_stages + 1,)
        assert abs(weights.sum()) <= 1e-14


@pytest.mark.parametrize("name", [n for n, m in METHODS.items() if issubclass(m, ExplicitRungeKutta)])
def test_dense_output_starts_at_y_and_ends_at_the_new_state(name):
    method = METHODS[name]()
    rng = np.random.default_rng(3)
    h = 0.3
    y, K = rng.standard_normal(4), rng.standard_normal((method.slots, 4))
    y_new = y + h * method.B @ K[:method.n_stages]
    stack = np.vstack([y, y_new, K])
    np.testing.assert_allclose(method.dense_weights(0.0, h) @ stack, y, atol=1e-14)
    np.testing.assert_allclose(method.dense_weights(1.0, h) @ stack, y_new, atol=1e-14)


def test_bs32_is_scipys_rk23():
    method = METHODS["bs32"]()
    for key in ("A", "B", "C", "E", "P"):
        np.testing.assert_allclose(getattr(method, key), getattr(RK23, key), rtol=1e-15, atol=1e-16, err_msg=key)
    assert (method.order, method.error_estimator_order, method.n_stages) == (RK23.order, RK23.error_estimator_order,
                                                                            RK23.n_stages)


def _rms(values: np.ndarray) -> np.ndarray:
    return np.sqrt(np.mean(values ** 2, axis=1))


@pytest.mark.parametrize("name, solver_class", [("bs32", RK23), ("dop853", DOP853)])
def test_steps_are_scipys_step_by_step(name, solver_class):
    """The stepper on the grid's array takes scipy's steps: the same stages, new state, dense output and
    (in the root-mean-square over the nodes, per unknown) the same embedded error."""
    text = PREDATOR_PREY.replace("t: {domain: [0, 2]}", "t: {domain: [0, 2], nodes: 8}").replace("]}", "], nodes: 5}")
    system = compile_system(parse_spec(text, source="pp.yaml"), 1e-8)
    rhs = GridRhs(system)
    y0 = initial_values(system)
    shape = y0.shape
    method = stepper(name)
    space = ArraySpace(rhs, y0, method.slots)
    scipy_solver = solver_class(lambda t, u: rhs(t, u.reshape(shape)).reshape(-1), 0.0, y0.reshape(-1), 2.0,
                                rtol=1e-8, atol=1e-10)
    for _ in range(6):
        t, y, f = scipy_solver.t, scipy_solver.y.reshape(shape).copy(), scipy_solver.f.reshape(shape).copy()
        scipy_solver.step()
        h = scipy_solver.t - t
        trial = method.step(space, t, space.start(y), f, h)
        scale = np.max(np.abs(y))
        np.testing.assert_allclose(trial.y_new, scipy_solver.y.reshape(shape), rtol=0, atol=1e-14 * scale)
        stages = scipy_solver.K[:method.n_stages + 1].reshape((method.n_stages + 1,) + shape)
        np.testing.assert_allclose(trial.K[:method.n_stages + 1], stages, rtol=0, atol=1e-13 * scale)
        if name == "bs32":  # scipy's error vector h K^T E, in the march's norm
            expected = _rms(h * np.tensordot(RK23.E, stages, axes=1))
            np.testing.assert_allclose(trial.local, expected, rtol=1e-12, atol=1e-18)
        dense = scipy_solver.dense_output()
        outs = [t + 0.3 * h, t + 0.8 * h, scipy_solver.t]
        got = method.dense_output(space, t, h, space.start(y), trial, outs, scipy_solver.t)
        for tn, state in zip(outs, got):
            np.testing.assert_allclose(state, dense(tn).reshape(shape), rtol=0, atol=1e-13 * scale)
        space.accept(trial)


def test_dop853_error_is_scipys_formula():
    """DOP853's two embedded estimates combined as scipy's DOP853._estimate_error_norm does."""
    method = stepper("dop853")
    e5, e3, h = np.array([1e-6, 0.0, 3e-7]), np.array([2e-5, 0.0, 1e-9]), 0.05
    expected = [h * a * a / np.sqrt(a * a + 0.01 * b * b) if a or b else 0.0 for a, b in zip(e5, e3)]
    np.testing.assert_allclose(method.local_error(h, [e5, e3]), expected, rtol=1e-15)


def _solved(march: str, integrator: str, tolerance: float):
    text = PREDATOR_PREY.replace("tolerance: 1e-5", f"tolerance: {tolerance}\n  march: {march}\n  integrator: {integrator}")
    return pgdcli.solve(parse_spec(text, source=f"pp_{march}_{integrator}.yaml"))


@pytest.mark.slow
@pytest.mark.parametrize("march, tolerance", [("grid", 1e-5), ("cross", 1e-5), ("train", 1e-4)])
def test_bs32_march_against_solve_ivp_off_the_grid(march, tolerance):
    result = _solved(march, "bs32", tolerance)
    assert result.converged, result.message
    report = result.codebook.report
    assert report["march"] == march
    # the low-order pair takes many more steps than DOP853 on the same problem: it is the one stepping
    assert report["steps"] > 3 * _solved(march, "dop853", tolerance).codebook.report["steps"]
    rng = np.random.default_rng(11)
    times = np.linspace(0.0, 2.0, 21)
    worst = 0.0
    for _ in range(20):
        a, b, x0 = rng.uniform([0.8, 0.6, 0.5], [1.2, 1.0, 1.5])
        ref = solve_ivp(predator_prey(a, b), (0.0, 2.0), [x0, 0.5], method="DOP853", rtol=1e-12, atol=1e-12,
                        t_eval=times)
        got = result.codebook(t=times, a=a, b=b, x0=x0)
        worst = max(worst, *(float(np.max(np.abs(np.asarray(got[u]).reshape(-1) - ref.y[i])))
                             for i, u in enumerate(("x", "y"))))
    assert worst <= tolerance


def test_unknown_integrator_is_a_one_line_spec_error():
    text = PREDATOR_PREY.replace("tolerance: 1e-5", "tolerance: 1e-5\n  integrator: rk4")
    with pytest.raises(SpecError) as info:
        parse_spec(text, source="pp.yaml")
    assert str(info.value) == "pp.yaml: solver.integrator: expected one of auto, dop853, bs32, rodas4, got 'rk4'"


def test_a_stepper_needing_a_jacobian_is_refused_on_tensor_trains():
    """A linearly implicit stepper names the Jacobian in ``requires``; the train march has none to give."""
    from pgdcli.algorithms.dop853 import Dop853
    from pgdcli.algorithms.march import march
    from pgdcli.errors import SolverError

    class NeedsJacobian(Dop853):
        name = "needs_jacobian"
        requires = ("jacobian",)

    text = PREDATOR_PREY.replace("t: {domain: [0, 2]}", "t: {domain: [0, 2], nodes: 8}").replace("]}", "], nodes: 5}")
    system = compile_system(parse_spec(text, source="pp.yaml"), 1e-6)
    with pytest.raises(SolverError, match="solver.integrator: 'needs_jacobian' needs the jacobian of the right-hand "
                                          "side, which the march on tensor trains does not provide"):
        march(system, 1e-6, stepper=NeedsJacobian())


def test_a_low_order_pair_out_of_steps_says_what_limits_it():
    text = PREDATOR_PREY.replace("t: {domain: [0, 2]}", "t: {domain: [0, 2], nodes: 8}").replace("]}", "], nodes: 5}")
    text = text.replace("tolerance: 1e-5", "tolerance: 1e-9\n  integrator: bs32\n  max_steps: 40")
    result = pgdcli.solve(parse_spec(text, source="pp.yaml"))
    assert not result.converged
    assert ("max_steps=40 reached (steps of" in result.message and "the Bogacki-Shampine 3(2) pair of order 3 needs "
            "steps this small for this tolerance" in result.message and "solver.integrator: dop853" in result.message)

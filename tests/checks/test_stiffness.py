"""The stiffness estimate that picks the ODE reference's method, and the error gate with the implicit reference."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

import pgdcli
from pgdcli.checks import check as checks
from pgdcli.checks.reference import solve_reference, solve_reference_vectorized
from pgdcli.checks.reference_system import CompiledSystem, reference_jacobian
from pgdcli.checks.sampling import check_sample, line_sample, nodes_and_midpoints
from pgdcli.checks.stiffness import decide_stiffness, estimate_stiffness
from pgdcli.codebook.codebook import Codebook, CPTensor

PROBLEMS = Path(__file__).resolve().parents[2] / "problems"

# an RC low-pass filter, fast time constant tau, driven by a sine, and a slow second stage
RC_FILTER = """
name: rc_filter
coordinates:
  t: {domain: [0, 20]}
  w: {domain: [0.5, 2]}
  tau: {domain: [0.001, 0.003]}
unknowns:
  v1: {initial: 1}
  v2: {initial: 0}
equations:
  - "tau*der(v1) = sin(w*t) - v1"
  - "der(v2) = 0.5*(v1 - v2)"
solver:
  tolerance: 1e-6
"""

# a decay chain a -> b -> c -> out with rates 1, k2 and k3 up to 1e3
DECAY_CHAIN = """
name: decay_chain
coordinates:
  t: {domain: [0, 10]}
  k2: {domain: [20, 40]}
  k3: {domain: [500, 1000]}
unknowns:
  a: {initial: 1}
  b: {initial: 0}
  c: {initial: 0}
equations:
  - "der(a) = -a"
  - "der(b) = a - k2*b"
  - "der(c) = k2*b - k3*c"
"""

LOTKA_VOLTERRA = """
name: lotka_volterra
coordinates:
  t: {domain: [0, 15]}
  alpha: {domain: [0.8, 1.2]}
  x0: {domain: [0.5, 2]}
unknowns:
  x: {initial: x0}
  y: {initial: 1}
equations:
  - "der(x) = alpha*x - x*y"
  - "der(y) = x*y - 0.5*y"
"""

# Robertson's kinetics as a user writes it, with the product rule of general terms (exp of a rate)
ROBERTSON_GENERAL = """
name: robertson_general
coordinates:
  t: {domain: [0, 40]}
  e: {domain: [0, 0.5]}
unknowns:
  y1: {initial: 1}
  y2: {initial: 0}
  y3: {initial: 0}
equations:
  - "der(y1) = -0.04*y1 + 1e4*exp(e)*y2*y3"
  - "der(y2) = 0.04*y1 - 1e4*exp(e)*y2*y3 - 3e7*y2**2"
  - "der(y3) = 3e7*y2**2"
"""


def _sample(problem, n: int = 12, seed: int = 0) -> tuple[dict, int]:
    """n random points of the parameter box and its two extreme corners."""
    rng = np.random.default_rng(seed)
    coords = problem.parameter_coordinates
    points = {c.name: np.concatenate([rng.uniform(*c.domain, n), c.domain]) for c in coords}
    return points, (n + 2 if coords else 1)


def _estimate(problem, method: str = "Radau"):
    """The estimate along states from an independent loose solve (rtol 1e-8) at 65 times."""
    points, S = _sample(problem)
    times = np.linspace(*problem.time_coordinate.domain, 65)
    ref = solve_reference(problem, points, times, method=method, rtol=1e-8, atol=1e-10)
    assert ref.success.all()
    return estimate_stiffness(problem, points, S, times, ref.values)


@pytest.mark.parametrize("spec", [RC_FILTER, DECAY_CHAIN, ROBERTSON_GENERAL, PROBLEMS / "robertson.yaml"],
                         ids=["rc_filter", "decay_chain", "robertson_general", "robertson"])
def test_estimate_finds_stiff_problems_stiff(spec):
    problem = pgdcli.load_spec(spec) if isinstance(spec, Path) else pgdcli.parse_spec(spec, source="stiff.yaml")
    estimate = _estimate(problem)
    assert estimate.stiff, estimate
    assert estimate.stability_steps > 8 * estimate.accuracy_steps
    assert estimate.text().startswith("stiff: an explicit method needs ~")


def test_estimate_finds_the_decay_rates_of_a_linear_system():
    """The decay chain's Jacobian is constant: its fastest decay rate is the largest k3 of the sample."""
    problem = pgdcli.parse_spec(DECAY_CHAIN, source="chain.yaml")
    points, _ = _sample(problem)
    assert _estimate(problem).decay_rate == pytest.approx(points["k3"].max(), rel=1e-12)


def _ode_problems() -> list[Path]:
    """The shipped problems without space coordinates, Robertson's kinetics (stiff) aside."""
    out = []
    for path in sorted(PROBLEMS.glob("*.yaml")):
        problem = pgdcli.load_spec(path)
        if problem.time and not any(c.role == "space" for c in problem.coordinates) and path.stem != "robertson":
            out.append(path)
    return out


@pytest.mark.parametrize("path", _ode_problems(), ids=lambda p: p.stem)
def test_estimate_finds_shipped_ode_problems_not_stiff(path):
    estimate = _estimate(pgdcli.load_spec(path), "DOP853")
    assert not estimate.stiff, estimate
    assert estimate.text().startswith("not stiff")


def test_estimate_finds_lotka_volterra_not_stiff():
    estimate = _estimate(pgdcli.parse_spec(LOTKA_VOLTERRA, source="lv.yaml"), "DOP853")
    assert not estimate.stiff and estimate.accuracy_steps > estimate.stability_steps, estimate


FAST_OSCILLATOR = """
name: fast_oscillator
coordinates:
  t: {domain: [0, 10]}
  w: {domain: [100, 200]}
unknowns:
  x: {initial: 1}
  v: {initial: 0}
equations:
  - "der(x) = v"
  - "der(v) = -w**2*x"
"""


def test_a_fast_oscillation_is_not_stiff():
    """Eigenvalues +-i w up to 200i: a large spectral radius, but nothing decays, and accuracy must follow
    the oscillation anyway."""
    estimate = _estimate(pgdcli.parse_spec(FAST_OSCILLATOR, source="oscillator.yaml"), "DOP853")
    assert not estimate.stiff and estimate.decay_rate < 1e-9, estimate


COUPLED_MASS = """
name: coupled_mass
coordinates:
  t: {domain: [0, 1]}
  k: {domain: [1, 2]}
unknowns:
  x: {initial: 0.3}
  y: {initial: -0.2}
  z: {initial: 0.5}
equations:
  - "der(x) + k*der(y) = sin(x*y) - k*z**2 + cos(t)"
  - "der(y) - der(x) = exp(-x)*y + max(z, 0.1)*x"
  - "(1 + t)*der(z) = -k*z + sqrt(1 + x**2)"
"""


@pytest.mark.parametrize("spec", [COUPLED_MASS, ROBERTSON_GENERAL, LOTKA_VOLTERRA], ids=["mass", "robertson", "lv"])
def test_exact_jacobian_matches_central_differences(spec):
    """The reference's exact Jacobian (product rule, symbolic derivatives of general terms, der()
    coefficients solved for) against central differences of its own right-hand side."""
    problem = pgdcli.parse_spec(spec, source="jac.yaml")
    points, S = _sample(problem, n=5)
    system = CompiledSystem(problem, points, S, max_evaluations=10**9)
    q = system.q
    rng = np.random.default_rng(2)
    y = system.initial(problem, points) + 0.1 * rng.standard_normal((S, q))
    y[:, :] = np.abs(y) * 1e-3 if "robertson" in problem.name else y
    t = 0.37
    J = system.jacobian(t, y.reshape(-1))
    numeric = np.empty_like(J)
    for j in range(q):
        h = 1e-6 * max(1.0, float(np.abs(y[:, j]).max()))
        up, down = y.copy(), y.copy()
        up[:, j] += h
        down[:, j] -= h
        numeric[:, :, j] = (system(t, up.reshape(-1)) - system(t, down.reshape(-1))).reshape(S, q) / (2 * h)
    scale = np.abs(numeric).max()
    assert np.abs(J - numeric).max() <= 1e-6 * scale
    # the finite-difference fallback (a function without a derivative rule) agrees too
    system.jacobian = lambda *args: (_ for _ in ()).throw(ValueError("no rule"))
    assert np.abs(reference_jacobian(system, t, y) - numeric).max() <= 1e-5 * scale


def test_estimate_of_states_that_are_not_finite_is_not_stiff():
    problem = pgdcli.parse_spec(DECAY_CHAIN, source="chain.yaml")
    points, S = _sample(problem)
    times = np.linspace(0, 10, 5)
    states = {u: np.full((S, 5), np.nan) for u in problem.unknown_names}
    estimate = estimate_stiffness(problem, points, S, times, states)
    assert not estimate.stiff and "not estimated" in estimate.text()


# ----------------------------------------------------------------------------------------------
# the gate on a stiff linear problem built by the enrichment
# ----------------------------------------------------------------------------------------------
# tau v' = a cos(3t) - v from the slow manifold: v = a (cos 3t + 3 tau sin 3t) / (1 + 9 tau^2) exactly
# (decay rate 1/tau up to 5e3, no transient), and q' = v - q, q(0) = 0
STIFF_LOWPASS = """
name: stiff_lowpass
coordinates:
  t: {domain: [0, 2]}
  tau: {domain: [0.0002, 0.0004]}
  a: {domain: [0.5, 1.5], nodes: 3}
unknowns:
  v: {initial: "a/(1 + 9*tau**2)"}
  q: {initial: 0}
equations:
  - "tau*der(v) = a*cos(3*t) - v"
  - "der(q) = v - q"
solver:
  method: pgd
  tolerance: 1e-6
"""


def _lowpass_exact(t, tau, a):
    A, B = a / (1 + 9 * tau**2), 3 * tau * a / (1 + 9 * tau**2)
    C, D = (A - 3 * B) / 10, (3 * A + B) / 10  # q' + q = A cos 3t + B sin 3t
    return A * np.cos(3 * t) + B * np.sin(3 * t), C * np.cos(3 * t) + D * np.sin(3 * t) - C * np.exp(-t)


@pytest.fixture(scope="module")
def lowpass():
    problem = pgdcli.parse_spec(STIFF_LOWPASS, source="stiff_lowpass.yaml")
    return problem, pgdcli.solve(problem)


def test_gate_of_a_stiff_enrichment_uses_radau_and_passes_a_right_codebook(lowpass):
    problem, result = lowpass
    cb = result.codebook
    assert result.accurate and cb.report["method"] == "pgd" and not cb.report.get("stiff", 0)
    # a ten-thousandth of the promise 1e-6, relative to |v| <= 1.5 (scale 10)
    assert result.check.method.startswith("Radau (rtol 1e-11, atol 1e-10; stiff: an explicit method needs ~3e+03 "
                                          "steps for stability (decay rate 5e+03 over a time domain of 2)")
    # the codebook against the exact solution, independently of the gate
    rng = np.random.default_rng(5)
    t, tau, a = rng.uniform(0, 2, 400), rng.uniform(2e-4, 4e-4, 400), rng.uniform(0.5, 1.5, 400)
    values = cb.evaluate({"t": t, "tau": tau, "a": a})
    v, q = _lowpass_exact(t, tau, a)
    assert max(np.abs(values["v"] - v).max(), np.abs(values["q"] - q).max()) <= 1e-6
    assert result.check.error <= 1e-6


def test_gate_of_a_stiff_enrichment_fails_a_perturbed_codebook(lowpass):
    """The right codebook with every value 4e-6 relative off (2e-6 to 6e-6 absolute in v): the gate fails it."""
    problem, result = lowpass
    cb = result.codebook
    fields = {u: CPTensor(f.weights * (1 + 4e-6), f.factors) for u, f in cb.fields.items()}
    wrong = Codebook(cb.coordinates, fields, name=cb.name, spec_text=cb.spec_text, report=dict(cb.report))
    stiffness = checks.reference_stiffness(problem, wrong)
    assert stiffness.stiff
    check = checks.check_codebook(problem, wrong, stiff=stiffness)
    assert not check.passed and 2.0 < check.ratio < 6.5, check.ratio
    assert check.method.startswith("Radau")


def test_stiff_reference_agrees_with_a_tight_independent_radau_and_the_exact_solution(lowpass):
    """The gate's stiff reference (one vectorized Radau call over the sample) at the check's own sample
    and times, against scipy's Radau per point at rtol 1e-12 with the exact Jacobian, and the exact
    solution: far inside the tolerance it checks (1e-6), at the gate's tolerances for it."""
    problem, result = lowpass
    cb = result.codebook
    grid, _ = check_sample(problem, cb, 0)
    lines, _ = line_sample(problem, cb, 0)
    points = {n: np.concatenate([grid[n], lines[n]]) for n in grid}
    S, times = points["a"].size, nodes_and_midpoints(cb, "t")[0]
    rtol, atol = checks.stiff_tolerances(1e-6, 0.0, 10.0)  # the gate's: |v| <= 1.5
    ref = solve_reference_vectorized(problem, points, S, times, method=checks.STIFF_METHOD, rtol=rtol, atol=atol)
    worst_exact = worst_scipy = 0.0
    for i in range(0, S, 16):
        tau, a = points["tau"][i], points["a"][i]
        sol = solve_ivp(lambda t, y: [(a * np.cos(3 * t) - y[0]) / tau, y[0] - y[1]], (0, 2),
                        [a / (1 + 9 * tau**2), 0.0], method="Radau", rtol=1e-12, atol=1e-14, t_eval=times,
                        jac=lambda t, y: [[-1 / tau, 0.0], [1.0, -1.0]])
        v, q = _lowpass_exact(times, tau, a)
        worst_scipy = max(worst_scipy, np.abs(ref["v"][i] - sol.y[0]).max(), np.abs(ref["q"][i] - sol.y[1]).max())
        worst_exact = max(worst_exact, np.abs(ref["v"][i] - v).max(), np.abs(ref["q"][i] - q).max())
    assert worst_exact <= 1e-9 and worst_scipy <= 1e-9  # three orders inside the tolerance


def test_stiff_reference_of_the_rc_filter_is_far_inside_its_tolerance():
    """The RC filter with its transient (v1(0) = 1, decay rates up to 1e3): the stiff reference at the
    gate's tolerances against the exact solution, at least 100 times tighter than the tolerance 1e-6."""
    problem = pgdcli.parse_spec(RC_FILTER, source="rc.yaml")
    points, S = _sample(problem, n=14)
    times = np.concatenate([np.linspace(0, 0.02, 9), np.linspace(0.02, 20, 41)[1:]])
    rtol, atol = checks.stiff_tolerances(1e-6, 0.0, 1.0)  # the gate's: |v1|, |v2| <= 1
    ref = solve_reference_vectorized(problem, points, S, times, method=checks.STIFF_METHOD, rtol=rtol, atol=atol)
    worst = 0.0
    for i in range(S):
        w, tau = points["w"][i], points["tau"][i]
        d = 1 + (w * tau) ** 2
        alpha, beta = 1 / d, -w * tau / d  # v1 = alpha sin wt + beta cos wt + (1 - beta) e^(-t/tau)
        gamma = 1 - beta
        C, D = np.linalg.solve([[0.5, -w], [w, 0.5]], [0.5 * alpha, 0.5 * beta])  # v2' + v2/2 = v1/2
        E = 0.5 * gamma / (0.5 - 1 / tau)
        v1 = alpha * np.sin(w * times) + beta * np.cos(w * times) + gamma * np.exp(-times / tau)
        v2 = C * np.sin(w * times) + D * np.cos(w * times) + E * np.exp(-times / tau) - (D + E) * np.exp(-times / 2)
        worst = max(worst, np.abs(ref["v1"][i] - v1).max(), np.abs(ref["v2"][i] - v2).max())
    assert worst <= 1e-8


def test_stiff_tolerances_are_a_share_of_the_promise():
    assert checks.stiff_tolerances(1e-6, 0.0, 1.0) == pytest.approx((1e-10, 1e-10))
    assert checks.stiff_tolerances(1e-6, 0.0, 100.0) == pytest.approx((1e-12, 1e-10))  # |u| up to 100
    assert checks.stiff_tolerances(1e-10, 1e-6, 1.0) == pytest.approx((1e-10, 1e-14))  # robertson's promise
    assert checks.stiff_tolerances(1e-12, 0.0, 1.0) == (checks.STIFF_RTOL, checks.STIFF_ATOL)  # never tighter
    assert checks.solution_scale({"u": np.array([0.3, -2.5, np.nan]), "v": np.array([1e-3])}) == 10.0
    assert checks.solution_scale({"u": np.array([0.5])}) == 1.0


def test_decide_stiffness_follows_a_stiff_march(lowpass):
    """A codebook whose report says a stiff stepper marched it is checked with Radau, whatever the estimate."""
    problem, result = lowpass
    cb = result.codebook
    marched = Codebook(cb.coordinates, cb.fields, name=cb.name, spec_text=cb.spec_text,
                       report=dict(cb.report, stiff=1))
    decision = decide_stiffness(problem, marched, {"tau": np.array([3e-4]), "a": np.array([1.0])}, 1,
                                np.linspace(0, 2, 5))
    assert decision.stiff and decision.text() == "the codebook was marched by a stiff stepper"


def test_verify_makes_the_gates_choice(lowpass):
    problem, result = lowpass
    report = pgdcli.verify(result.codebook, samples=8, times=4, jobs=1)
    assert report.passed()
    assert report.settings["method"] == "Radau" and report.settings["stiffness"].startswith("stiff: ")
    asked = pgdcli.verify(result.codebook, samples=2, times=0, jobs=1, method="BDF", max_corners=0)
    assert asked.settings["method"] == "BDF" and asked.settings["stiffness"] is None

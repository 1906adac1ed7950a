"""The exact solution of time-invariant linear method-of-lines systems, against exact solutions and Radau."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import spec_text

import pgdcli
from pgdcli.checks import modal_basis, reference_pde_modal
from pgdcli.checks.collocation import PdeModel
from pgdcli.checks.reference import solve_reference_pde
from pgdcli.checks.reference_pde_modal import (FORCED_METHOD_NAME, METHOD_NAME, MIN_SAMPLES, forced_modal_states,
                                              forcing_weights, modal_states)

PI = np.pi

HEAT_2D = spec_text(
    coordinates={'x': '{domain: [0, 1]}', 'y': '{domain: [0, 1]}', 't': '{domain: [0, 0.5]}',
                 'kappa': '{domain: [0.1, 1]}', 'g': '{domain: [-1, 1]}', 'q': '{domain: [0, 2]}'},
    unknowns={'u': '\n    initial: "g*x + sin(pi*x)*cos(pi*y)"\n    boundary:\n      x: {low: 0, high: g}\n'
                   '      y: {low: {gradient: 0}, high: {gradient: 0}}'},
    equations=['"der(u) = kappa*(der(u, x, 2) + der(u, y, 2)) + q*sin(pi*x)"'],
)

# advection-diffusion-reaction with one rate: a non-symmetric operator, a source, Robin-free Dirichlet ends
DRIFT = spec_text(
    coordinates={'x': '{domain: [0, 2]}', 't': '{domain: [0, 1.5]}', 'a': '{domain: [0.2, 1.5]}',
                 'c': '{domain: [-1, 1]}'},
    unknowns={'u': '\n    initial: "sin(pi*x/2) + c*x"\n    boundary:\n      x: {low: 0, high: 2*c}'},
    equations=['"der(u) = a*(0.3*der(u, x, 2) + der(u, x) - 0.5*u) + c*exp(-x)"'],
)

# two parameters scaling two different terms: the samples do not share one operator
TWO_RATES = spec_text(DRIFT, equations=['"der(u) = a*der(u, x, 2) + c*der(u, x)"'])


def _samples(problem, S, seed=0):
    rng = np.random.default_rng(seed)
    return {c.name: rng.uniform(*c.domain, S) for c in problem.coordinates if c.role == "parameter"}


def test_heat_2d_matches_the_exact_solution():
    problem = pgdcli.parse_spec(HEAT_2D)
    P = _samples(problem, 6)
    x, y = np.linspace(0, 1, 7), np.linspace(0, 1, 5)
    times = np.array([0.0, 0.01, 0.2, 0.5])
    result = solve_reference_pde(problem, P, {"x": x, "y": y}, times, space_nodes=24)
    assert result.method == METHOD_NAME and result.success.all()
    k, g, q = (P[c][:, None, None, None] for c in ("kappa", "g", "q"))
    T, X, Y = times[None, :, None, None], x[None, None, :, None], y[None, None, None, :]
    exact = (g * X + np.exp(-2 * k * PI**2 * T) * np.sin(PI * X) * np.cos(PI * Y)
             + q * (1 - np.exp(-k * PI**2 * T)) * np.sin(PI * X) / (k * PI**2))
    assert np.max(np.abs(result.values["u"] - exact)) <= 1e-10


def test_a_non_symmetric_operator_with_source_matches_radau():
    problem = pgdcli.parse_spec(DRIFT)
    P = _samples(problem, 5, seed=1)
    times = np.linspace(0, 1.5, 13)
    exact = solve_reference_pde(problem, P, None, times, space_nodes=32)
    radau = solve_reference_pde(problem, P, None, times, space_nodes=32, method="Radau", rtol=1e-12, atol=1e-13)
    assert exact.method == METHOD_NAME and radau.method == "Radau"
    scale = np.abs(radau.values["u"]).max()
    assert np.max(np.abs(exact.values["u"] - radau.values["u"])) <= 1e-10 * scale


def test_it_declines_what_it_cannot_solve_exactly(monkeypatch):
    drift = pgdcli.parse_spec(DRIFT)
    model = PdeModel(drift, {"x": 16})
    times = np.linspace(0, 1.5, 4)
    # too few samples to pay for a decomposition
    few = _samples(drift, MIN_SAMPLES - 1)
    assert modal_states(model, few, MIN_SAMPLES - 1, 0.0, times) is None
    # enough samples: it applies
    P = _samples(drift, MIN_SAMPLES)
    assert modal_states(model, P, MIN_SAMPLES, 0.0, times).shape == (MIN_SAMPLES, 1, 4, 16)
    # the samples' operators are not multiples of one matrix
    two = pgdcli.parse_spec(TWO_RATES)
    assert modal_states(PdeModel(two, {"x": 16}), P, MIN_SAMPLES, 0.0, times) is None
    # an eigenvector basis too ill-conditioned to trust
    monkeypatch.setattr(modal_basis, "MAX_CONDITION", 1.0)
    assert modal_states(model, P, MIN_SAMPLES, 0.0, times) is None


def test_a_time_dependent_coefficient_is_integrated():
    problem = pgdcli.parse_spec(spec_text(DRIFT, equations=['"der(u) = a*(1 + t)*der(u, x, 2)"']))
    P = _samples(problem, 6)
    result = solve_reference_pde(problem, P, None, np.linspace(0, 1.5, 5), space_nodes=16)
    assert result.method == "BDF" and result.success.all()


@pytest.mark.parametrize("S", [MIN_SAMPLES, 9])
def test_samples_a_radau_integration_agrees_with_at_the_nodes(S):
    problem = pgdcli.parse_spec(HEAT_2D)
    P = _samples(problem, S, seed=S)
    model = PdeModel(problem, {"x": 12, "y": 10})
    times = np.array([0.0, 0.1, 0.5])
    values = modal_states(model, P, S, 0.0, times)
    radau = solve_reference_pde(problem, P, None, times, space_nodes={"x": 12, "y": 10}, method="Radau",
                                rtol=1e-12, atol=1e-13)
    grid = values.reshape(S, 1, 3, 12, 10)[:, 0]
    assert np.max(np.abs(grid - radau.values["u"])) <= 1e-10


@pytest.mark.parametrize("zeta", [0.0, -1e-3, -0.7, 2.0, -10.0, -59.9, -60.1, -150.0, -3000.0, -5 + 30j, -80 + 40j])
def test_forcing_weights_are_the_integrals_of_the_lagrange_basis_against_quad(zeta):
    from scipy.integrate import quad
    from scipy.interpolate import BarycentricInterpolator

    p = reference_pde_modal.FORCING_NODES
    nodes = 0.5 * (1 - np.cos(np.pi * np.arange(p) / (p - 1)))
    got = forcing_weights(np.array([zeta]))[0]
    for j in range(p):
        basis = BarycentricInterpolator(nodes, np.eye(p)[j])
        parts = [quad(lambda s, f=f: f(np.exp(zeta * (1 - s)) * basis(s)), 0, 1, epsabs=1e-14, epsrel=1e-13,
                      limit=400, points=[1 - 1 / max(abs(zeta), 1)])[0] for f in (np.real, np.imag)]
        assert abs(got[j] - complex(*parts)) <= 1e-12 * max(1.0, abs(got).max()), j


# sources that vary in time: a pulse moving with time (non-separable), a separable oscillation, a switch of time
MOVING = spec_text(DRIFT, equations=[
    '"der(u) = a*(0.3*der(u, x, 2) + der(u, x) - 0.5*u) + c*exp(-(x - 1 - 0.5*sin(3*t))**2/0.1) + cos(4*t)*exp(-x)"'])
SWITCHED = spec_text(DRIFT, equations=['"der(u) = a*(0.3*der(u, x, 2) - 0.5*u) + c*step(t - 0.6)*sin(pi*x/2)"'])


def _radau_on_the_grid(model, P, S, times, switches=()):
    """The collocation system integrated by Radau at a tight tolerance, restarted at each switch of time."""
    from scipy.integrate import solve_ivp

    from pgdcli.checks.collocation_system import PdeSystem

    system = PdeSystem(model, P, S, 10**9)
    y = model.interior_values(model.initial_grid(P, S)).reshape(-1)
    J = system.jacobian(0.0, y).toarray()
    out, start = [], 0.0
    for end in [*switches, times[-1]]:
        inside = times[(times > start) & (times <= end)]
        sol = solve_ivp(system, (start, end), y, method="Radau", jac=J, rtol=1e-12, atol=1e-14,
                        t_eval=np.r_[inside, end] if inside.size == 0 or inside[-1] != end else inside)
        out += list(sol.y.T[: inside.size])
        y, start = sol.y[:, -1], end
    return np.array(out)  # (T - 1, S m)


@pytest.mark.parametrize("spec, switches", [(MOVING, ()), (SWITCHED, (0.6,))])
def test_sources_varying_in_time_match_radau_on_the_same_grid(spec, switches):
    problem = pgdcli.parse_spec(spec)
    S, times = 5, np.array([0.0, 0.1, 0.45, 0.7, 0.9, 1.5])
    P = _samples(problem, S, seed=3)
    model = PdeModel(problem, {"x": 24})
    got = forced_modal_states(model, P, S, 0.0, times, 1e-12, 1e-12)  # (S, q, T, n)
    ref = _radau_on_the_grid(model, P, S, times, switches).reshape(times.size - 1, S, model.m)
    interior = np.stack([model.interior_values(got[:, :, k]).reshape(S, model.m) for k in range(1, times.size)])
    assert np.max(np.abs(interior - ref)) <= 1e-10 * max(1.0, np.abs(ref).max())
    result = solve_reference_pde(problem, P, None, times, space_nodes=24)
    assert result.method == FORCED_METHOD_NAME and result.success.all()


def test_a_source_that_jumps_along_a_line_of_space_and_time_is_left_to_the_integration():
    problem = pgdcli.parse_spec(spec_text(DRIFT, equations=['"der(u) = a*der(u, x, 2) + c*step(x - 0.5 - t)"']))
    P = _samples(problem, MIN_SAMPLES)
    assert forced_modal_states(PdeModel(problem, {"x": 16}), P, MIN_SAMPLES, 0.0, np.linspace(0, 1.5, 4),
                               1e-12, 1e-12) is None

"""The pilot's first nodes: from the Chebyshev spectrum of lines of marched trajectories, checked against the
interpolation error of the exact solution along each coordinate."""

from pathlib import Path

import numpy as np

from pgdcli.adapt.pilot import (PILOT_NODES, PILOT_TRAJECTORIES, SPECTRUM_SAFETY, first_nodes, nodes_from_spectrum,
                                pilot_coordinates, pilot_problem)
from pgdcli.adapt.resolution import ROOM, TARGET, initial_nodes
from pgdcli.algorithms.march import solve_march
from pgdcli.problem.spec import parse_spec
import pgdcli

# u' = -k u^2, u(0) = u0: u = u0 / (1 + k u0 t), analytic in k and u0 over the box
DECAY = """
coordinates:
  t: {domain: [0, 2]}
  k: {domain: [0.5, 3]}
  u0: {domain: [0.5, 2]}
unknowns:
  u: {initial: u0}
equations:
  - "der(u) = -k*u**2"
solver:
  tolerance: 1e-6
"""


def exact(t, k, u0):
    return u0 / (1 + k * u0 * t)


def interpolation_error(n: int, name: str) -> float:
    """Max error of degree n - 1 Chebyshev interpolation of the exact solution along ``name`` (the other
    parameter and time on a grid), at 400 points."""
    domains = {"k": (0.5, 3.0), "u0": (0.5, 2.0)}
    other = "u0" if name == "k" else "k"
    worst = 0.0
    x = np.linspace(*domains[name], 400)
    for t in np.linspace(0, 2, 9):
        for v in np.linspace(*domains[other], 7):
            f = (lambda s: exact(t, s, v)) if name == "k" else (lambda s: exact(t, v, s))
            p = np.polynomial.Chebyshev.interpolate(f, n - 1, domain=domains[name])
            worst = max(worst, float(np.abs(p(x) - f(x)).max()))
    return worst


def test_nodes_from_a_geometric_spectrum():
    spectrum = 10.0 ** -np.arange(20.0)  # tail from degree n: 2 * 1.11.. * 10^-n
    assert nodes_from_spectrum(spectrum, 1e-6) == 7
    assert nodes_from_spectrum(spectrum, 2.3e-6) == 6
    assert nodes_from_spectrum(spectrum, 1e-30) is None  # not resolved by the pilot's nodes
    assert nodes_from_spectrum(np.zeros(5), 0.0) == 0


def test_the_pilot_measures_automatic_chebyshev_parameters_within_its_budget():
    problem = initial_nodes(parse_spec(DECAY), march=True)
    assert pilot_coordinates(problem) == ["k", "u0"]
    fixed = parse_spec(DECAY.replace("k: {domain: [0.5, 3]}", "k: {domain: [0.5, 3], nodes: 12}"))
    assert pilot_coordinates(initial_nodes(fixed, march=True)) == ["u0"]
    line = pilot_problem(problem, "k", ["k", "u0"])
    assert (line.coordinate("k").nodes, line.coordinate("u0").nodes) == (PILOT_NODES, 3)
    many = "\n".join(f"  p{i}: {{domain: [0, 1]}}" for i in range(6))
    wide = parse_spec(DECAY.replace("  u0: {domain: [0.5, 2]}", "  u0: {domain: [0.5, 2]}\n" + many))
    assert 8 * PILOT_NODES * 3 ** 7 > PILOT_TRAJECTORIES and pilot_coordinates(initial_nodes(wide, True)) == []


def test_first_nodes_meet_each_coordinates_share_of_the_tolerance():
    problem = initial_nodes(parse_spec(DECAY), march=True)
    tol = 1e-6
    nodes = first_nodes(problem, tol, lambda p, name: solve_march(p, 0.07 * tol).codebook)
    share = min(TARGET, ROOM / 2) * tol
    for name, n in nodes.items():
        assert 9 <= n < PILOT_NODES
        assert interpolation_error(n, name) <= share  # the exact solution's, along the chosen nodes
        needed = next(m for m in range(2, 60) if interpolation_error(m, name) <= share / SPECTRUM_SAFETY)
        assert n <= needed + 4, (name, n, needed)  # and not many more than it takes


def test_a_march_starts_at_the_pilots_nodes_and_keeps_its_promise():
    result = pgdcli.solve(parse_spec(DECAY))
    report = result.codebook.report
    assert result.accurate is True
    pilot = dict(item.split(":") for item in report["resolution_pilot"].split(","))
    assert set(pilot) == {"k", "u0"}
    assert report["resolution_rounds"].shape[0] == 1  # the pilot's nodes sufficed: one round
    rng = np.random.default_rng(5)
    t, k, u0 = rng.uniform(0, 2, 300), rng.uniform(0.5, 3, 300), rng.uniform(0.5, 2, 300)
    values = result.codebook.evaluate({"t": t, "k": k, "u0": u0})["u"]
    assert np.abs(values - exact(t, k, u0)).max() <= 1e-6


RUNGE = DECAY.replace("  k: {domain: [0.5, 3]}\n  u0: {domain: [0.5, 2]}", "  p: {domain: [0, 1]}").replace(
    "u: {initial: u0}", 'u: {initial: "1/(1 + 400*(p - 0.3)**2)"}').replace("-k*u**2", "-u**3")


def test_an_unresolved_parameter_starts_at_the_pilots_nodes_only_when_its_spectrum_falls_fast():
    runge = initial_nodes(parse_spec(RUNGE), march=True)  # a sharp feature: the rounds cut elements from 9
    assert first_nodes(runge, 1e-6, lambda p, name: solve_march(p, 7e-8).codebook) == {}
    pendulum = initial_nodes(pgdcli.load_spec(Path(__file__).parents[1] / "problems" / "pendulum.yaml"), march=True)  # needs ~48: geometric
    assert first_nodes(pendulum, 1e-6, lambda p, name: solve_march(p, 7e-8).codebook) == {"L": 33, "th0": 33}

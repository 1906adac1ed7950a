"""The pilot's first nodes: from the Chebyshev spectrum of lines of marched trajectories, checked against the
interpolation error of the exact solution along each coordinate."""

from pathlib import Path

import numpy as np
from scipy.special import ellipj, ellipk

from pgdcli.adapt.pilot import (PILOT_NODES, PILOT_TRAJECTORIES, SPECTRUM_SAFETY, extrapolated_nodes, first_nodes,
                                nodes_from_spectrum, pilot_coordinates, pilot_problem)
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


def chebyshev_error(solution, domains: dict, t_end: float, n: int, name: str) -> float:
    """Max error of degree n - 1 Chebyshev interpolation of ``solution(t, p, q)`` along ``name`` (one of the two
    parameters of ``domains``; the other and time on a grid), at 400 points."""
    first, other = name == list(domains)[0], [c for c in domains if c != name][0]
    worst, x = 0.0, np.linspace(*domains[name], 400)
    for t in np.linspace(0, t_end, 9):
        for v in np.linspace(*domains[other], 7):
            f = (lambda s: solution(t, s, v)) if first else (lambda s: solution(t, v, s))
            p = np.polynomial.Chebyshev.interpolate(f, n - 1, domain=domains[name])
            worst = max(worst, float(np.abs(p(x) - f(x)).max()))
    return worst


def interpolation_error(n: int, name: str) -> float:
    """:func:`chebyshev_error` of the exact solution of ``DECAY``."""
    return chebyshev_error(exact, {"k": (0.5, 3.0), "u0": (0.5, 2.0)}, 2.0, n, name)


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


def pendulum_exact(t, L, th0):
    """th'' = -(9.81 / L) sin(th), th(0) = th0, th'(0) = 0: th = 2 arcsin(k sn(K(k^2) - w t; k^2)), k = sin(th0/2)."""
    k = np.sin(th0 / 2)
    sn = ellipj(ellipk(k * k) - np.sqrt(9.81 / L) * t, k * k)[0]
    return 2 * np.arcsin(k * sn)


def pendulum_interpolation_error(n: int, name: str) -> float:
    """:func:`chebyshev_error` of the pendulum's angle."""
    return chebyshev_error(pendulum_exact, {"L": (0.5, 2.0), "th0": (0.1, 2.5)}, 3.0, n, name)


def test_an_unresolved_parameter_starts_where_its_spectrum_extrapolates_only_when_it_falls_fast():
    runge = initial_nodes(parse_spec(RUNGE), march=True)  # a sharp feature: the rounds cut elements from 9
    assert first_nodes(runge, 1e-6, lambda p, name: solve_march(p, 7e-8).codebook) == {}
    pendulum = initial_nodes(pgdcli.load_spec(Path(__file__).parents[1] / "problems" / "pendulum.yaml"), march=True)
    nodes = first_nodes(pendulum, 1e-6, lambda p, name: solve_march(p, 7e-8).codebook)
    assert set(nodes) == {"L", "th0"}
    share = min(TARGET, ROOM / 2) * 1e-6
    for name, n in nodes.items():  # geometric decay: past the pilot's nodes, to what the exact solution needs
        assert PILOT_NODES < n <= 65
        assert pendulum_interpolation_error(n, name) <= share, name
        needed = next(m for m in range(20, 80) if pendulum_interpolation_error(m, name) <= share / SPECTRUM_SAFETY)
        assert n <= 1.2 * needed, (name, n, needed)  # an extrapolation: a little more than it takes


def test_extrapolated_nodes_of_a_geometric_spectrum():
    spectrum = 10.0 ** -np.arange(12.0)  # a decade a node: 2 x 1e-10 (the last two's) to 1e-15 in 5.3 more nodes
    assert extrapolated_nodes(spectrum, 1e-15) == 18
    assert extrapolated_nodes(2.0 ** -np.arange(12.0), 1e-30) is None  # slow: beyond MAX_ELEMENT_NODES


ONE = DECAY.replace("  u0: {domain: [0.5, 2]}\n", "").replace("u: {initial: u0}", "u: {initial: 1.5}")


def test_a_one_parameter_pilot_march_is_the_first_rounds(monkeypatch):
    import pgdcli.driver.methods as methods
    calls = []

    def counted(problem, *args, **kwargs):
        calls.append({c.name: c.nodes for c in problem.parameter_coordinates})
        return solve_march(problem, *args, **kwargs)

    monkeypatch.setattr(methods, "solve_march", counted)
    result = pgdcli.solve(parse_spec(ONE))
    assert calls == [{"k": PILOT_NODES}]  # one march: the pilot's grid is the whole grid
    assert result.accurate is True and result.codebook.coordinate("k").nodes == PILOT_NODES
    rng = np.random.default_rng(6)
    t, k = rng.uniform(0, 2, 300), rng.uniform(0.5, 3, 300)
    assert np.abs(result.codebook.evaluate({"t": t, "k": k})["u"] - exact(t, k, 1.5)).max() <= 1e-6
